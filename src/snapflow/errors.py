"""snapflow's own errors: what a user can fix, told by name.

Every ``snapflow`` command tells a :class:`SnapflowError` in one line and exits with code 2; anything else that
escapes a command is a bug in snapflow, shown with its traceback and where to report it (``cli.common.run_command``).
So raise a :class:`SnapflowError` (most often :class:`InvalidInputError`) for what the user gave or can change (a
setting, a name, a file, a data set, a checkpoint, an environment), and a plain ``ValueError`` / ``TypeError`` /
assertion for what only a programming error reaches (a broken invariant, a registry filled twice).
"""

from __future__ import annotations


class SnapflowError(Exception):
    """Something the user can fix: told in one line, without a traceback."""


class InvalidInputError(SnapflowError, ValueError):
    """A setting, name, shape, file or data set snapflow cannot take. A ``ValueError`` too, so that code written
    against the ``ValueError`` snapflow raised before keeps working."""


__all__ = ["SnapflowError", "InvalidInputError"]
