"""Settings as they are recorded (job records, checkpoints' training state): a dataclass as a dict, where a field
added after records were first written is left out while it holds its default.

That default must be the behaviour from before the field existed (a lever that is off), so a record written before
the field existed still describes a run with the new code's default: sweep caches and resumable runs stay valid when
an option is added, and a run that sets the option is recorded with it.
"""

from __future__ import annotations

import copy
from dataclasses import MISSING, Field, field, fields, is_dataclass
from typing import Any

_ADDED = "snapflow_added_option"


def added_option(default: Any = MISSING, metadata: dict[str, Any] | None = None, **kwargs: Any) -> Any:
    """A dataclass field added after records existed: ``default`` (or what ``default_factory`` makes, for a mutable
    default) must reproduce the behaviour from before it."""
    return field(default=default, metadata={**(metadata or {}), _ADDED: True}, **kwargs)


def _left_out(definition: Field, value: Any) -> bool:
    default = definition.default if definition.default_factory is MISSING else definition.default_factory()
    return bool(definition.metadata.get(_ADDED)) and value == default


def as_record(instance: Any) -> dict[str, Any]:
    """``dataclasses.asdict`` of ``instance``, without the added options that hold their defaults."""
    return {
        definition.name: as_record(value) if is_dataclass(value) else copy.deepcopy(value)
        for definition in fields(instance)
        if not _left_out(definition, value := getattr(instance, definition.name))
    }


def without_unset(record: dict[str, Any], optional: tuple[str, ...]) -> dict[str, Any]:
    """``record`` without those of its ``optional`` keys that are None: a result written only where measured, as the
    results written before it could be keep their form."""
    return {key: value for key, value in record.items() if key not in optional or value is not None}


__all__ = ["added_option", "as_record", "without_unset"]
