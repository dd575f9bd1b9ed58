"""Vectorized ray/segment-triangle and triangle-triangle tests, and a triangle AABB index.

Private numerics of the Maskle: every function works on stacks of pairs at
once (no Python loop over triangles).
"""

from __future__ import annotations

import numpy as np

#: A ray is parallel to a triangle when |det| is below this fraction of
#: |d| |e1| |e2| (Möller–Trumbore).
_PARALLEL_RTOL = 1e-12


def segment_params(origins, directions, tri):
    """Möller–Trumbore for paired rays and triangles.

    Parameters
    ----------
    origins, directions : ndarray of shape (M, 3)
    tri : ndarray of shape (M, 3, 3)
        Triangle corners.

    Returns
    -------
    t, u, v : ndarray of shape (M,)
        Hit point ``origins + t * directions = (1-u-v) a + u b + v c``; NaN
        where the ray is parallel to the triangle's plane.
    """
    a = tri[:, 0]
    e1 = tri[:, 1] - a
    e2 = tri[:, 2] - a
    h = np.cross(directions, e2)
    det = np.einsum("ij,ij->i", e1, h)
    scale = (np.linalg.norm(directions, axis=1) * np.linalg.norm(e1, axis=1)
             * np.linalg.norm(e2, axis=1))
    ok = np.abs(det) > _PARALLEL_RTOL * scale
    inv = np.divide(1.0, det, out=np.full_like(det, np.nan), where=ok)
    s = origins - a
    u = inv * np.einsum("ij,ij->i", s, h)
    q = np.cross(s, e1)
    v = inv * np.einsum("ij,ij->i", directions, q)
    t = inv * np.einsum("ij,ij->i", e2, q)
    return t, u, v


def _inside(u, v) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return (u >= 0) & (v >= 0) & (u + v <= 1)


def segments_cross(p0, p1, tri) -> np.ndarray:
    """True where segment ``p0 -> p1`` (M, 3) meets triangle `tri` (M, 3, 3)."""
    t, u, v = segment_params(p0, p1 - p0, tri)
    with np.errstate(invalid="ignore"):
        return _inside(u, v) & (t >= 0) & (t <= 1)


def _one_side(tri_a, tri_b) -> np.ndarray:
    """True where every corner of `tri_b` lies strictly on one side of `tri_a`'s plane."""
    n = np.cross(tri_a[:, 1] - tri_a[:, 0], tri_a[:, 2] - tri_a[:, 0])
    d = np.einsum("ij,ikj->ik", n, tri_b - tri_a[:, :1])
    return np.all(d > 0, axis=1) | np.all(d < 0, axis=1)


def triangles_intersect(tri_a, tri_b) -> np.ndarray:
    """Pairwise triangle-triangle intersection test.

    Pairs with one triangle strictly on one side of the other's plane are
    rejected first; for the rest, two triangles in general position intersect
    iff an edge of one crosses the other (the intersection segment ends on
    such crossings). Coplanar overlapping pairs (a measure-zero case for
    moving meshes) count as disjoint.

    Parameters
    ----------
    tri_a, tri_b : ndarray of shape (M, 3, 3)

    Returns
    -------
    ndarray of bool, shape (M,)
    """
    hit = np.zeros(len(tri_a), dtype=bool)
    maybe = np.flatnonzero(~_one_side(tri_a, tri_b))
    maybe = maybe[~_one_side(tri_b[maybe], tri_a[maybe])]
    tri_a, tri_b = tri_a[maybe], tri_b[maybe]
    found = np.zeros(len(maybe), dtype=bool)
    for first, second in ((tri_a, tri_b), (tri_b, tri_a)):
        for i, j in ((0, 1), (1, 2), (2, 0)):
            todo = ~found
            found[todo] = segments_cross(first[todo, i], first[todo, j], second[todo])
    hit[maybe] = found
    return hit


def triangle_normals(tri: np.ndarray) -> np.ndarray:
    """Unit normals (T, 3) of triangles (T, 3, 3), right-handed corner order (0 if degenerate)."""
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def nearest_ray_hits(origins, directions, index: "TriangleIndex", max_distance: float, *,
                     min_cosine: float | None = None):
    """Nearest hit of bidirectional rays (lines) against an indexed triangle set.

    Parameters
    ----------
    origins, directions : ndarray of shape (R, 3)
        Unit directions.
    index : TriangleIndex
        The triangles (T, 3, 3).
    max_distance : float
        Hits farther than this from the origin are ignored (and never tested:
        only triangles whose box meets the origin's ``max_distance`` box are).
    min_cosine : float, optional
        Only triangles whose normal makes a cosine above this with the ray's
        direction count (a surface facing the same way); None: any triangle.

    Returns
    -------
    face : ndarray of int64, shape (R,)
        Triangle hit, -1 where the line misses every triangle.
    t : ndarray of shape (R,)
        Signed distance along the direction to the hit (NaN where missed).
    """
    face = np.full(len(origins), -1, dtype=np.int64)
    best = np.full(len(origins), np.nan)
    r, f = index.pairs(origins - max_distance, origins + max_distance)
    t, u, v = segment_params(origins[r], directions[r], index.tri[f])
    with np.errstate(invalid="ignore"):
        ok = _inside(u, v) & (np.abs(t) <= max_distance)
    if min_cosine is not None:
        ok &= np.einsum("ij,ij->i", directions[r], triangle_normals(index.tri)[f]) > min_cosine
    r, f, t = r[ok], f[ok], t[ok]
    order = np.lexsort((np.abs(t), r))
    r, f, t = r[order], f[order], t[order]
    first = np.r_[True, r[1:] != r[:-1]][:len(r)]        # (no hit at all: empty)
    face[r[first]] = f[first]
    best[r[first]] = t[first]
    return face, best


class TriangleIndex:
    """An R-tree over the bounding boxes of a triangle set (rtree, bulk-loaded).

    Parameters
    ----------
    tri : ndarray of shape (T, 3, 3)
    """

    def __init__(self, tri: np.ndarray):
        from rtree.index import Index, Property

        self.tri = tri
        prop = Property()
        prop.dimension = 3
        lo, hi = tri.min(axis=1), tri.max(axis=1)
        self._index = Index((np.arange(len(tri), dtype=np.int64), lo, hi),
                            properties=prop) if len(tri) else None

    def pairs(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(query id, triangle id) for every query box (Q, 3) overlapping a triangle box."""
        if self._index is None or len(lo) == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        ids, counts = self._index.intersection_v(lo, hi)
        return (np.repeat(np.arange(len(lo)), counts.astype(np.int64)),
                np.asarray(ids).astype(np.int64))
