"""LAPACK's banded Cholesky factorization (``dpbtrf``) without holding the GIL.

SciPy's :func:`scipy.linalg.cholesky_banded` calls the same routine through an f2py wrapper
that keeps the GIL while it factors, so nothing else of the process's Python runs
meanwhile. This calls it through SciPy's Cython LAPACK (:mod:`scipy.linalg.cython_lapack`,
whose function pointers SciPy exports for such use) by :mod:`ctypes`, which releases the
GIL for the call: a factorization on a thread of its own then runs beside the caller's
work (the smooth solve factors the next state while the marker-centre fit evaluates its
model). Same routine, same library: the same factor, bit for bit.
"""

from __future__ import annotations

import ctypes
import functools

import numpy as np
import scipy.linalg.cython_lapack

__all__ = ["cholesky_banded_upper"]


@functools.cache
def _dpbtrf():
    """``dpbtrf(uplo, n, kd, ab, ldab, info)`` of SciPy's LAPACK, callable by ctypes."""
    capsule = scipy.linalg.cython_lapack.__pyx_capi__["dpbtrf"]
    api = ctypes.pythonapi
    api.PyCapsule_GetName.restype = ctypes.c_char_p
    api.PyCapsule_GetName.argtypes = [ctypes.py_object]
    api.PyCapsule_GetPointer.restype = ctypes.c_void_p
    api.PyCapsule_GetPointer.argtypes = [ctypes.py_object, ctypes.c_char_p]
    address = api.PyCapsule_GetPointer(capsule, api.PyCapsule_GetName(capsule))
    integer = ctypes.POINTER(ctypes.c_int)
    return ctypes.CFUNCTYPE(None, ctypes.c_char_p, integer, integer, ctypes.c_void_p,
                            integer, integer)(address)


def cholesky_banded_upper(ab: np.ndarray) -> np.ndarray:
    """Factor the symmetric positive-definite band matrix `ab` in place: ``A = UᵀU``.

    Parameters
    ----------
    ab : ndarray of shape (kd + 1, N), float64, Fortran-ordered
        The upper band in LAPACK's storage, as :func:`scipy.linalg.cholesky_banded`
        takes it (``ab[kd + i − j, j] = A[i, j]``); overwritten by U in the same storage.

    Returns
    -------
    ndarray
        `ab`, holding U (for :func:`scipy.linalg.cho_solve_banded` with ``lower=False``).

    Raises
    ------
    numpy.linalg.LinAlgError
        When A is not positive definite (the leading minor that is not).
    ValueError
        When `ab` is not a writeable, Fortran-ordered float64 band.
    """
    if ab.dtype != np.float64 or ab.ndim != 2 or not ab.flags.f_contiguous \
            or not ab.flags.writeable:
        raise ValueError(f"ab must be a writeable Fortran-ordered float64 band, got "
                         f"{ab.dtype} {ab.shape}")
    info = ctypes.c_int(0)
    _dpbtrf()(b"U", ctypes.c_int(ab.shape[1]), ctypes.c_int(ab.shape[0] - 1),
              ab.ctypes.data, ctypes.c_int(ab.shape[0]), info)
    if info.value > 0:
        raise np.linalg.LinAlgError(f"{info.value}-th leading minor not positive definite")
    if info.value < 0:
        raise ValueError(f"dpbtrf rejected argument {-info.value}")
    return ab
