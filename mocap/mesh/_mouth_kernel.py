"""The lip gap's pair distances as one compiled loop (numba, the ``speed`` extra).

:meth:`mocap.mesh.mouth.MouthOpening.gap` in NumPy expands every pair's squared distance
as ``‖u‖² + ‖l‖² − 2 u·l`` (a product of blocks of frames, then a reduction of the
block), which loses digits with the points' squared distance from their centre; this
takes each pair's coordinate differences directly, frame by frame, without the GIL,
exact but for the rounding of three squares and two sums.

It measures only the pairs that can be the nearest. Along the axis from the lower lip's
centroid to the upper lip's, two points are at least as far apart in space as their
projections are; so once some pair is known to be `r` apart, an upper point projected
more than `r` above the lower lip's highest point, or a lower point more than `r` below
the upper lip's lowest, has no nearer partner. The known pair is the nearer of the
frame before's nearest pair (the lips move little from frame to frame) and the two
points nearest each other along the axis. Of a 35,000-frame take of the ICT face's lips
about a sixth of the pairs are left (more while the lips touch, fewer while they part);
the least of them is the least of all, to the bit.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["least_squared_distances"]

#: The reach of the known pair is widened by this share of itself and of the points' extent
#: about the lower lip's centroid, far above the rounding of the projections (a few units
#: in the last place of that extent) and of the square root: a pair the rounding would have
#: kept is never left out.
_ROUNDING_MARGIN = 1e-9


@numba.njit(cache=True, inline="always")
def _squared(ux, uy, uz, px, py, pz):  # pragma: no cover - compiled
    """The squared distance of two points, ``(dx·dx + dy·dy) + dz·dz``."""
    dx, dy, dz = ux - px, uy - py, uz - pz
    return dx * dx + dy * dy + dz * dz


@numba.njit(cache=True, nogil=True)
def least_squared_distances(x, n_up, out):  # pragma: no cover - compiled; tested against NumPy
    """The least squared distance between the points ``[:n_up]`` and ``[n_up:]`` of each
    frame of `x` (T, n, 3) into `out` (T,); NaN in a frame with a coordinate that is not
    finite, inf where one side has no point.

    A pair's is ``(dx·dx + dy·dy) + dz·dz``, summed in that order, of the pairs that can
    be the nearest (:func:`_candidates`); the frames in order, each starting from the
    nearest pair of the frame before.
    """
    n_low = x.shape[1] - n_up
    # the candidates' coordinates, each side's copied coordinate by coordinate, and ids
    ux, uy, uz = np.empty(n_up), np.empty(n_up), np.empty(n_up)
    lx, ly, lz = np.empty(n_low), np.empty(n_low), np.empty(n_low)
    up_ids, low_ids = np.empty(n_up, np.int64), np.empty(n_low, np.int64)
    along, least = np.empty(x.shape[1]), np.empty(n_low)
    near_up = near_low = -1                 # the frame before's nearest pair
    for t in range(x.shape[0]):
        m_up, m_low = _candidates(x[t], n_up, near_up, near_low, ux, uy, uz, up_ids, lx, ly,
                                  lz, low_ids, along)
        if m_up < 0:
            out[t] = np.nan
            near_up = near_low = -1
            continue
        out[t], i, j = _least_pair(ux, uy, uz, m_up, lx, ly, lz, m_low, least)
        near_up, near_low = (up_ids[i], low_ids[j]) if i >= 0 else (-1, -1)


@numba.njit(cache=True, nogil=True)
def _candidates(frame, n_up, near_up, near_low, ux, uy, uz, up_ids, lx, ly, lz, low_ids,
                along):  # pragma: no cover - compiled
    """Copy the points of `frame` (n, 3) that can be in its nearest pair into `ux`.. and
    `lx`.. (their ids into `up_ids`, `low_ids`); returns how many of each side, or
    (-1, -1) for a frame with a coordinate that is not finite. `near_up`, `near_low`: a
    pair to start from (-1: none); `along` is scratch (n,)."""
    n = frame.shape[0]
    n_low = n - n_up
    cux = cuy = cuz = clx = cly = clz = 0.0
    for k in range(n_up):
        cux, cuy, cuz = cux + frame[k, 0], cuy + frame[k, 1], cuz + frame[k, 2]
    for k in range(n_up, n):
        clx, cly, clz = clx + frame[k, 0], cly + frame[k, 1], clz + frame[k, 2]
    prune = n_up > 0 and n_low > 0
    # a coordinate that is not finite makes its side's sums so; sums of finite points that
    # overflow leave every pair to measure
    if not (np.isfinite(cux + cuy + cuz) and np.isfinite(clx + cly + clz)):
        if not _finite(frame):
            return -1, -1
        prune = False
    if prune:
        clx, cly, clz = clx / n_low, cly / n_low, clz / n_low
        ax, ay, az = cux / n_up - clx, cuy / n_up - cly, cuz / n_up - clz
        norm = np.sqrt(ax * ax + ay * ay + az * az)
        prune = norm > 0.0
    reach = np.inf
    lowest_up, highest_low = 0, n_up
    if prune:
        ax, ay, az = ax / norm, ay / norm, az / norm
        extent = 0.0
        for k in range(n):
            dx, dy, dz = frame[k, 0] - clx, frame[k, 1] - cly, frame[k, 2] - clz
            p = dx * ax + dy * ay + dz * az
            along[k] = p
            extent = max(extent, abs(dx) + abs(dy) + abs(dz))
            if k < n_up:
                lowest_up = k if p < along[lowest_up] else lowest_up
            elif p > along[highest_low]:
                highest_low = k
        a, b = frame[lowest_up], frame[highest_low]
        known = _squared(a[0], a[1], a[2], b[0], b[1], b[2])
        if near_up >= 0:
            a, b = frame[near_up], frame[n_up + near_low]
            known = min(known, _squared(a[0], a[1], a[2], b[0], b[1], b[2]))
        reach = np.sqrt(known)
        reach += _ROUNDING_MARGIN * (reach + extent)
    m_up = m_low = 0
    for k in range(n_up):
        if not prune or along[k] <= along[highest_low] + reach:
            ux[m_up], uy[m_up], uz[m_up], up_ids[m_up] = frame[k, 0], frame[k, 1], \
                frame[k, 2], k
            m_up += 1
    for k in range(n_up, n):
        if not prune or along[k] >= along[lowest_up] - reach:
            lx[m_low], ly[m_low], lz[m_low], low_ids[m_low] = frame[k, 0], frame[k, 1], \
                frame[k, 2], k - n_up
            m_low += 1
    return m_up, m_low


@numba.njit(cache=True, nogil=True)
def _finite(frame) -> bool:  # pragma: no cover - compiled
    """Whether every coordinate of `frame` (n, 3) is finite."""
    for k in range(frame.shape[0]):
        if not (np.isfinite(frame[k, 0]) and np.isfinite(frame[k, 1])
                and np.isfinite(frame[k, 2])):
            return False
    return True


@numba.njit(cache=True, nogil=True)
def _least_pair(ux, uy, uz, m_up, lx, ly, lz, m_low, least):  # pragma: no cover - compiled
    """The least squared distance between the first `m_up` points of `ux`.. and the first
    `m_low` of `lx`.., and which pair it is (-1, -1 for none); `least` is scratch.

    The upper points, four at a time, lower the running least of every lower point (no
    reduction along the inner loop, so that it runs on the vector units; each lower
    point's coordinates and least are loaded once for four upper points).
    """
    for j in range(m_low):
        least[j] = np.inf
    i = 0
    while i + 4 <= m_up:
        ax, ay, az = ux[i], uy[i], uz[i]
        bx, by, bz = ux[i + 1], uy[i + 1], uz[i + 1]
        cx, cy, cz = ux[i + 2], uy[i + 2], uz[i + 2]
        ex, ey, ez = ux[i + 3], uy[i + 3], uz[i + 3]
        for j in range(m_low):
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
    while i < m_up:
        px, py, pz = ux[i], uy[i], uz[i]
        for j in range(m_low):
            d = _squared(px, py, pz, lx[j], ly[j], lz[j])
            least[j] = d if d < least[j] else least[j]
        i += 1
    gap, low = np.inf, -1
    for j in range(m_low):
        if least[j] < gap:
            gap, low = least[j], j
    if low >= 0:
        for i in range(m_up):
            if _squared(ux[i], uy[i], uz[i], lx[low], ly[low], lz[low]) == gap:
                return gap, i, low
    return gap, -1, -1
