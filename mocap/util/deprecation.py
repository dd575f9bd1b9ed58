"""Old import paths that keep working for one release, with a ``FutureWarning``.

When a module or a public name moves, its old path stays importable until
:data:`REMOVED_IN`: importing an old module path, or reading an old name,
warns once per place and hands out the object at its new home (the very same
object, so ``isinstance`` and identity checks keep holding).

Examples
--------
>>> import warnings
>>> from mocap.io.c3d import read_c3d as new
>>> with warnings.catch_warnings():
...     warnings.simplefilter("ignore", FutureWarning)
...     from mocap.c3d import read_c3d
>>> read_c3d is new
True
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


def _warn(old: str, new: str, stacklevel: int = 3) -> None:
    # the default skips this helper and its caller; the import system's own
    # frames are skipped by the warnings module itself
    warnings.warn(f"{old} moved to {new.replace(':', '.')}; the old path is removed in "
                  f"mocap2mesh {REMOVED_IN}", FutureWarning, stacklevel=stacklevel)


def _moved(module: str, name: str, target, stacklevel: int):
    """The object an old name `module.name` stands for, with its warning."""
    if isinstance(target, tuple):
        new, adapter = target
        _warn(f"{module}.{name}", new, stacklevel + 1)
        return adapter()
    _warn(f"{module}.{name}", target, stacklevel + 1)
    return _resolve(target)


class _ModuleAliases(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds old module paths and loads each as a proxy of where its names went."""

    def __init__(self, aliases: dict):
        self.aliases = {old: (new,) if isinstance(new, (str, dict)) else tuple(new)
                        for old, new in aliases.items()}

    def find_spec(self, fullname, path=None, target=None):
        if fullname in self.aliases:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec):
        return types.ModuleType(spec.name)

    def exec_module(self, module):
        old = module.__name__
        sources = self.aliases[old]
        modules = [s for s in sources if isinstance(s, str)]
        names = {k: v for s in sources if isinstance(s, dict) for k, v in s.items()}
        _warn(old, " and ".join(modules) or "new homes")
        targets = [importlib.import_module(m) for m in modules]

        def __getattr__(name):
            if name.startswith("__"):             # the proxy's own dunders: never forwarded
                raise AttributeError(name)
            if name in names:
                return _moved(old, name, names[name], stacklevel=3)
            for target in targets:
                if hasattr(target, name):
                    return getattr(target, name)
            raise AttributeError(f"module {old!r} has no attribute {name!r}")
        module.__doc__ = f"Moved to {', '.join(modules)} (this path goes in {REMOVED_IN})."
        module.__all__ = [n for t in targets for n in getattr(t, "__all__", ())] + list(names)
        module.__getattr__ = __getattr__
        module.__dir__ = lambda: sorted(set(module.__all__))
        if any(hasattr(t, "__path__") for t in targets):   # a package: submodules resolve too
            module.__path__ = []


def alias_modules(aliases: dict) -> None:
    """Keep old module paths importable.

    Parameters
    ----------
    aliases : dict
        Old module path -> where its names are now: a module path, a mapping
        as :func:`moved_names` takes, or a sequence of those (searched in
        order). Old paths of submodules of an aliased package need their own
        entries.
    """
    sys.meta_path.insert(0, _ModuleAliases(aliases))


def moved_names(module: str, moved: dict, *, wrapped: bool = False):
    """A module ``__getattr__`` serving names that moved out of `module`.

    Parameters
    ----------
    module : str
        The module's ``__name__``.
    moved : dict
        Old name -> ``"new.module:name"``, or -> ``("new.module:name", adapter)``
        where ``adapter()`` builds what the old name gave (the new function
        under the old signature, say).
    wrapped : bool
        The module's own ``__getattr__`` calls this one (e.g. that of
        :func:`mocap.util.lazy.lazy_names`): the warning skips its frame too.
    """
    def __getattr__(name):
        if name not in moved:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        return _moved(module, name, moved[name], stacklevel=3 + wrapped)
    return __getattr__
