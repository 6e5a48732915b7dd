"""Names imported on first use: package exports (PEP 562), and the classes a registry names as ``"module:Class"``;
``snapflow --help`` and argument errors then load no torch."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable
from typing import Any


def lazy_exports(
    package: str, exports: dict[str, list[str]]
) -> tuple[Callable[[str], Any], Callable[[], list[str]], list[str]]:
    """``__getattr__``, ``__dir__`` and ``__all__`` of ``package``, whose public names (``exports``: submodule ->
    names it defines) are imported from their submodule when first read, then kept in the package's namespace."""
    owner = {name: module for module, names in exports.items() for name in names}
    namespace = sys.modules[package].__dict__

    def __getattr__(name: str) -> Any:
        if name not in owner:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(owner[name]), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted({*namespace, *owner})

    return __getattr__, __dir__, list(owner)


def resolve(target: type | str) -> Any:
    """A class, or ``"module:name"`` (a class or a function) imported now: a registry names what it holds without
    importing their modules."""
    if isinstance(target, type):
        return target
    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)
