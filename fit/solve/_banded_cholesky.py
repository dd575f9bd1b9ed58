"""LAPACK's banded Cholesky factorization (``dpbtrf``) without holding the GIL.

SciPy's :func:`scipy.linalg.cholesky_banded` calls the same routine through an f2py wrapper
that keeps the GIL while it factors, so nothing else of the process's Python runs
meanwhile. This calls it through SciPy's Cython LAPACK (:mod:`scipy.linalg.cython_lapack`,
whose function pointers SciPy exports for such use) by :mod:`ctypes`, which releases the
GIL for the call: a factorization on a thread of its own then runs beside the caller's
work (the smooth solve factors the next state while the marker-centre fit evaluates its
model). Same routine, same library: the same factor, bit for bit. A SciPy that exports
the routine with another C signature than the one called here is not called blind: its
:func:`scipy.linalg.cholesky_banded` factors instead, with the GIL held.
"""

from __future__ import annotations

import ctypes
import functools
import re

import numpy as np
import scipy.linalg
import scipy.linalg.cython_lapack

__all__ = ["cholesky_banded_upper"]


#: The C signature (the capsule's name) of the ``dpbtrf`` called here: 32-bit LAPACK
#: integers, the band as doubles (SciPy's typedef ``d``).
_SIGNATURE = re.compile(rb"void \(char \*, int \*, int \*, (?:\w*_)?d \*, int \*, int \*\)")


@functools.cache
def _dpbtrf():
    """``dpbtrf(uplo, n, kd, ab, ldab, info)`` of SciPy's LAPACK, callable by ctypes;
    None when SciPy exports it with another signature."""
    capsule = scipy.linalg.cython_lapack.__pyx_capi__.get("dpbtrf")
    # prototypes of our own: ctypes.pythonapi's functions are shared by every library
    get_name = ctypes.PYFUNCTYPE(ctypes.c_char_p, ctypes.py_object)(
        ("PyCapsule_GetName", ctypes.pythonapi))
    get_pointer = ctypes.PYFUNCTYPE(ctypes.c_void_p, ctypes.py_object, ctypes.c_char_p)(
        ("PyCapsule_GetPointer", ctypes.pythonapi))
    name = None if capsule is None else get_name(capsule)
    if name is None or not _SIGNATURE.fullmatch(name):
        return None
    address = get_pointer(capsule, name)
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
        U in the same storage, for :func:`scipy.linalg.cho_solve_banded` with
        ``lower=False``: `ab` itself (but for SciPy's own factorization, see above).

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
    dpbtrf = _dpbtrf()
    if dpbtrf is None:
        return scipy.linalg.cholesky_banded(ab, overwrite_ab=True, check_finite=False)
    info = ctypes.c_int(0)
    dpbtrf(b"U", ctypes.c_int(ab.shape[1]), ctypes.c_int(ab.shape[0] - 1),
              ab.ctypes.data, ctypes.c_int(ab.shape[0]), info)
    if info.value > 0:
        raise np.linalg.LinAlgError(f"{info.value}-th leading minor not positive definite")
    if info.value < 0:
        raise ValueError(f"dpbtrf rejected argument {-info.value}")
    return ab
