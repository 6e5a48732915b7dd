"""What every built-in policy configuration shares: typed, validated fields and a JSON round trip."""

from __future__ import annotations

from dataclasses import MISSING, dataclass, fields
from typing import Any, TypeVar

from snapflow.errors import InvalidInputError
from snapflow.reporting.records import as_record

Config = TypeVar("Config", bound="PolicyConfig")


@dataclass(frozen=True)
class PolicyConfig:
    """Base of the built-in policies' frozen dataclass configurations.

    Every field is an ``int`` (at least 1 unless its metadata says ``minimum``), a ``bool``, a ``str`` or a
    ``tuple[str, ...]`` (given as a list in JSON and TOML); a flag given for a size (or a size for a flag) is as wrong
    as a string, so ``bool`` is not accepted where an ``int`` is expected. Subclasses add their own checks in
    ``__post_init__`` after calling ``super().__post_init__()``. Each has ``chunk_length`` and ``action_dim`` fields.
    """

    def __post_init__(self) -> None:
        name = type(self).__name__
        for field in fields(self):
            value = getattr(self, field.name)
            if field.type == "tuple[str, ...]":
                if not isinstance(value, (list, tuple)) or not all(isinstance(item, str) for item in value):
                    raise InvalidInputError(f"{name}.{field.name} must be a list of names, got {value!r}")
                object.__setattr__(self, field.name, tuple(value))
                continue
            expected = {"int": int, "bool": bool, "str": str}[field.type]
            if not isinstance(value, expected) or (expected is int and isinstance(value, bool)):
                raise InvalidInputError(f"{name}.{field.name} must be {field.type}, got {value!r}")
            minimum = field.metadata.get("minimum", 1)
            if expected is int and value < minimum:
                raise InvalidInputError(f"{name}.{field.name} must be at least {minimum}, got {value}")

    def to_dict(self) -> dict[str, Any]:
        return as_record(self)

    @classmethod
    def from_dict(cls: type[Config], data: dict[str, Any]) -> Config:
        unknown = sorted(set(data) - {field.name for field in fields(cls)})
        if unknown:
            raise InvalidInputError(f"unknown {cls.__name__} field(s) {unknown}")
        missing = sorted(field.name for field in fields(cls) if field.default is MISSING and field.name not in data)
        if missing:
            raise InvalidInputError(f"missing {cls.__name__} field(s) {missing}")
        return cls(**data)


__all__ = ["PolicyConfig"]
