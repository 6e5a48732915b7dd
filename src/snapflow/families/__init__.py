"""The families of policies snapflow trains and distils, registered in one place and asked, never branched on:
"built-in or LeRobot?" is answered here alone (:func:`family_of`). A family's module is plain Python at import (its
heavy imports are inside its methods), so the CLI reads the registry before torch loads."""

from __future__ import annotations

from typing import Any

from snapflow.families.base import PolicyFamily, Progress, Source, StudentRun, TeacherOptions, TeacherRun
from snapflow.families.builtin import BuiltinFamily
from snapflow.families.lerobot import LeRobotFamily

#: every family, in the order they are asked; the first is the default (a sweep's teacher run with no family's key)
FAMILIES: list[PolicyFamily] = []


def register_family(family: PolicyFamily) -> None:
    """Add a family of policies, asked after those registered before it."""
    if any(known.name == family.name or known.run_key == family.run_key for known in FAMILIES):
        raise ValueError(f"a policy family named {family.name!r} or keyed {family.run_key!r} is registered already")
    FAMILIES.append(family)


register_family(BuiltinFamily())
register_family(LeRobotFamily())


def family_of(what: Any) -> PolicyFamily:
    """The family of ``what``: a policy type's name (as ``snapflow bench --architecture`` takes, every type a family
    trains among them), a teacher's spec (a built-in policy's config, a LeRobot spec), or a sweep's teacher-run table
    (by the key that describes its policy; neither key: the default family's)."""
    if isinstance(what, str):
        for family in FAMILIES:
            if what in family.architectures():
                return family
        known = [name for family in FAMILIES for name in family.architectures()]
        raise ValueError(f"no policy family has a policy type {what!r}; known: {known}")
    if isinstance(what, dict):
        keyed = [family for family in FAMILIES if family.run_key in what]
        if len(keyed) > 1:
            from snapflow.errors import InvalidInputError

            keys = " or ".join(repr(family.run_key) for family in keyed)
            raise InvalidInputError(f"give {keys}, not both: a run's policy is of one family")
        return keyed[0] if keyed else FAMILIES[0]
    for family in FAMILIES:
        if family.claims_spec(what):
            return family
    raise ValueError(f"no policy family claims {what!r}")


def teacher_types() -> list[str]:
    """Every policy type a family trains from scratch, family by family."""
    return [name for family in FAMILIES for name in family.teacher_types()]


__all__ = [
    "FAMILIES",
    "PolicyFamily",
    "Progress",
    "Source",
    "StudentRun",
    "TeacherOptions",
    "TeacherRun",
    "family_of",
    "register_family",
    "teacher_types",
]
