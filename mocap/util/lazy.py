"""Package namespaces whose names are imported from their modules on first use (PEP 562).

A package that re-exports the public names of its modules imports every one of them,
and what they import, as soon as any of its modules is imported: ``mocap2mesh run``
needs one function of :mod:`fit.gestures` and would otherwise pay for the speech
analysis' imports (``scipy.signal``, 0.4 s). A lazy package imports a module when one
of its names is first read, and keeps the name (later reads are plain attributes).

Examples
--------
In a package's ``__init__.py``::

    __getattr__, __dir__ = lazy_names(__name__, {"speech": ["read_wav"]})
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Iterable, Mapping

__all__ = ["lazy_names"]


def lazy_names(package: str, modules: Mapping[str, Iterable[str]], *,
               otherwise: Callable | None = None) -> tuple[Callable, Callable]:
    """A package's ``__getattr__`` and ``__dir__`` that import its names when first read.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    modules : mapping of str to iterable of str
        Submodule (relative to `package`) to the public names it defines.
    otherwise : callable, optional
        ``otherwise(name)`` for a name no submodule defines (e.g. the ``__getattr__``
        of :func:`mocap.util.deprecation.moved_names`); default: AttributeError.

    Returns
    -------
    (__getattr__, __dir__)
    """
    home = {name: f"{package}.{module}" for module, names in modules.items()
            for name in names}

    def __getattr__(name):
        if name not in home:
            if otherwise is not None:
                return otherwise(name)
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(home[name]), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__():
        return sorted(set(vars(sys.modules[package])) | set(home))

    return __getattr__, __dir__
