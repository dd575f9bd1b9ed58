"""Optional dependencies: import a package of an extra, or say which extra installs it.

The core install of mocap2mesh is MIT-clean; packages under other licences
(Praat through ``praat-parselmouth``, GPL-3.0; FFmpeg through PyAV, a GPL build)
live in optional extras (``pip install 'mocap2mesh[speech]'``). Code that needs
one imports it through :func:`require`, at the point of use, so that the rest
of the package never imports it.
"""

from __future__ import annotations

import contextlib
import importlib
import sys
import warnings

from mocap.errors import MissingDependencyError

__all__ = ["require", "available", "compiled", "compiled_if_worth", "load_numba",
           "numba_loaded"]


def require(module: str, *, package: str, extra: str, purpose: str):
    """Import `module`, or raise :class:`MissingDependencyError` naming the extra.

    Parameters
    ----------
    module : str
        Importable name (``parselmouth``).
    package : str
        Its distribution on PyPI (``praat-parselmouth``), named in the error.
    extra : str
        The mocap2mesh extra that installs it.
    purpose : str
        What needs it, starting the error message.

    Returns
    -------
    module

    Raises
    ------
    MissingDependencyError
        The module cannot be imported.

    Examples
    --------
    >>> require("math", package="math", extra="none", purpose="sqrt").sqrt(4.0)
    2.0
    """
    try:
        return importlib.import_module(module)
    except ImportError:
        raise MissingDependencyError(package, extra, purpose) from None


def available(module: str) -> bool:
    """True when `module` can be imported (the extra that brings it is installed)."""
    try:
        importlib.import_module(module)
    except ImportError:
        return False
    return True


def compiled(module: str, name: str, *, what: str, fallback: str):
    """The function `name` of `module`, a numba kernel of the ``speed`` extra, or None.

    None without numba, and where numba can keep its compiled code nowhere (a read-only
    install and home: numba raises RuntimeError at import); that case is warned once per
    call, saying what is off (`what`), what does the work instead (`fallback`) and that
    ``NUMBA_CACHE_DIR`` turns it back on. Callers cache the result.
    """
    try:
        return getattr(importlib.import_module(module), name)
    except ImportError:                 # numba is optional: the `speed` extra
        return None
    except RuntimeError as exc:         # numba's "cannot cache function ...": no folder to write
        warnings.warn(f"the compiled {what} is off ({exc}); {fallback}: set NUMBA_CACHE_DIR "
                      "to a writable folder", stacklevel=4)
        return None


def compiled_if_worth(loader, work: int, worth: int):
    """``loader()`` (a module's cached :func:`compiled` kernel, or None) in a process that
    has loaded numba, or for `work` of at least `worth`; else None, and NumPy does the work.

    Loading numba and a kernel's machine code costs a process about half a second, which
    only large work pays back; a process that has loaded it (``mocap2mesh run``'s fit)
    uses the kernel for any work.
    """
    return loader() if numba_loaded() or work >= worth else None


def load_numba() -> None:
    """Import numba (the ``speed`` extra) when it is installed: for a process that will use
    its kernels anyway, so that work before them which :func:`compiled_if_worth` would
    leave to NumPy takes them too."""
    with contextlib.suppress(ImportError):
        importlib.import_module("numba")


def numba_loaded() -> bool:
    """Whether this process has imported numba (its kernels then cost no more to load)."""
    return "numba" in sys.modules
