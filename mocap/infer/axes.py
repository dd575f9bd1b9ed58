"""The axes of a face from its geometry: symmetry plane, where it points, which way is up.

Nothing is assumed about the lab's coordinate system: the subject's left
comes from the symmetry plane of the markers (or of the mesh), forward from
where the face bulges (the midline, the nose, stands out of the cheeks), up
from evidence that :func:`face_axes` weighs and reports. With up and forward
known, left is ``up x forward`` in a right-handed capture frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize
from scipy.spatial import cKDTree

from mocap.errors import InputError
from mocap.util.validation import as_float_array

__all__ = ["FaceAxes", "symmetry_plane", "forward_direction", "face_axes"]


@dataclass(frozen=True)
class FaceAxes:
    """Orthonormal face axes in some frame (the capture's head frame, or a mesh's).

    Attributes
    ----------
    left, up, forward : ndarray of shape (3,)
        Unit vectors; ``left = up x forward`` (the subject's left).
    origin : ndarray of shape (3,)
        A point of the symmetry plane (its normal is `left`).
    symmetry_rms : float
        Root mean square distance from each reflected point to its nearest
        point (the units of the points): how symmetric the set is.
    evidence : tuple of str
        What decided the sign of up, one sentence per cue.
    """

    left: np.ndarray
    up: np.ndarray
    forward: np.ndarray
    origin: np.ndarray
    symmetry_rms: float
    evidence: tuple = ()

    @property
    def matrix(self) -> np.ndarray:
        """Rows left, up, forward (3, 3): ``matrix @ (p - origin)`` is p in face coordinates."""
        return np.array([self.left, self.up, self.forward])

    def coordinates(self, points) -> np.ndarray:
        """Points (..., 3) as (left, up, forward) coordinates about the origin."""
        return (np.asarray(points, dtype=float) - self.origin) @ self.matrix.T

    def flipped(self) -> "FaceAxes":
        """The same plane and forward with up reversed (left reverses with it)."""
        return FaceAxes(-self.left, -self.up, self.forward, self.origin, self.symmetry_rms,
                        self.evidence)


def _reflect(points, normal, offset):
    return points - 2.0 * ((points @ normal) - offset)[:, None] * normal


def _unit(v) -> np.ndarray:
    return v / np.linalg.norm(v)


def symmetry_plane(points, *, trim: float = 0.8) -> tuple:
    """The plane that maps a point set best onto itself by reflection.

    Parameters
    ----------
    points : array_like of shape (n, 3)
        A face's markers or vertices (any units); at least 4, no NaN.
    trim : float, default 0.8
        Fraction of points (the best matched) the cost is taken over, so that
        unpaired points (a marker on one side only) do not pull the plane.

    Returns
    -------
    normal : ndarray of shape (3,)
        Unit normal (its sign is arbitrary).
    offset : float
        ``normal . p = offset`` on the plane.
    rms : float
        Trimmed root mean square distance of the reflected points to their
        nearest points.

    Notes
    -----
    The cost (trimmed RMS nearest-neighbour distance of the reflected set) is
    minimized over the plane's normal and offset by Nelder-Mead, started from
    each principal axis of the points through their centroid; the best of
    the three is returned. No correspondence between left and right is assumed.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> half = rng.uniform(1, 5, (20, 3))
    >>> pts = np.vstack([half, half * [-1, 1, 1]]) + [3, 0, 0]
    >>> normal, offset, rms = symmetry_plane(pts)
    >>> bool(abs(abs(normal[0]) - 1) < 1e-4 and abs(abs(offset) - 3) < 1e-3)
    True
    """
    points = as_float_array(points, "points", shape=(None, 3), allow_nan=False)
    if len(points) < 4:
        raise InputError(f"a symmetry plane needs at least 4 points, got {len(points)}")
    tree = cKDTree(points)
    keep = max(3, int(np.ceil(trim * len(points))))
    centre = points.mean(axis=0)
    scale = float(np.sqrt(((points - centre) ** 2).sum(axis=1).mean()))

    def cost(params, basis):
        normal = _unit(basis @ np.array([1.0, params[0], params[1]]))
        dist, _ = tree.query(_reflect(points, normal, normal @ centre + params[2] * scale))
        return float(np.sqrt(np.mean(np.sort(dist)[:keep] ** 2)))

    _, _, axes = np.linalg.svd(points - centre)
    best = None
    for k in range(3):
        basis = np.roll(axes, -k, axis=0).T                     # columns: axis k, the others
        res = minimize(cost, np.zeros(3), args=(basis,), method="Nelder-Mead",
                       options={"xatol": 1e-6, "fatol": 1e-9 * scale, "maxiter": 2000})
        if best is None or res.fun < best[0]:
            normal = _unit(basis @ np.array([1.0, res.x[0], res.x[1]]))
            best = (res.fun, normal, float(normal @ centre + res.x[2] * scale))
    rms, normal, offset = best
    return normal, offset, float(rms)


def forward_direction(points, normal, lateral=None) -> np.ndarray:
    """Where a face points: the in-plane direction its midline bulges towards.

    Parameters
    ----------
    points : array_like of shape (n, 3)
        The face's markers or vertices.
    normal : array_like of shape (3,)
        Normal of the symmetry plane.
    lateral : array_like of shape (n,), optional
        Distance of each point from the plane (default: computed).

    Returns
    -------
    ndarray of shape (3,)
        Unit vector in the symmetry plane: of the two principal directions
        of the points in the plane, the one of least spread (depth; a face is
        taller than deep), signed so that points near the midline (nose,
        lips, chin) stand out in front of the lateral ones (cheeks, jaw,
        temples wrap back).
    """
    points = np.asarray(points, dtype=float)
    normal = _unit(np.asarray(normal, dtype=float))
    centred = points - points.mean(axis=0)
    seed = np.eye(3)[int(np.argmin(np.abs(normal)))]
    plane = np.array([_unit(np.cross(normal, seed)), np.zeros(3)])
    plane[1] = np.cross(normal, plane[0])                    # orthonormal basis of the plane
    flat = centred @ plane.T
    _, vectors = np.linalg.eigh(flat.T @ flat)               # ascending: depth first
    depth = _unit(vectors[:, 0] @ plane)
    side = np.abs(centred @ normal if lateral is None else np.asarray(lateral, dtype=float))
    width = side.max()
    mid = side <= 0.3 * width
    out = side >= 0.6 * width
    if mid.any() and out.any() and (centred[mid] @ depth).mean() < (centred[out] @ depth).mean():
        depth = -depth
    return depth


def face_axes(points, *, up_hint=None, evidence=()) -> FaceAxes:
    """Face axes of a set of points: symmetry plane, forward, and up from a hint.

    Parameters
    ----------
    points : array_like of shape (n, 3)
        A neutral face's markers (head frame) or a mesh's vertices.
    up_hint : array_like of shape (3,), optional
        A direction roughly up (its sign is what counts): up is the in-plane
        direction orthogonal to forward on its side. Default: the second
        principal direction in the plane, with an arbitrary sign (the caller
        weighs the evidence and may flip it, :meth:`FaceAxes.flipped`).
    evidence : sequence of str
        Sentences saying where `up_hint` came from (kept in the result).

    Returns
    -------
    FaceAxes
    """
    points = as_float_array(points, "points", shape=(None, 3), allow_nan=False)
    normal, offset, rms = symmetry_plane(points)
    forward = forward_direction(points, normal)
    up = np.cross(forward, normal)
    if up_hint is not None and np.dot(up, up_hint) < 0:
        up = -up
    up = _unit(up)
    left = np.cross(up, forward)
    centre = points.mean(axis=0)
    origin = centre - ((centre @ normal) - offset) * normal
    return FaceAxes(left=left, up=up, forward=forward, origin=origin, symmetry_rms=rms,
                    evidence=tuple(evidence))
