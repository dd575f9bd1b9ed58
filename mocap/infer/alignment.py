"""A neutral frame's markers placed on a face mesh without any landmark pair.

The markers' face axes (:mod:`mocap.infer.axes`) are turned onto the
mesh's (:mod:`mocap.infer.mesh_landmarks`), the nose tips meet, the scale
comes from the face's height, and trimmed ICP with scale refines the
similarity. Up is the one axis the markers alone may leave in doubt: both
signs are tried and the better fit is kept, the other reported.
"""

from __future__ import annotations

from dataclasses import dataclass

import igl
import numpy as np

from mocap.errors import InputError
from mocap.infer.axes import FaceAxes
from mocap.infer.mesh_landmarks import MeshLandmarks
from mocap.mesh.mesh import Mesh
from mocap.rigid import fit_rigid

__all__ = ["Alignment", "align_to_mesh", "UNITS_MM"]

#: Millimetres per unit of the mesh units a face mesh may be in.
UNITS_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4}
#: Fraction of the markers each ICP step fits (the rest may be off the skin:
#: markers on a headband, a lip marker over the mouth opening).
_KEEP = 0.8
_MAX_ITER = 100
#: Markers farther than this many times the median distance from the cloud's
#: median point do not set the start (markers on a headband, 10 cm out).
_CORE = 1.8
#: Starts of ICP along the mesh's up, in mouth-to-eye heights from the nose tip.
_START_SHIFTS = (0.0, -0.3, 0.3)


@dataclass(frozen=True, eq=False)
class Alignment:
    """``mesh = scale * rotation @ marker + translation``, from the markers alone.

    Attributes
    ----------
    scale : float
        Mesh units per capture millimetre.
    rotation : ndarray of shape (3, 3)
    translation : ndarray of shape (3,), mesh units
    rms : float, mm
        Trimmed RMS distance of the markers to the surface.
    flipped_rms : float, mm
        The same with up reversed: how clearly up was decided.
    distances : ndarray of shape (M,), mm
        Each marker's distance to the surface.
    on_mesh : ndarray of shape (M, 3), mesh units
        Each marker's closest surface point.
    units : str or None
        The mesh units a real-size face would be in (:data:`UNITS_MM`), when
        the scale is within 30 % of one of them.
    axes : FaceAxes
        The markers' axes with up as chosen.
    """

    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    rms: float
    flipped_rms: float
    distances: np.ndarray
    on_mesh: np.ndarray
    units: str | None
    axes: FaceAxes

    def to_mesh(self, points) -> np.ndarray:
        """Marker-frame points (..., 3), mm, to mesh units."""
        return self.scale * np.asarray(points, dtype=float) @ self.rotation.T + self.translation


class _Surface:
    """Closest points on a mesh, its AABB tree built once."""

    def __init__(self, mesh: Mesh):
        self.vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
        self.tree = igl.AABB()
        self.tree.init(self.vertices, self.faces)

    def closest(self, points):
        sq, _, closest = self.tree.squared_distance(self.vertices, self.faces,
                                                    np.ascontiguousarray(points))
        return np.sqrt(np.maximum(sq, 0.0)), closest


def _icp(points, surface, scale, rotation, translation, keep):
    """Trimmed ICP with scale from a start; returns scale, rotation, translation, rms (mm)."""
    n_keep = max(3, int(np.ceil(keep * len(points))))
    previous = np.inf
    for _ in range(_MAX_ITER):
        moved = scale * points @ rotation.T + translation
        dist, target = surface.closest(moved)
        order = np.argsort(dist, kind="stable")[:n_keep]
        rms = float(np.sqrt(np.mean(dist[order] ** 2)) / scale)
        if abs(previous - rms) <= 1e-6 * max(rms, 1e-9):
            break
        previous = rms
        weights = np.zeros(len(points))
        weights[order] = 1.0
        fit = fit_rigid(points, target, weights, scale=True)
        if not fit.valid:
            break
        scale, rotation, translation = float(fit.scale), fit.rotation, fit.translation
    return scale, rotation, translation, rms


def _core(points) -> np.ndarray:
    """Markers of the face's core (bool, (M,)): not far out of the cloud (a headband, a neck)."""
    centre = np.median(points, axis=0)
    dist = np.linalg.norm(points - centre, axis=1)
    core = dist <= _CORE * np.median(dist)
    return core if core.sum() >= 4 else np.ones(len(points), dtype=bool)


def _start(axes: FaceAxes, points, mesh_marks: MeshLandmarks, scale):
    """Similarity turning the marker axes onto the mesh's, nose tip on nose tip."""
    rotation = mesh_marks.axes.matrix.T @ axes.matrix
    coords = axes.coordinates(points)
    midline = np.abs(coords[:, 0]) <= 0.25 * np.ptp(coords[:, 0])
    tip = points[np.flatnonzero(midline)[np.argmax(coords[midline, 2])]] if midline.any() \
        else points[np.argmax(coords[:, 2])]
    mesh_tip = mesh_marks.axes.origin + mesh_marks.coordinates["nose_tip"] @ \
        mesh_marks.axes.matrix
    return rotation, mesh_tip - scale * rotation @ tip


def align_to_mesh(points, axes: FaceAxes, mesh: Mesh, mesh_marks: MeshLandmarks, *,
                  both: bool = True) -> Alignment:
    """Place a neutral frame's markers on a face mesh from the two sets of face axes.

    Parameters
    ----------
    points : array_like of shape (M, 3), mm
        The face markers of a neutral frame in the head frame (no NaN).
    axes : FaceAxes
        Their axes (:func:`mocap.infer.axes.face_axes`); the sign of up is
        checked here.
    mesh : Mesh
    mesh_marks : MeshLandmarks
        The mesh's landmarks and axes.
    both : bool, default True
        Try up reversed too and keep the better fit; False keeps `axes` as
        they are (``flipped_rms`` is then NaN).

    Returns
    -------
    Alignment

    Raises
    ------
    InputError
        Fewer than 4 points, or NaN.

    Notes
    -----
    The start turns the markers' (left, up, forward) onto the mesh's, puts
    the most forward midline marker on the mesh's nose tip and sets the
    scale so that the markers' height spread (RMS about their mean along up)
    matches 0.6 times the mesh's mouth-to-eye height times the ratio of a
    typical face (markers cover the face from the chin to the brows, whose
    RMS spread is about 0.6 of the mouth-eye distance: the start only has to
    be in ICP's basin), all from the markers of the face's core (within 1.8
    times the median distance of the cloud's median point: not a headband). Trimmed ICP (the best 80 % of markers) refines it,
    for up and for up reversed, each from the nose tip and from 0.3 of the
    face's height above and below it; the fit of smaller RMS is kept.
    """
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 4 \
            or np.isnan(points).any():
        raise InputError(f"aligning to a mesh needs 4 or more markers (M, 3) without NaN, got "
                         f"shape {points.shape}")
    surface = _Surface(mesh)
    marks = mesh_marks.coordinates
    mouth = (marks["mouth_corner_left"] + marks["mouth_corner_right"]) / 2
    eyes = np.mean([marks[p] for p in ("eye_inner_left", "eye_outer_left", "eye_inner_right",
                                       "eye_outer_right")], axis=0)
    mesh_height = float(eyes[1] - mouth[1])
    fits = []
    up = mesh_marks.axes.up
    core = _core(points)
    for candidate in ((axes, axes.flipped()) if both else (axes,)):
        spread = float(np.sqrt(np.mean(candidate.coordinates(points[core])[:, 1] ** 2)))
        scale = 0.6 * mesh_height / max(spread, 1e-9)
        rotation, translation = _start(candidate, points[core], mesh_marks, scale)
        # the most forward midline marker may not be on the nose tip: start a little
        # above and below too, and keep the best fit
        for shift in _START_SHIFTS:
            fits.append((*_icp(points, surface, scale, rotation,
                               translation + shift * mesh_height * up, _KEEP), candidate))
    best = {}
    for fit in fits:                                  # the best start of each orientation
        key = id(fit[4])
        if key not in best or fit[3] < best[key][3]:
            best[key] = fit
    fits = sorted(best.values(), key=lambda f: f[3])
    (scale, rotation, translation, rms, chosen) = fits[0]
    flipped_rms = fits[1][3] if both else np.nan
    moved = scale * points @ rotation.T + translation
    dist, on_mesh = surface.closest(moved)
    units = None
    for name, mm in UNITS_MM.items():
        if abs(scale * mm - 1.0) <= 0.3:
            units = name
    return Alignment(scale=scale, rotation=rotation, translation=translation, rms=rms,
                     flipped_rms=flipped_rms, distances=dist / scale, on_mesh=on_mesh,
                     units=units, axes=chosen)
