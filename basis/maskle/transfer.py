"""Weight transfer from a fitted mask to a face: normal rays, Shepard, smoothing.

For each face vertex inside the fitted mask's bounding sphere, the line along
its normal (both directions) is intersected with the mask's triangles that
face the same way as the vertex (outward normals at an acute angle: the inner
surface of the upper lip reads the upper tongue strip above the lower one, a
brow never reads a patch from behind); the nearest hit within
``max_distance`` names a mask polygon, whose corner
weights are averaged with inverse-distance (Shepard, power 2) weights of the
hit point. The result is smoothed over the face's edge graph among hit
vertices. Both steps are linear, so the transfer is one sparse (N, V) operator
applied to the mask's weights (build once, apply to many weight sets).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np
import scipy.sparse as sp

from basis.maskle._geometry import TriangleIndex, nearest_ray_hits
from basis.maskle.fitting import MaskFit, fit_mask
from basis.maskle.mask import Mask
from mocap.errors import InputError
from mocap.markerset import REQUIRED_REGIONS
from mocap.mesh.mesh import Mesh, vertex_normals
from mocap.util.validation import as_float_array, as_int, as_positive_float

__all__ = ["TransferOperator", "MaskleWeights", "transfer_operator", "shepard_coefficients",
           "smoothing_operator", "maskle_weights"]

#: Shepard power: corner weights 1 / d**_SHEPARD_POWER.
_SHEPARD_POWER = 2.0
#: Default least cosine between a vertex normal and the normal of the mask triangle it reads.
_MIN_FACING = 0.0


def shepard_coefficients(points, corners, valid=None) -> np.ndarray:
    """Inverse-distance (Shepard) interpolation coefficients.

    Parameters
    ----------
    points : array_like of shape (R, 3)
    corners : array_like of shape (R, C, 3)
        The polygon corners each point interpolates from.
    valid : array_like of bool, shape (R, C), optional
        False for unused corners (a triangle among quads).

    Returns
    -------
    ndarray of shape (R, C)
        Rows sum to 1; a point on a corner gets exactly that corner.
    """
    points = as_float_array(points, "points", shape=(None, 3))
    corners = as_float_array(corners, "corners", shape=(len(points), None, 3))
    valid = np.ones(corners.shape[:2], bool) if valid is None else np.asarray(valid, bool)
    d = np.linalg.norm(corners - points[:, None], axis=2)
    exact = (d == 0) & valid
    with np.errstate(divide="ignore"):
        w = np.where(valid, 1.0 / d ** _SHEPARD_POWER, 0.0)
    w = np.where(exact.any(axis=1, keepdims=True), exact.astype(float), w)
    return w / w.sum(axis=1, keepdims=True)


def smoothing_operator(faces, defined, *, iterations: int = 3, strength: float = 0.5):
    """Laplacian smoothing over a mesh's edge graph as a sparse (N, N) matrix.

    Each iteration replaces a defined vertex's value by ``(1 - strength) w +
    strength * mean(w of its defined neighbours)``; vertices without defined
    neighbours keep theirs. Rows are convex combinations, so values stay in
    the range of the input (weights in [0, 1] stay in [0, 1]).

    Parameters
    ----------
    faces : array_like of shape (F, 3), int
    defined : array_like of bool, shape (N,)
        Vertices that carry a value; undefined vertices are neither read nor changed.
    iterations : int
    strength : float in (0, 1]
    """
    defined = np.asarray(defined, bool)
    n = len(defined)
    iterations = as_int(iterations, "iterations", minimum=0)
    strength = as_positive_float(strength, "strength")
    if strength > 1:
        raise InputError(f"strength must lie in (0, 1], got {strength}")
    faces = np.asarray(faces, np.int64)
    a, b = faces.ravel(), np.roll(faces, -1, axis=1).ravel()
    adj = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n)).tocsr()
    adj = ((adj + adj.T) > 0).astype(float)
    adj = sp.diags(defined.astype(float)) @ adj @ sp.diags(defined.astype(float))
    deg = np.asarray(adj.sum(axis=1)).ravel()
    lam = np.where(deg > 0, strength, 0.0)
    step = sp.diags(1 - lam) + sp.diags(lam / np.maximum(deg, 1)) @ adj
    out = sp.identity(n, format="csr")
    for _ in range(iterations):
        out = step @ out
    return out.tocsr()


@dataclass(frozen=True)
class TransferOperator:
    """The linear map from mask vertex weights to face vertex weights.

    Attributes
    ----------
    matrix : scipy.sparse.csr_matrix of shape (N, V)
        Face weights = ``matrix @ mask_weights`` on hit vertices (rows of other
        vertices are empty).
    hit : ndarray of bool, shape (N,)
        Face vertices whose normal line meets the mask.
    missed : ndarray of int64
        Face vertices inside the mask's bounding sphere whose line missed it.
    distance : ndarray of shape (N,), mesh units
        Distance from each hit vertex to its hit point (NaN elsewhere).
    """

    matrix: sp.csr_matrix
    hit: np.ndarray
    missed: np.ndarray
    distance: np.ndarray

    def apply(self, mask_weights) -> np.ndarray:
        """Face weights (N, K) from mask weights (V, K); NaN on vertices not hit."""
        w = np.asarray(self.matrix @ np.asarray(mask_weights, float))
        w[~self.hit] = np.nan
        return np.clip(w, 0.0, 1.0, out=w, where=self.hit[:, None])


def transfer_operator(mask: Mask, fit: MaskFit, mesh: Mesh, *, max_distance: float = 1.0,
                      smoothing: int = 3, min_facing: float = _MIN_FACING) -> TransferOperator:
    """Build the transfer operator of a fitted mask onto a face.

    Parameters
    ----------
    mask : Mask
    fit : MaskFit
        `mask` fitted to `mesh` (:func:`~basis.maskle.fitting.fit_mask`).
    mesh : Mesh
    max_distance : float
        Farthest hit along a vertex normal, template cm (times ``fit.scale``).
    smoothing : int
        Laplacian smoothing iterations (0: none).
    min_facing : float in [-1, 1)
        A vertex takes weights only from mask triangles whose (outward) normal
        makes a cosine above this with its own normal: the inner surface of one
        lip faces the other lip's band but not its outward normal, so it reads
        its own lip's tongue strip instead. -1 accepts every triangle.

    Returns
    -------
    TransferOperator
    """
    max_distance = as_positive_float(max_distance, "max_distance")
    min_facing = float(as_float_array(min_facing, "min_facing", ndim=0, allow_nan=False))
    if not -1.0 <= min_facing < 1.0:
        raise InputError(f"min_facing must lie in [-1, 1), got {min_facing}")
    x = fit.vertices
    centre = x.mean(axis=0)
    radius = np.linalg.norm(x - centre, axis=1).max()
    inside = np.flatnonzero(np.linalg.norm(mesh.vertices - centre, axis=1) <= radius)
    normals = vertex_normals(mesh.vertices, mesh.faces)[inside]
    usable = np.linalg.norm(normals, axis=1) > 0
    tri = mask.triangles
    face, t = nearest_ray_hits(mesh.vertices[inside[usable]], normals[usable],
                               TriangleIndex(x[tri]), max_distance * fit.scale,
                               min_cosine=None if min_facing == -1.0 else min_facing)
    ok = face >= 0
    rows = inside[usable][ok]
    points = mesh.vertices[rows] + t[ok, None] * normals[usable][ok]
    poly = mask.polygons[mask.triangle_polygon[face[ok]]]
    valid = poly >= 0
    coef = shepard_coefficients(points, x[np.where(valid, poly, poly[:, :1])], valid)
    n = mesh.n_vertices
    raw = sp.csr_matrix((coef[valid], (np.repeat(rows, valid.sum(axis=1)), poly[valid])),
                        shape=(n, mask.n_vertices))
    hit = np.zeros(n, bool)
    hit[rows] = True
    distance = np.full(n, np.nan)
    distance[rows] = np.abs(t[ok])
    missed = np.setdiff1d(inside, rows)
    smooth = smoothing_operator(mesh.faces, hit, iterations=smoothing)
    return TransferOperator((smooth @ raw).tocsr(), hit, missed, distance)


@dataclass(frozen=True)
class MaskleWeights:
    """Per-vertex weights of a face.

    Attributes
    ----------
    channel_names, channel_kinds : tuple of str
        K channels (see :class:`~basis.maskle.mask.Mask`).
    weights : ndarray of shape (N, K)
        In [0, 1]; NaN rows for vertices that got no weights.
    hit : ndarray of bool, shape (N,)
    missed : ndarray of int64
        Vertices inside the mask's bounding sphere whose rays missed it.
    fit : MaskFit or None
        The fitted mask (None for methods without one).
    """

    channel_names: tuple
    channel_kinds: tuple
    weights: np.ndarray
    hit: np.ndarray
    missed: np.ndarray
    fit: MaskFit | None = None

    def channel(self, name: str) -> np.ndarray:
        """Weights (N,) of one channel."""
        if name not in self.channel_names:
            raise InputError(f"no weight channel {name!r}; channels: "
                             f"{', '.join(self.channel_names)}")
        return self.weights[:, self.channel_names.index(name)].copy()

    def region_masks(self) -> np.ndarray:
        """Region weights (N, R) over :data:`mocap.markerset.REQUIRED_REGIONS`.

        Rows sum to 1 where defined; rows of vertices without weights are NaN.
        Vertices whose region weights are all 0 belong to ``other``.
        """
        absent = [r for r in REQUIRED_REGIONS if r not in self.channel_names]
        if absent:
            raise InputError(f"the mask paints no region {', '.join(absent)}")
        w = self.weights[:, [self.channel_names.index(r) for r in REQUIRED_REGIONS]].copy()
        total = w.sum(axis=1, keepdims=True)
        w[total[:, 0] == 0, REQUIRED_REGIONS.index("other")] = 1.0
        return w / np.where(total > 0, total, 1.0)


def maskle_weights(mesh: Mesh, landmarks: Mapping, mask: Mask, *,
                   max_distance: float = 1.0, smoothing: int = 3,
                   **fit_options) -> MaskleWeights:
    """Fit `mask` to a face and transfer its weights.

    Parameters
    ----------
    mesh : Mesh
    landmarks : mapping of str to int
        Vertex ids of the ten :data:`~mocap.anatomy.MASKLE_POINTS` (more are ignored).
    mask : Mask
    max_distance, smoothing
        See :func:`transfer_operator`.
    **fit_options
        ``a``, ``b``, ``max_iterations``, ``standoff`` of :func:`fit_mask`.

    Returns
    -------
    MaskleWeights
    """
    fit = fit_mask(mask, mesh, landmarks, **fit_options)
    op = transfer_operator(mask, fit, mesh, max_distance=max_distance, smoothing=smoothing)
    return MaskleWeights(mask.channel_names, mask.channel_kinds, op.apply(mask.weights),
                         op.hit, op.missed, fit)
