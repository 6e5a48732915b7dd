"""Settings tables as a user writes them (a TOML table, a JSON object) checked before they become settings: unknown
or missing keys, counts, a dataclass with some fields given; every mistake an ``InvalidInputError`` naming its
section."""

from __future__ import annotations

from dataclasses import fields, replace
from typing import Any

from snapflow.errors import InvalidInputError


def checked_table(
    section: str, table: Any, allowed: set[str], required: frozenset[str] = frozenset()
) -> dict[str, Any]:
    """``table`` itself, once it is a table of only ``allowed`` keys holding every ``required`` one."""
    if not isinstance(table, dict):
        raise InvalidInputError(f"{section}: expected a table of keys, got {table!r}")
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise InvalidInputError(f"{section}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
    missing = sorted(required - set(table))
    if missing:
        raise InvalidInputError(f"{section}: missing key(s) {missing}")
    return table


def field_names(cls: type) -> set[str]:
    """The field names of the dataclass ``cls``."""
    return {field.name for field in fields(cls)}


def dataclass_from(section: str, base: Any, overrides: Any) -> Any:
    """``base`` (a dataclass instance) with the fields ``overrides`` gives, checked by its own ``__post_init__``."""
    checked_table(section, overrides, field_names(type(base)))
    try:
        return replace(base, **overrides)
    except (TypeError, ValueError) as error:
        raise InvalidInputError(f"{section}: {error}") from None


def checked_count(section: str, name: str, value: Any) -> int:
    """A count (episodes, actions per chunk, image size): an integer of at least 1, never a silent default."""
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise InvalidInputError(f"{section}: {name} must be an integer of at least 1, got {value!r}")
    return value


__all__ = ["checked_count", "checked_table", "dataclass_from", "field_names"]
