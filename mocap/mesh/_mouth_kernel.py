"""The lip gap's pair distances as one compiled loop (numba, the ``speed`` extra).

:meth:`mocap.mesh.mouth.MouthOpening.gap` in NumPy expands every pair's squared distance
as ``‖u‖² + ‖l‖² − 2 u·l`` (a product of blocks of frames, then a reduction of the
block), which loses digits with the points' squared distance from their centre; this
takes each pair's coordinate differences directly, frame by frame, without the GIL:
about twice as fast, and exact but for the rounding of three squares and two sums.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["least_squared_distances"]


@numba.njit(cache=True, inline="always")
def _squared(ux, uy, uz, px, py, pz):  # pragma: no cover - compiled
    """The squared distance of two points, ``(dx·dx + dy·dy) + dz·dz``."""
    dx, dy, dz = ux - px, uy - py, uz - pz
    return dx * dx + dy * dy + dz * dz


@numba.njit(cache=True, nogil=True)
def least_squared_distances(x, n_up, out):  # pragma: no cover - compiled; tested against NumPy
    """The least squared distance between the points ``[:n_up]`` and ``[n_up:]`` of each
    frame of `x` (T, n, 3) into `out` (T,); NaN in a frame with a coordinate that is not
    finite.

    A pair's is ``(dx·dx + dy·dy) + dz·dz``, summed in that order. The lower lip's points
    are copied coordinate by coordinate once a frame, and the upper points, four at a
    time, lower the running least of every lower point (no reduction along the inner loop,
    so that it runs on the vector units; each lower point's coordinates and least are
    loaded once for four upper points); the frame's gap is the least of those.
    """
    n_low = x.shape[1] - n_up
    lx, ly, lz = np.empty(n_low), np.empty(n_low), np.empty(n_low)
    least = np.empty(n_low)
    for t in range(x.shape[0]):
        finite = True
        for j in range(n_low):
            lx[j], ly[j], lz[j] = x[t, n_up + j, 0], x[t, n_up + j, 1], x[t, n_up + j, 2]
            finite &= np.isfinite(lx[j]) & np.isfinite(ly[j]) & np.isfinite(lz[j])
            least[j] = np.inf
        i = 0
        while i + 4 <= n_up:
            ax, ay, az = x[t, i, 0], x[t, i, 1], x[t, i, 2]
            bx, by, bz = x[t, i + 1, 0], x[t, i + 1, 1], x[t, i + 1, 2]
            cx, cy, cz = x[t, i + 2, 0], x[t, i + 2, 1], x[t, i + 2, 2]
            ex, ey, ez = x[t, i + 3, 0], x[t, i + 3, 1], x[t, i + 3, 2]
            finite &= (np.isfinite(ax) & np.isfinite(ay) & np.isfinite(az)
                       & np.isfinite(bx) & np.isfinite(by) & np.isfinite(bz)
                       & np.isfinite(cx) & np.isfinite(cy) & np.isfinite(cz)
                       & np.isfinite(ex) & np.isfinite(ey) & np.isfinite(ez))
            for j in range(n_low):
                px, py, pz = lx[j], ly[j], lz[j]
                da = _squared(ax, ay, az, px, py, pz)
                db = _squared(bx, by, bz, px, py, pz)
                dc = _squared(cx, cy, cz, px, py, pz)
                de = _squared(ex, ey, ez, px, py, pz)
                m = least[j]
                m = da if da < m else m
                m = db if db < m else m
                m = dc if dc < m else m
                least[j] = de if de < m else m
            i += 4
        while i < n_up:
            ux, uy, uz = x[t, i, 0], x[t, i, 1], x[t, i, 2]
            finite &= np.isfinite(ux) & np.isfinite(uy) & np.isfinite(uz)
            for j in range(n_low):
                d = _squared(ux, uy, uz, lx[j], ly[j], lz[j])
                least[j] = d if d < least[j] else least[j]
            i += 1
        gap = np.inf
        for j in range(n_low):
            gap = least[j] if least[j] < gap else gap
        out[t] = gap if finite else np.nan
