"""The smooth solve's banded matrix written as one compiled loop (numba, the ``speed`` extra).

:meth:`fit.solve._smooth._Band.matrix` in NumPy gathers the free weights' entries of G by
fancy indexing, the columns of each place among their frame's free weights at once, over
a zeroed band: four to five times the time of this loop, which writes each column once.
The same values, bit for bit (the same sums, the zeros' signs too), so that the
factorization that follows is the same too. The whole sequence's band is formed for
every factorization of the smooth solve (up to 800 MB at 35,000 frames × 53 weights).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["band_matrix"]


@numba.njit(cache=True, nogil=True)
def band_matrix(G_rows, g_diag, ridge, lam, free, deg, link,
                ab):  # pragma: no cover - compiled; tested against the NumPy matrix
    """Write the upper banded reduced Hessian of the free weights into `ab`.

    Parameters
    ----------
    G_rows : ndarray of shape (n, n), C-contiguous
        Gᵀ: row i is G's column i (read along a row).
    g_diag : ndarray of shape (n,)
        G's diagonal.
    ridge, lam : float
        The ridge added to G's diagonal, and λ.
    free : ndarray of bool, shape (F, n)
    deg : ndarray of shape (F,)
        Each frame's degree in the path.
    link : ndarray of bool, shape (F - 1,)
        True where a frame is coupled to the next one.
    ab : ndarray of shape (kd + 1, N), Fortran-ordered
        Out: LAPACK's upper band storage, a column per free weight (frame by frame, each
        frame's in order), kd the bands they need
        (:meth:`fit.solve._smooth._Band.bandwidth`).
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
            # above the frame's entries (the weight itself in the frame before is farther
            # back than its frame's m), zeros but that coupling
            for r in range(kd - m):
                ab[r, c] = 0.0
            if tied and before[i] >= 0:
                ab[kd - (c - before[i]), c] = -lam
            for k in range(m):          # the frame's free weights before this one
                ab[kd - (m - k), c] = G_rows[i, own[k]]
            ab[kd, c] = (g_diag[i] + ridge) + diffusion
            own[m] = i
            here[i] = c
            m += 1
            c += 1
        before, here = here, before
