"""Old import paths that keep working for one release, with a ``FutureWarning``.

When a module or a public name moves, its old path stays importable until
:data:`REMOVED_IN`: importing an old module path, or reading an old name,
warns once per place and hands out the object at its new home (the very same
object, so ``isinstance`` and identity checks keep holding).

Examples
--------
>>> import warnings
>>> with warnings.catch_warnings(record=True) as caught:
...     warnings.simplefilter("always")
...     from mocap.c3d import read_c3d
>>> from mocap.io.c3d import read_c3d as new
>>> read_c3d is new, caught[0].category.__name__
(True, 'FutureWarning')
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import types
import warnings

__all__ = ["REMOVED_IN", "alias_modules", "moved_names"]

#: The release that drops the old paths.
REMOVED_IN = "0.3"


def _resolve(target: str):
    """``"package.module:name"`` (or a module path alone) to the object it names."""
    module, _, name = target.partition(":")
    obj = importlib.import_module(module)
    return getattr(obj, name) if name else obj


def _warn(old: str, new: str) -> None:
    # stacklevel 3 skips this helper and its caller; the import system's own
    # frames are skipped by the warnings module itself
    warnings.warn(f"{old} moved to {new.replace(':', '.')}; the old path is removed in "
                  f"mocap2mesh {REMOVED_IN}", FutureWarning, stacklevel=3)


class _ModuleAliases(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds old module paths and loads each as a proxy of its new module."""

    def __init__(self, aliases: dict):
        self.aliases = dict(aliases)

    def find_spec(self, fullname, path=None, target=None):
        if fullname in self.aliases:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec):
        return types.ModuleType(spec.name)

    def exec_module(self, module):
        new = self.aliases[module.__name__]
        _warn(module.__name__, new)
        target = importlib.import_module(new)
        module.__doc__ = f"Moved to :mod:`{new}` (this path goes in {REMOVED_IN})."
        module.__all__ = list(getattr(target, "__all__", ()))
        module.__getattr__ = lambda name: getattr(target, name)
        module.__dir__ = lambda: dir(target)
        if hasattr(target, "__path__"):          # a package: its submodules resolve too
            module.__path__ = []


def alias_modules(aliases: dict) -> None:
    """Keep old module paths importable: `aliases` maps old path -> new path.

    Old paths of submodules of an aliased package need their own entries.
    """
    sys.meta_path.insert(0, _ModuleAliases(aliases))


def moved_names(module: str, moved: dict):
    """A module ``__getattr__`` serving names that moved out of `module`.

    Parameters
    ----------
    module : str
        The module's ``__name__``.
    moved : dict
        Old name -> ``"new.module:name"``, or -> ``("new.module:name", adapter)``
        where ``adapter()`` builds what the old name gave (the new function
        under the old signature, say).
    """
    def __getattr__(name):
        if name not in moved:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        target = moved[name]
        if isinstance(target, tuple):
            new, adapter = target
            _warn(f"{module}.{name}", new)
            return adapter()
        _warn(f"{module}.{name}", target)
        return _resolve(target)
    return __getattr__
