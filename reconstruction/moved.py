"""Old import names of modules that moved into rooms, kept working for lab scripts.

A package calls :func:`keep_old_names` with a map ``{old name: new name}``; ``import old`` (and ``from old import
x``) then gives the module at its new place, the same object in ``sys.modules`` under both names, so a script
written against an earlier layout runs unchanged and patches it makes are seen by the project.

>>> import importlib
>>> import reconstruction.core.geometry as g
>>> importlib.import_module("reconstruction.geometry") is g
True
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
from collections.abc import Mapping
from types import ModuleType

__all__ = ["keep_old_names", "OLD_NAMES"]

#: Every old name served, to its new name (all packages): the test suite checks each still imports.
OLD_NAMES: dict[str, str] = {}


class _Alias(importlib.abc.Loader):
    """Loads an old name by importing the new one and putting that module in its place."""

    def __init__(self, new: str) -> None:
        self.new = new

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> None:
        return None  # a throwaway module, replaced in exec_module

    def exec_module(self, module: ModuleType) -> None:
        sys.modules[module.__name__] = importlib.import_module(self.new)


class _OldNames(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname: str, path: object = None, target: object = None
                  ) -> importlib.machinery.ModuleSpec | None:
        new = OLD_NAMES.get(fullname)
        return None if new is None else importlib.util.spec_from_loader(fullname, _Alias(new))


_FINDER = _OldNames()


def keep_old_names(moved: Mapping[str, str]) -> None:
    """Serve each old module name of ``moved`` ({old: new}, dotted names) as the module at its new name."""
    OLD_NAMES.update(moved)
    if _FINDER not in sys.meta_path:
        sys.meta_path.insert(0, _FINDER)


keep_old_names({
    "reconstruction.geometry": "reconstruction.core.geometry",
    "reconstruction.models": "reconstruction.core.models",
    "reconstruction.merl": "reconstruction.formats.merl",
    "reconstruction.slicefile": "reconstruction.formats.slicefile",
})
