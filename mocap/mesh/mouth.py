"""The mouth opening of a face mesh: its upper and lower lip, and the lip gap.

A face mesh whose lips are not connected (the ICT face, the demo face) has a
boundary loop around the mouth opening. :func:`find_mouth` picks it with the
mesh landmarks and splits it at the mouth corners into the upper and the
lower lip's edge. The loop is where the mesh ends, often inside the mouth
(the ICT face's lips curl in: its loop is 11 mm open at rest while the lips
touch), so the gap is measured between the lips' surfaces: the vertices
within a band of each edge, over the middle of the mouth, and the gap of a
frame is the smallest distance between the two bands.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from mocap.errors import InputError
from mocap.mesh.mesh import Mesh, boundary_loops, mesh_edges
from mocap.util.arrays import read_only
from mocap.util.optional import compiled, compiled_if_worth
from mocap.util.validation import as_float_array

__all__ = ["MouthOpening", "find_mouth", "UPPER_POINTS", "LOWER_POINTS", "MIDDLE"]

#: Landmarks above the mouth and below it (any one of each tells up from down).
UPPER_POINTS = ("upper_lip_bottom", "upper_lip_top", "subnasale", "nose_tip")
LOWER_POINTS = ("lower_lip_top", "lower_lip_bottom", "chin")
#: The middle of the mouth, as fractions of its width from the left corner: the
#: lips are measured there (at the corners they always touch).
MIDDLE = (0.3, 0.7)
#: Each lip's band: vertices this far along the surface from its edge, as a
#: fraction of the mouth's width (less than the way round a corner to the other lip).
_BAND = 0.25
#: A boundary loop is the mouth when it passes this close to both corner
#: landmarks, as a fraction of the corners' distance.
_CORNER_REACH = 0.35
#: Bytes of one block of frames' lip-pair distances expanded by NumPy
#: (:func:`_expanded_least_squared_distances`, without numba): a block
#: well inside a core's L2 cache (with the factors it is made from) is formed and reduced
#: before it leaves the cache, in memory made once per call (a new array of this size per
#: block would be mapped and its pages faulted in afresh).
_CHUNK_BYTES = 2 ** 20
#: Blocks whose factors NumPy's expansion forms at once (~3 MB for the ICT lips):
#: each block then runs only its product and reduction, which release the GIL, so that
#: threads measuring other frames at the same time do not queue for each other's small
#: steps.
_BLOCKS_PER_BATCH = 32
#: Lip pairs (frames × upper × lower points) from which the compiled gap is worth loading
#: numba in a process that has not (its import and the kernel's load take about 0.4 s; the
#: loop, which measures only the pairs that can be the nearest, saves about 0.6 ns a pair,
#: 0.3 s on 35,000 frames of the ICT lips).
_PAIRS_WORTH_COMPILING = 1_000_000_000


@dataclass(frozen=True, eq=False)
class MouthOpening:
    """The lips of a mesh and how to measure the gap between them.

    Attributes
    ----------
    upper_edge, lower_edge : ndarray of int
        Vertex ids of the mouth opening's upper and lower edge, left corner to
        right corner (both corners in both); empty for ``method="landmarks"``.
    upper, lower : ndarray of int
        Vertices of the upper and the lower lip the gap is measured between.
    method : str
        ``"loop"`` (the lips around the mouth opening's boundary loop) or
        ``"landmarks"`` (a mesh without an opening: the gap between the
        landmark vertices ``upper_lip_bottom`` and ``lower_lip_top``).
    """

    upper_edge: np.ndarray
    lower_edge: np.ndarray
    upper: np.ndarray
    lower: np.ndarray
    method: str

    def __post_init__(self):
        for name in ("upper_edge", "lower_edge", "upper", "lower"):
            object.__setattr__(self, name, read_only(getattr(self, name), copy=True))

    @property
    def vertex_ids(self) -> np.ndarray:
        """Vertices the gap reads (:attr:`upper`, then :attr:`lower`)."""
        return np.r_[self.upper, self.lower]

    def gap(self, positions) -> np.ndarray:
        """The lip gap of each frame: the smallest distance between the two lips.

        Parameters
        ----------
        positions : array_like of shape (..., n, 3)
            Positions of :attr:`vertex_ids` (e.g. ``vertices[..., vertex_ids, :]``),
            any length unit. No NaN.

        Returns
        -------
        ndarray of shape (...)
            The gap, in the unit of `positions`; 0 where the lips touch or cross.

        Raises
        ------
        InputError
            Wrong shape, NaN or infinite values; a lip without vertices.

        Examples
        --------
        >>> import numpy as np
        >>> mouth = MouthOpening([], [], upper=[0, 1], lower=[2], method="loop")
        >>> round(float(mouth.gap(np.array([[0., 1, 0], [1, 1, 0], [0.5, 0, 0]]))), 4)
        1.118
        """
        n_up, n = len(self.upper), len(self.upper) + len(self.lower)
        if not n_up or n == n_up:
            raise InputError(f"the mouth needs vertices on both lips to measure a gap, got "
                             f"{n_up} upper and {n - n_up} lower")
        # only read; a NaN or infinite coordinate makes its frame's gap NaN (below)
        x = as_float_array(positions, "positions", copy=False, check_finite=False)
        if x.ndim < 2 or x.shape[-2:] != (n, 3):
            raise InputError(f"positions must have shape (..., {n}, 3) (the lips' "
                             f"vertices, vertex_ids), got {x.shape}")
        batch = x.shape[:-2]
        out = _least_squared_distances(x.reshape(-1, n, 3), n_up)
        np.sqrt(np.maximum(out, 0.0, out=out), out=out)
        if not np.isfinite(out).all():
            # a NaN or infinite coordinate makes that coordinate of its frame's centre NaN
            # or infinite, so NaN in the centred points (its own at least), in their pairs
            # and in their least: the exact checks name it
            as_float_array(positions, "positions", allow_nan=False, copy=False)
        return out.reshape(batch)


def _least_squared_distances(x: np.ndarray, n_up: int) -> np.ndarray:
    """The least squared distance between the points ``[:n_up]`` and ``[n_up:]`` of each
    frame of `x` (T, n, 3), (T,); NaN in a frame with a NaN or infinite coordinate.

    By the compiled loop of :mod:`mocap.mesh._mouth_kernel` (each pair's coordinate
    differences) in a process that has loaded numba, or for :data:`_PAIRS_WORTH_COMPILING`
    pairs or more; else by :func:`_expanded_least_squared_distances`. The two agree to
    rounding (the compiled one is the more exact), not bit for bit.
    """
    kernel = compiled_if_worth(_compiled_gap, len(x) * n_up * (x.shape[1] - n_up),
                               _PAIRS_WORTH_COMPILING)
    if kernel is None:
        return _expanded_least_squared_distances(x, n_up)
    out = np.empty(len(x))
    kernel(np.ascontiguousarray(x, dtype=np.float64), n_up, out)
    return out


@functools.cache
def _compiled_gap():
    """:func:`mocap.mesh._mouth_kernel.least_squared_distances`, or None (NumPy expands the
    pairs' distances): :func:`mocap.util.optional.compiled`."""
    return compiled("mocap.mesh._mouth_kernel", "least_squared_distances", what="lip gap",
                    fallback="NumPy measures it by products, about half as fast")


@np.errstate(invalid="ignore")              # NaN from a non-finite point: the caller's check
def _expanded_least_squared_distances(x: np.ndarray, n_up: int) -> np.ndarray:
    """:func:`_least_squared_distances` by products of blocks of frames.

    ‖u − l‖² = ‖u‖² + ‖l‖² − 2 u·l: every pair's is one product of [u, 1, ‖u‖²] with
    [−2 l, ‖l‖², 1], a block of frames at a time, then the least of each frame's pairs (one
    reduction over a frame's contiguous pairs: one per upper point, over its few pairs,
    costs more than the product). The factors are formed for :data:`_BLOCKS_PER_BATCH`
    blocks at once, stored coordinate by coordinate, each a contiguous row of points.
    Each frame's points are taken about their centre: the expansion loses digits with
    their squared distance from the origin.
    """
    n = x.shape[1]
    n_low = n - n_up
    block = max(1, min(len(x), _CHUNK_BYTES // (8 * n_up * n_low)))
    batch = max(1, min(len(x), block * _BLOCKS_PER_BATCH))
    upper, lower = np.ones((batch, 5, n_up)), np.ones((batch, 5, n_low))
    pairs = np.empty((block, n_up, n_low))
    out = np.empty(len(x))
    average = np.full(n, 1.0 / n)
    for first in range(0, len(x), batch):
        points = x[first:first + batch]                                     # (m, n, 3)
        m = len(points)
        centre = np.matmul(average, points)[:, :, None]                     # (m, 3, 1)
        frames = points.transpose(0, 2, 1)                                  # (m, 3, n)
        u = np.subtract(frames[:, :, :n_up], centre, out=upper[:m, :3])
        np.einsum("tci,tci->ti", u, u, out=upper[:m, 4])
        low = np.subtract(frames[:, :, n_up:], centre, out=lower[:m, :3])
        np.einsum("tcj,tcj->tj", low, low, out=lower[:m, 3])
        low *= -2.0
        for start in range(0, m, block):
            k = min(block, m - start)
            product = np.matmul(upper[start:start + k].transpose(0, 2, 1),
                                lower[start:start + k], out=pairs[:k])
            out[first + start:first + start + k] = product.reshape(k, -1).min(axis=1)
    return out


def _landmark(landmarks, names, n_vertices):
    found = [landmarks[n] for n in names if n in landmarks]
    for vertex in found:
        if not 0 <= int(vertex) < n_vertices:
            raise InputError(f"landmark vertex {vertex} is not a vertex of the mesh "
                             f"(0..{n_vertices - 1})")
    return [int(v) for v in found]


def find_mouth(mesh: Mesh, landmarks: Mapping[str, int], *,
               middle: tuple = MIDDLE) -> MouthOpening:
    """The mouth opening of `mesh`, found with its landmarks.

    Parameters
    ----------
    mesh : Mesh
        The neutral face (its own units).
    landmarks : mapping of str to int
        Mesh landmarks (:func:`mocap.mesh.landmarks.load_mesh_landmarks`):
        ``mouth_corner_left`` and ``mouth_corner_right``, and one point above
        the mouth (:data:`UPPER_POINTS`) and one below (:data:`LOWER_POINTS`).
    middle : (float, float)
        The span of the mouth the lips are measured over, as fractions of its
        width from the left corner (default :data:`MIDDLE`), within (0, 1).

    Returns
    -------
    MouthOpening

    Raises
    ------
    InputError
        A landmark missing or off the mesh; no mouth opening and no
        ``upper_lip_bottom`` / ``lower_lip_top`` landmarks to measure instead; a
        bad `middle`; lips that cannot be told apart in it.

    Notes
    -----
    The mouth is the boundary loop passing nearest the two corner landmarks
    (within 35 % of their distance of each). It is cut at its two vertices
    farthest apart along the corner-to-corner axis; of the two edges the upper
    lip's is the one lying farther towards the upper landmarks. Each lip is
    the set of vertices within a quarter of the mouth's width of its edge
    along the mesh's edges (Dijkstra), within `middle` of the width.
    """
    if not isinstance(mesh, Mesh):
        raise InputError(f"mesh must be a mocap.mesh.mesh.Mesh, got {type(mesh).__name__}")
    lo, hi = (float(x) for x in as_float_array(middle, "middle", shape=(2,), allow_nan=False))
    if not 0.0 < lo < hi < 1.0:
        raise InputError(f"middle must be two fractions 0 < a < b < 1 of the mouth's width, "
                         f"got {tuple(middle)}")
    n = mesh.n_vertices
    corners = _landmark(landmarks, ("mouth_corner_left", "mouth_corner_right"), n)
    upper_points = _landmark(landmarks, UPPER_POINTS, n)
    lower_points = _landmark(landmarks, LOWER_POINTS, n)
    missing = [name for name, got in (("mouth_corner_left and mouth_corner_right",
                                       len(corners) == 2),
                                      (" or ".join(UPPER_POINTS), upper_points),
                                      (" or ".join(LOWER_POINTS), lower_points)) if not got]
    if missing:
        raise InputError(f"the mouth needs the mesh landmarks {missing[0]} (the lip gap is "
                         "measured between the lips, split at the corners)")
    v = mesh.vertices
    left, right = v[corners[0]], v[corners[1]]
    width = float(np.linalg.norm(left - right))
    up = v[upper_points].mean(axis=0) - v[lower_points].mean(axis=0)
    best, reach = None, np.inf
    for loop in boundary_loops(mesh):
        d = max(np.linalg.norm(v[loop] - c, axis=1).min() for c in (left, right))
        if d < reach:
            best, reach = loop, d
    if best is None or reach > _CORNER_REACH * width:
        return _from_landmarks(landmarks, n)
    axis = (left - right) / width
    along = v[best] @ axis
    i, j = int(np.argmax(along)), int(np.argmin(along))       # left and right corner
    n_loop = len(best)
    first = best[(i + np.arange((j - i) % n_loop + 1)) % n_loop]
    second = best[(j + np.arange((i - j) % n_loop + 1)) % n_loop][::-1]
    if v[first].mean(axis=0) @ up < v[second].mean(axis=0) @ up:
        first, second = second, first
    mouth_width = float(along[i] - along[j])
    fraction = (along[i] - v @ axis) / mouth_width            # 0 at the left corner
    inside = (fraction >= lo) & (fraction <= hi)
    sources = (fraction > lo / 2) & (fraction < (1 + hi) / 2)
    bands = [_band(mesh, edge[sources[edge]], _BAND * mouth_width) & inside
             for edge in (first, second)]
    if (bands[0] & bands[1]).any() or not (bands[0].any() and bands[1].any()):
        raise InputError("cannot tell the upper lip from the lower one in the middle of the "
                         f"mouth (between {lo:.0%} and {hi:.0%} of its width): "
                         f"its opening ({n_loop} vertices) is too small or too coarse")
    return MouthOpening(first, second, np.flatnonzero(bands[0]), np.flatnonzero(bands[1]),
                        "loop")


def _band(mesh: Mesh, sources: np.ndarray, reach: float) -> np.ndarray:
    """Vertices (mask) within `reach` of `sources` along the mesh's edges."""
    edges = mesh_edges(mesh.faces)[0]
    lengths = np.linalg.norm(mesh.vertices[edges[:, 0]] - mesh.vertices[edges[:, 1]], axis=1)
    graph = sp.coo_array((lengths, (edges[:, 0], edges[:, 1])),
                         shape=(mesh.n_vertices,) * 2).tocsr()
    dist = dijkstra(graph, directed=False, indices=sources, limit=reach, min_only=True)
    return np.isfinite(dist)


def _from_landmarks(landmarks, n) -> MouthOpening:
    pair = _landmark(landmarks, ("upper_lip_bottom", "lower_lip_top"), n)
    if len(pair) != 2:
        raise InputError("the mesh has no mouth opening (no boundary loop near both mouth "
                         "corners) and no landmarks upper_lip_bottom and lower_lip_top to "
                         "measure the lip gap between")
    empty = np.zeros(0, dtype=np.int64)
    return MouthOpening(empty, empty, np.array(pair[:1]), np.array(pair[1:]), "landmarks")
