"""Lazy package exports (PEP 562): ``from prt_torch.<pkg> import X`` imports X's submodule on first access.

A package whose submodules include light hooks (a ``prt`` command or bench module, a stage-table hook that
``prt --help`` imports) must not run its heavy submodules (torch, healpy) when one of the light ones is imported.
:func:`lazy_exports` makes the package's exports lazy: ``exports`` lists each submodule's exported names, and
the module ``__getattr__`` imports it on first access and binds the value on the package. An export named like
its own submodule (``prt_torch.vct.voxelize``'s ``voxelize``) stays the export when the submodule is imported (the
import system sets the submodule on its parent; the eager ``from .voxelize import voxelize`` kept the function).
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import Any


class LazyPackage(types.ModuleType):
    """A package module whose exports are imported on first access (:func:`lazy_exports`)."""

    lazy_exports: dict[str, str]

    def __getattr__(self, name: str) -> Any:
        module = self.__dict__.get("lazy_exports", {}).get(name)
        if module is None:
            raise AttributeError(f"module {self.__name__!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        super().__setattr__(name, value)
        return value

    def __setattr__(self, name: str, value: Any) -> None:
        if isinstance(value, types.ModuleType) and self.__dict__.get("lazy_exports", {}).get(name) == value.__name__:
            value = getattr(value, name)  # the submodule named like its export: keep the export
        super().__setattr__(name, value)

    def __dir__(self) -> list[str]:
        return sorted({*self.__dict__, *self.__dict__.get("lazy_exports", {})})


def lazy_exports(package: str, exports: dict[str, tuple[str, ...]]) -> None:
    """Make ``exports`` (submodule -> the names the package exports from it) of the already-imported ``package``
    lazy; call it at the end of the package's ``__init__``."""
    module = sys.modules[package]
    module.__class__ = LazyPackage
    module.__dict__["lazy_exports"] = {name: sub for sub, names in exports.items() for name in names}
