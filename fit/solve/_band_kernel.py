"""The smooth solve's banded matrix written as one compiled loop (numba, the ``speed`` extra).

:meth:`fit.solve._smooth._Band.matrix` in NumPy masks a frame's bands by the free weights
of each pair of variables with byte masks and products over pieces of frames, plus two
strided columns: about twice the time of writing the (n + 1, F·n) floats once, which this
does, column after column. The same values, bit for bit (the same products by 1.0 or 0.0
and the same sums), so that the factorization that follows is the same too.
:func:`free_band_matrix` writes the matrix of the free weights only
(:meth:`~fit.solve._smooth._Band.free_matrix`), which the whole sequence's factorizations
take: a whole take's full matrix is 800 MB at 35,000 frames × 53 weights.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["band_matrix", "free_band_matrix"]


@numba.njit(cache=True, nogil=True)
def band_matrix(bands, g_diag, ridge, lam, fill, free, deg, link,
                ab):  # pragma: no cover - compiled; tested against the NumPy matrix
    """Write the upper banded reduced Hessian of a run of frames into `ab`.

    Parameters
    ----------
    bands : ndarray of shape (n, n - 1)
        ``bands[i, r - 1]``: G's entry of storage row r (band n - r) in a frame's column
        i, 0 where the band leaves the frame.
    g_diag : ndarray of shape (n,)
        G's diagonal.
    ridge, lam, fill : float
        The ridge added to G's diagonal, λ, and the diagonal of a bound variable's row.
    free : ndarray of bool, shape (F, n)
    deg : ndarray of shape (F,)
        Each frame's degree in the path.
    link : ndarray of bool, shape (F - 1,)
        True where a frame is coupled to the next one.
    ab : ndarray of shape (n + 1, F n), Fortran-ordered
        Out: LAPACK's upper band storage.
    """
    n_frames, n = free.shape
    for t in range(n_frames):
        tied = t > 0 and link[t - 1]
        diffusion = lam * deg[t]
        for i in range(n):
            j = t * n + i
            own = free[t, i]
            ab[n, j] = (g_diag[i] + ridge) + diffusion if own else fill
            ab[0, j] = -lam * (1.0 if own and tied and free[t - 1, i] else 0.0)
            for r in range(1, n):
                # the variable n - r before this one; in the frame before, the band is 0
                other = i - (n - r)
                both = own and other >= 0 and free[t, other]
                ab[r, j] = bands[i, r - 1] * (1.0 if both else 0.0)


@numba.njit(cache=True, nogil=True)
def free_band_matrix(G, g_diag, ridge, lam, free, deg, link,
                     ab):  # pragma: no cover - compiled; tested against the NumPy matrix
    """Write the upper banded reduced Hessian of the free weights only into `ab`.

    As :func:`band_matrix`, but a column per free weight (frame by frame, each frame's in
    order) and `ab` of shape (kd + 1, N), Fortran-ordered, for N free weights and kd the
    bands they need (:meth:`fit.solve._smooth._Band.free_bands`); G (n, n) whole.
    """
    n_frames, n = free.shape
    kd = ab.shape[0] - 1
    before = np.full(n, -1, np.int64)   # each weight's column in the frame before (-1: bound)
    here = np.full(n, -1, np.int64)
    own = np.empty(n, np.int64)         # this frame's free weights so far
    c = 0
    for t in range(n_frames):
        tied = t > 0 and link[t - 1]
        diffusion = lam * deg[t]
        m = 0
        for i in range(n):
            if not free[t, i]:
                here[i] = -1
                continue
            for r in range(kd):
                ab[r, c] = 0.0
            ab[kd, c] = (g_diag[i] + ridge) + diffusion
            for k in range(m):          # the frame's free weights before this one
                ab[kd - (m - k), c] = G[own[k], i]
            if tied and before[i] >= 0:
                ab[kd - (c - before[i]), c] = -lam
            own[m] = i
            here[i] = c
            m += 1
            c += 1
        before, here = here, before
