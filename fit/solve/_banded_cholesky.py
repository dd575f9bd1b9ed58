"""LAPACK's banded Cholesky factorization and solve (``dpbtrf``, ``dpbtrs``) without
holding the GIL.

SciPy's :func:`scipy.linalg.cholesky_banded` and :func:`scipy.linalg.cho_solve_banded` call
the same routines through f2py wrappers that keep the GIL while they run, so nothing else of
the process's Python runs meanwhile. These call them through SciPy's Cython LAPACK
(:mod:`scipy.linalg.cython_lapack`, whose function pointers SciPy exports for such use) by
:mod:`ctypes`, which releases the GIL for the call: a factorization or solves on a thread of
their own then run beside the caller's work (the smooth solve prepares the next state's
factor, or the columns that border the kept one, while the marker-centre fit evaluates its
model). Same routines, same library: the same results, bit for bit. A SciPy that exports a
routine with another C signature than the one called here is not called blind: its own
wrapper runs instead, with the GIL held.
"""

from __future__ import annotations

import ctypes
import functools
import re

import numpy as np
import scipy.linalg
import scipy.linalg.cython_lapack

__all__ = ["cho_solve_banded_upper", "cholesky_banded_upper"]


#: The C signatures (the capsules' names) of the routines called here: 32-bit LAPACK
#: integers, the band and the right-hand sides as doubles (SciPy's typedef ``d``).
_DOUBLES = rb"(?:\w*_)?d \*"
_SIGNATURE = re.compile(rb"void \(char \*, int \*, int \*, " + _DOUBLES + rb", int \*, int \*\)")
_SOLVE_SIGNATURE = re.compile(rb"void \(char \*, int \*, int \*, int \*, " + _DOUBLES
                              + rb", int \*, " + _DOUBLES + rb", int \*, int \*\)")


def _routine(name: str, signature: re.Pattern, *argtypes):
    """SciPy's LAPACK routine `name`, callable by ctypes with `argtypes`; None when SciPy
    does not export it with `signature`."""
    capsule = scipy.linalg.cython_lapack.__pyx_capi__.get(name)
    # prototypes of our own: ctypes.pythonapi's functions are shared by every library
    get_name = ctypes.PYFUNCTYPE(ctypes.c_char_p, ctypes.py_object)(
        ("PyCapsule_GetName", ctypes.pythonapi))
    get_pointer = ctypes.PYFUNCTYPE(ctypes.c_void_p, ctypes.py_object, ctypes.c_char_p)(
        ("PyCapsule_GetPointer", ctypes.pythonapi))
    capsule_name = None if capsule is None else get_name(capsule)
    if capsule_name is None or not signature.fullmatch(capsule_name):
        return None
    return ctypes.CFUNCTYPE(None, *argtypes)(get_pointer(capsule, capsule_name))


_INTEGER = ctypes.POINTER(ctypes.c_int)


@functools.cache
def _dpbtrf():
    """``dpbtrf(uplo, n, kd, ab, ldab, info)``, or None (see :func:`_routine`)."""
    return _routine("dpbtrf", _SIGNATURE, ctypes.c_char_p, _INTEGER, _INTEGER,
                    ctypes.c_void_p, _INTEGER, _INTEGER)


@functools.cache
def _dpbtrs():
    """``dpbtrs(uplo, n, kd, nrhs, ab, ldab, b, ldb, info)``, or None (see :func:`_routine`)."""
    return _routine("dpbtrs", _SOLVE_SIGNATURE, ctypes.c_char_p, _INTEGER, _INTEGER, _INTEGER,
                    ctypes.c_void_p, _INTEGER, ctypes.c_void_p, _INTEGER, _INTEGER)


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


def cho_solve_banded_upper(factor: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """``(UᵀU)⁻¹ rhs`` with U from :func:`cholesky_banded_upper`, a new array.

    Parameters
    ----------
    factor : ndarray of shape (kd + 1, N), float64, Fortran-ordered
        U in LAPACK's upper band storage.
    rhs : ndarray of shape (N,)

    Returns
    -------
    ndarray of shape (N,)
        What :func:`scipy.linalg.cho_solve_banded` returns for ``(factor, False)``, bit for
        bit (its own, with the GIL held, when SciPy exports another ``dpbtrs``).
    """
    dpbtrs = _dpbtrs()
    if dpbtrs is None or factor.dtype != np.float64 or not factor.flags.f_contiguous:
        return scipy.linalg.cho_solve_banded((factor, False), rhs, check_finite=False)
    x = np.array(rhs, dtype=np.float64, copy=True)
    if x.shape != (factor.shape[1],):
        raise ValueError(f"rhs must have shape ({factor.shape[1]},), got {x.shape}")
    info = ctypes.c_int(0)
    dpbtrs(b"U", ctypes.c_int(factor.shape[1]), ctypes.c_int(factor.shape[0] - 1),
           ctypes.c_int(1), factor.ctypes.data, ctypes.c_int(factor.shape[0]), x.ctypes.data,
           ctypes.c_int(max(len(x), 1)), info)
    if info.value < 0:
        raise ValueError(f"dpbtrs rejected argument {-info.value}")
    return x
