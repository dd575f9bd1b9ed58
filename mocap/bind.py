"""Binding: markers of a neutral capture frame placed on a face mesh.

Correspondence stage. A similarity transform (scale, rotation, translation)
takes capture millimetres to mesh units; it is fitted to the landmark pairs
(a marker-set landmark and a mesh landmark with the same anatomical name),
refined by trimmed ICP against the surface, and every marker is then projected
to its closest surface point, kept as a face id and barycentric coordinates so
that the bound points follow any mesh of the same topology.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import igl
import numpy as np

import mocap.neutral as neutrals
from mocap._moved import BIND_NAMES
from mocap.anatomy import ANATOMICAL_POINTS
from mocap.errors import FileFormatError, InputError, MarkerError
from mocap.head_frame import STABILIZATIONS, find_head_frame
from mocap.mesh.landmarks import check_mesh_landmarks
from mocap.mesh.layout import MarkerLayout
from mocap.mesh.mesh import Mesh, degenerate_faces, face_normals
from mocap.rigid import apply_transform, fit_rigid, weighted_fit
from mocap.stabilize import ROBUST_GUARD_DEG
from mocap.take import as_take
from mocap.util.atomic import atomic_path
from mocap.util.deprecation import moved_names
from mocap.util.files import read_input_text
from mocap.util.validation import as_float_array, as_int, as_positive_float

__all__ = ["Binding", "bind_markers", "load_binding", "closest_surface_points", "BoundTake",
           "bind_take", "BIND_STABILIZATIONS"]

_FORMAT = "mocap2mesh-binding-1"


@dataclass(frozen=True, eq=False)
class Binding:
    """Markers bound to a mesh topology, with the capture-to-mesh transform.

    ``p_mesh = scale * rotation @ p_mm + translation``.

    Attributes
    ----------
    labels : tuple of str
        Marker labels, M of them.
    scale : float
        Mesh units per capture millimetre (0.1 for a mesh in cm, if the face
        has its real size).
    rotation : ndarray of shape (3, 3)
    translation : ndarray of shape (3,), mesh units
    face_ids : ndarray of shape (M,), int64
        Triangle of :attr:`mocap.mesh.mesh.Mesh.faces` holding each bound point.
    vertex_ids : ndarray of shape (M, 3), int64
        Its three vertices.
    barycentric : ndarray of shape (M, 3)
        Barycentric coordinates of the bound point in that triangle.
    distances : ndarray of shape (M,), mm
        Distance of each transformed marker to the surface, capture millimetres.
    rms : float, mm
        Root mean square of ``distances - skin_offset`` over all markers.
    skin_offset : float, mm
        The marker height off the skin assumed by the fit.
    n_landmarks : int
        Landmark pairs the initial transform was fitted to.
    n_iterations : int
        ICP iterations run (0 without ICP).
    converged : bool
    message : str
    """

    labels: tuple
    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    face_ids: np.ndarray
    vertex_ids: np.ndarray
    barycentric: np.ndarray
    distances: np.ndarray
    rms: float
    skin_offset: float
    n_landmarks: int
    n_iterations: int
    converged: bool
    message: str

    def __post_init__(self):
        for name in ("rotation", "translation", "face_ids", "vertex_ids", "barycentric",
                     "distances"):
            arr = np.array(getattr(self, name))
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)

    def to_mesh(self, points) -> np.ndarray:
        """Capture points (..., 3) in mm to mesh units (...,  3); NaN propagates."""
        points = as_float_array(points, "points")
        return self.scale * points @ self.rotation.T + self.translation

    def to_capture(self, points) -> np.ndarray:
        """Mesh points (..., 3) in mesh units back to capture mm (..., 3); NaN propagates."""
        points = as_float_array(points, "points")
        return (points - self.translation) @ self.rotation / self.scale

    def marker_points(self, vertices) -> np.ndarray:
        """Bound marker points on one mesh or many frames of it.

        Parameters
        ----------
        vertices : array_like of shape (..., N, 3), mesh units
            Any mesh of the bound topology (neutral, expressions, a sequence).

        Returns
        -------
        ndarray of shape (..., M, 3), mesh units
            On the surface (no skin offset). NaN vertices propagate.
        """
        vertices = as_float_array(vertices, "vertices")
        if vertices.ndim < 2 or vertices.shape[-1] != 3 \
                or vertices.shape[-2] <= self.vertex_ids.max():
            raise InputError(f"vertices must have shape (..., N, 3) with N > "
                             f"{self.vertex_ids.max()}, got {vertices.shape}")
        return np.einsum("...mkc,mk->...mc", vertices[..., self.vertex_ids, :],
                         self.barycentric)

    def centre_layout(self, mesh: Mesh, labels=None) -> MarkerLayout:
        """The bound markers as a layout of `mesh`: their centres, `skin_offset` off the skin.

        The offset is along the interpolated vertex normal
        (:meth:`mocap.mesh.layout.MarkerLayout.positions`), in mesh units. `labels`
        picks and orders the markers (default: all, in the binding's order).

        Raises
        ------
        MarkerError
            A label not in the binding.
        """
        labels = self.labels if labels is None else tuple(labels)
        absent = [x for x in labels if x not in self.labels]
        if absent:
            raise MarkerError(absent[0], "is not in the binding")
        rows = [self.labels.index(x) for x in labels]
        return MarkerLayout(labels, self.vertex_ids[rows], self.barycentric[rows],
                            self.face_ids[rows], np.full(len(rows), self.skin_offset * self.scale),
                            mesh.faces, mesh.n_vertices)

    def save(self, path) -> None:
        """Write the binding to a JSON file atomically (see :func:`load_binding`)."""
        doc = {"format": _FORMAT, "labels": list(self.labels), "scale": self.scale,
               "rotation": self.rotation.tolist(), "translation": self.translation.tolist(),
               "face_ids": self.face_ids.tolist(), "vertex_ids": self.vertex_ids.tolist(),
               "barycentric": self.barycentric.tolist(), "distances_mm": self.distances.tolist(),
               "rms_mm": self.rms, "skin_offset_mm": self.skin_offset,
               "n_landmarks": self.n_landmarks, "n_iterations": self.n_iterations,
               "converged": self.converged, "message": self.message}
        with atomic_path(path) as tmp:
            Path(tmp).write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")


def load_binding(path) -> Binding:
    """Read a binding written by :meth:`Binding.save`.

    Raises
    ------
    FileFormatError
        Unreadable or not JSON, another format, missing fields or inconsistent shapes.
    """
    text = read_input_text(path, "binding")
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FileFormatError(path, f"not valid JSON: {exc}") from None
    except RecursionError:
        raise FileFormatError(path, "not a binding file: JSON nested too deeply") from None
    if not isinstance(doc, dict) or doc.get("format") != _FORMAT:
        raise FileFormatError(path, f"not a binding file (expected format {_FORMAT!r})")
    try:
        m = len(doc["labels"])
        binding = Binding(
            labels=tuple(str(x) for x in doc["labels"]), scale=float(doc["scale"]),
            rotation=np.array(doc["rotation"], float).reshape(3, 3),
            translation=np.array(doc["translation"], float).reshape(3),
            face_ids=np.array(doc["face_ids"], np.int64).reshape(m),
            vertex_ids=np.array(doc["vertex_ids"], np.int64).reshape(m, 3),
            barycentric=np.array(doc["barycentric"], float).reshape(m, 3),
            distances=np.array(doc["distances_mm"], float).reshape(m),
            rms=float(doc["rms_mm"]), skin_offset=float(doc["skin_offset_mm"]),
            n_landmarks=int(doc["n_landmarks"]), n_iterations=int(doc["n_iterations"]),
            converged=bool(doc["converged"]), message=str(doc["message"]))
    except (KeyError, TypeError, ValueError, OverflowError) as exc:
        raise FileFormatError(path, f"bad or missing binding field: {exc}") from None
    return binding


def _barycentric(points: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Barycentric coordinates (K, 3) of points (K, 3) in triangles (K, 3, 3), clipped to >= 0."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    v0, v1, v2 = b - a, c - a, points - a
    d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
    d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
    denom = d00 * d11 - d01 * d01
    v = (d11 * d20 - d01 * d21) / denom
    w = (d00 * d21 - d01 * d20) / denom
    bary = np.clip(np.stack([1 - v - w, v, w], axis=1), 0.0, None)
    return bary / bary.sum(axis=1, keepdims=True)


class _Surface:
    """Closest-point queries on a mesh, with its AABB tree built once."""

    def __init__(self, mesh: Mesh):
        self.vertices = np.ascontiguousarray(mesh.vertices)
        keep = np.ones(mesh.n_faces, dtype=bool)
        keep[degenerate_faces(mesh.vertices, mesh.faces)] = False
        self.face_map = np.flatnonzero(keep)
        self.faces = np.ascontiguousarray(mesh.faces[keep])
        self.normals = face_normals(self.vertices, self.faces)
        self.tree = igl.AABB()
        self.tree.init(self.vertices, self.faces)

    def closest(self, points: np.ndarray):
        """Distances (K,), local face ids (K,), closest points (K, 3)."""
        sq, local, closest = self.tree.squared_distance(self.vertices, self.faces,
                                                        np.ascontiguousarray(points))
        return np.sqrt(np.maximum(sq, 0.0)), local, closest


def closest_surface_points(mesh: Mesh, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest points of a mesh surface, as face ids and barycentric coordinates.

    Parameters
    ----------
    mesh : Mesh
    points : array_like of shape (K, 3), mesh units
        Finite query points.

    Returns
    -------
    face_ids : ndarray of shape (K,), int64
        Triangle of ``mesh.faces`` (degenerate triangles are never returned).
    barycentric : ndarray of shape (K, 3)
    distances : ndarray of shape (K,), mesh units
    """
    points = as_float_array(points, "points", shape=(None, 3), allow_nan=False)
    surface = _Surface(mesh)
    dist, local, closest = surface.closest(points)
    return (surface.face_map[local], _barycentric(closest, surface.vertices[surface.faces[local]]),
            dist)


def _landmark_pairs(labels, marker_landmarks, mesh, mesh_landmarks):
    """Marker indices and mesh vertex ids of the anatomical points both sides name."""
    if not isinstance(marker_landmarks, Mapping):
        raise InputError("marker_landmarks must be a mapping of anatomical point to marker label")
    for point, label in marker_landmarks.items():
        if point not in ANATOMICAL_POINTS:
            raise InputError(f"marker_landmarks: unknown anatomical point {point!r}; known: "
                             f"{', '.join(ANATOMICAL_POINTS)}")
        if label not in labels:
            raise MarkerError(label, f"marker_landmarks names it for {point!r}, but it is not "
                                     "among the markers")
    mesh_landmarks = check_mesh_landmarks(mesh_landmarks, mesh.n_vertices,
                                          where="mesh_landmarks")
    points = [p for p in marker_landmarks if p in mesh_landmarks]
    markers = np.array([labels.index(marker_landmarks[p]) for p in points], dtype=np.int64)
    vertices = np.array([mesh_landmarks[p] for p in points], dtype=np.int64)
    return points, markers, vertices


def bind_markers(neutral_markers, labels: Sequence[str], marker_landmarks: Mapping[str, str],
                 mesh: Mesh, mesh_landmarks: Mapping[str, int], *, icp: bool = True,
                 icp_scale: bool = True, skin_offset: float = 0.0, icp_keep: float = 0.9,
                 max_iterations: int = 200, tolerance: float = 1e-6,
                 max_distance_warn: float = 3.0) -> Binding:
    """Bind the markers of a neutral frame to a face mesh.

    Parameters
    ----------
    neutral_markers : array_like of shape (M, 3), mm
        Marker positions of the neutral frame (see :func:`pick_neutral_frame`);
        NaN is rejected.
    labels : sequence of str
        The M marker labels.
    marker_landmarks : mapping of str to str
        Anatomical point (:mod:`mocap.anatomy`) to marker label, e.g.
        ``MarkerSet.landmarks``.
    mesh : Mesh
        The neutral face mesh, in its own units.
    mesh_landmarks : mapping of str to int
        Anatomical point to vertex id (:func:`mocap.mesh.landmarks.load_mesh_landmarks`).
    icp : bool, default True
        Refine the landmark fit by trimmed ICP on all markers.
    icp_scale : bool, default True
        Let ICP refine the scale too (otherwise it keeps the landmark scale).
    skin_offset : float, default 0, mm
        Height of the marker centres off the skin: ICP pulls each marker to
        this distance along the normal of its closest surface point.
    icp_keep : float, default 0.9
        Fraction of markers (closest to their target) each ICP step fits.
    max_iterations : int, default 200
    tolerance : float, default 1e-6
        ICP has converged when its (trimmed) RMS has not fallen below its
        lowest by more than this fraction in ``_ICP_PATIENCE`` steps, or is at
        rounding level; it returns the transform of the lowest. (The skin
        offset's targets jump where the closest face changes and the trimming
        changes the pairs, so ICP's descent ends in a cycle at the markers'
        noise level rather than at a fixed point.)
    max_distance_warn : float, default 3, mm
        Warn about markers whose distance to the surface differs from
        `skin_offset` by more than this.

    Returns
    -------
    Binding

    Raises
    ------
    InputError
        Wrong shapes, NaN markers, an unknown anatomical point, fewer than 3
        landmark pairs or collinear ones.
    MarkerError
        Duplicate labels, or a landmark naming a marker that is not in `labels`.

    Warns
    -----
    UserWarning
        Markers farther from the surface than `max_distance_warn` (named).

    Notes
    -----
    The landmark fit is Umeyama's least-squares similarity (:func:`mocap.rigid.fit_rigid`
    with ``scale=True``). Each ICP step takes, for every transformed marker x,
    the closest surface point c and its face normal n, the target
    ``c + skin_offset * scale * n``, keeps the `icp_keep` fraction of pairs with
    the smallest residual (trimmed ICP) and refits the similarity (or the
    rigid motion at fixed scale) to them.
    """
    points = as_float_array(neutral_markers, "neutral_markers", shape=(None, 3))
    labels = list(labels)
    if len(labels) != len(points):
        raise InputError(f"labels has {len(labels)} entries for {len(points)} markers")
    if len(set(labels)) != len(labels):
        dup = next(x for x in labels if labels.count(x) > 1)
        raise MarkerError(dup, "appears twice in labels")
    missing = np.flatnonzero(np.isnan(points).any(axis=1))
    if len(missing):
        raise MarkerError(labels[missing[0]], "is missing (NaN) in the neutral frame; binding "
                                              "needs every marker (choose another frame)")
    if not isinstance(mesh, Mesh):
        raise InputError(f"mesh must be a mocap.mesh.mesh.Mesh, got {type(mesh).__name__}")
    skin_offset = float(as_float_array(skin_offset, "skin_offset", ndim=0, allow_nan=False))
    icp_keep = as_positive_float(icp_keep, "icp_keep")
    if icp_keep > 1:
        raise InputError(f"icp_keep must be in (0, 1], got {icp_keep}")
    max_iterations = as_int(max_iterations, "max_iterations", minimum=1)
    tolerance = as_positive_float(tolerance, "tolerance")
    max_distance_warn = as_positive_float(max_distance_warn, "max_distance_warn")

    names, marker_idx, vertex_idx = _landmark_pairs(labels, marker_landmarks, mesh,
                                                    mesh_landmarks)
    if len(names) < 3:
        raise InputError(f"{len(names)} landmark pairs ({', '.join(names) or 'none'}); the "
                         "similarity fit needs at least 3 anatomical points named by both "
                         "marker_landmarks and mesh_landmarks")
    fit = fit_rigid(points[marker_idx], mesh.vertices[vertex_idx], scale=True)
    if not fit.valid:
        raise InputError(f"the landmark markers {', '.join(names)} are collinear (or "
                         "coincide): the similarity transform is undetermined")
    scale, rotation, translation = float(fit.scale), fit.rotation, fit.translation

    surface = _Surface(mesh)
    n_keep = max(3, int(np.ceil(icp_keep * len(points))))
    n_iter, converged, best, since_best = 0, not icp, np.inf, 0
    floor = 1e-12 * float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))  # rounding level
    while icp and n_iter < max_iterations:
        moved = scale * points @ rotation.T + translation
        _, local, closest = surface.closest(moved)
        target = closest + skin_offset * scale * surface.normals[local]
        resid = np.linalg.norm(moved - target, axis=1)
        rms = float(np.sqrt(np.mean(np.sort(resid)[:n_keep] ** 2)))
        if best - rms > tolerance * rms + floor:
            best, kept, since_best = rms, (scale, rotation, translation), 0
        elif rms <= floor or since_best >= _ICP_PATIENCE:
            converged = True
            break
        since_best += 1
        weights = np.zeros(len(points))
        weights[np.argsort(resid, kind="stable")[:n_keep]] = 1.0
        # points and targets are finite (checked above, and surface points): the fit's own
        # checks of its inputs are skipped (about 5% of an ICP step)
        if icp_scale:
            step = weighted_fit(points, target, weights, scale=True)
        else:
            step = weighted_fit(scale * points, target, weights)
        if not step.valid:
            break
        rotation, translation = step.rotation, step.translation
        if icp_scale:
            scale = float(step.scale)
        n_iter += 1
    if icp and n_iter:
        scale, rotation, translation = kept

    moved = scale * points @ rotation.T + translation
    dist, local, closest = surface.closest(moved)
    faces = surface.faces[local]
    distances = dist / scale
    excess = np.abs(distances - skin_offset)
    far = np.flatnonzero(excess > max_distance_warn)
    if len(far):
        worst = ", ".join(f"{labels[i]} ({distances[i]:.1f} mm)"
                          for i in far[np.argsort(-excess[far])][:10])
        warnings.warn(f"{len(far)} markers are more than {max_distance_warn} mm off the "
                      f"expected {skin_offset} mm from the mesh surface: {worst}", stacklevel=2)
    if not icp:
        message = f"similarity from {len(names)} landmark pairs, no ICP"
    elif converged:
        message = f"ICP converged after {n_iter} iterations"
    else:
        message = f"ICP stopped after {n_iter} iterations without converging"
    return Binding(labels=tuple(labels), scale=scale, rotation=rotation,
                   translation=translation, face_ids=surface.face_map[local],
                   vertex_ids=faces, barycentric=_barycentric(closest, surface.vertices[faces]),
                   distances=distances, rms=float(np.sqrt(np.mean(excess ** 2))),
                   skin_offset=skin_offset, n_landmarks=len(names), n_iterations=n_iter,
                   converged=converged, message=message)


#: ICP steps without a new lowest RMS after which :func:`bind_markers` has converged.
_ICP_PATIENCE = 10


#: How :func:`bind_take` finds the head frame of a take: its marker set's head
#: markers, face markers that hold their shape, or none (the take is in the
#: head frame already); :data:`mocap.head_frame.STABILIZATIONS`.
BIND_STABILIZATIONS = STABILIZATIONS


@dataclass(frozen=True, eq=False)
class BoundTake:
    """The binding of a take's markers and the neutral frame it was made from.

    ``window`` frames centred on ``frame`` (1, or a neutral hold's
    :func:`mocap.neutral.hold_window`) average into the rest pose that was
    bound and that displacements are measured from.

    Attributes
    ----------
    binding : Binding
    frame : int
        0-based index of the neutral frame.
    window : int
    """

    binding: Binding
    frame: int
    window: int = 1

    def neutral_pose(self, positions) -> np.ndarray:
        """The rest pose (M, 3) of `positions` (T, M, 3) (:func:`mocap.neutral.neutral_pose`)."""
        return neutrals.neutral_pose(positions, self.frame, self.window)


def bind_take(take, markerset, mesh: Mesh, mesh_landmarks: Mapping[str, int], *,
              frame="auto", stabilize: str = "head", head_frame: bool = False,
              icp: bool = True, skin_offset: float = 0.0,
              max_distance_warn: float = 3.0, robust: bool = True,
              guard_deg: float | None = ROBUST_GUARD_DEG) -> BoundTake:
    """Bind the markers of a take's neutral frame to a face mesh.

    Parameters
    ----------
    take : Take
        Positions (n_frames, n_markers, 3), mm; markers outside the marker
        set are ignored.
    markerset : MarkerSet
        The markers to bind (every marker of the set: landmarks may name head
        markers) and the head markers.
    mesh : Mesh
    mesh_landmarks : mapping of str to int
    frame : int, "auto" or "hold"
        0-based index of the neutral frame, or picked on the face markers in
        the head frame (:func:`mocap.neutral.find_neutral`). With "hold" the
        bound pose is the mean over the hold's window, taken in the head
        frame (the head may move during the hold): one frame's noise is not
        bound into every displacement.
    stabilize : {"head", "auto", "none"}
        How the head frame is found (:func:`mocap.head_frame.find_head_frame`):
        from the marker set's head markers, from the face markers that hold
        their shape ("auto", or the set's ``stabilization`` list), or "none":
        `take` is in the head frame already (a stabilized take, as the chain
        binds; not checked here).
    head_frame : bool, default False
        Bind the pose in the head frame; otherwise in the capture frame of the
        neutral frame (the head-frame mean carried there by that frame's head
        pose). Either is the same with ``stabilize = "none"``.
    icp, skin_offset, max_distance_warn
        As in :func:`bind_markers` (skin_offset in mm).
    robust, guard_deg
        Of the head fit (:func:`mocap.head_frame.find_head_frame`).

    Returns
    -------
    BoundTake

    Raises
    ------
    MarkerError
        A marker of the set absent from the take, or missing in the neutral
        frame (or the hold's window).
    InputError
        A frame index beyond the take; ``stabilize = "head"`` with a marker set
        naming no head markers; the errors of :func:`bind_markers`.
    """
    take = as_take(take)
    if stabilize not in BIND_STABILIZATIONS:
        raise InputError(f"stabilize must be one of {BIND_STABILIZATIONS}, got {stabilize!r}")
    take = markerset.own_labels(take)
    markerset.check_labels(take.labels, source=take.source.path or "the take")
    labels = tuple(markerset.markers)       # read where they are in the take, not copied
    picked = frame in neutrals.PICKED_FRAMES
    if not picked:
        frame = as_int(frame, "frame", minimum=0)
    head = None
    if stabilize != "none" and (picked or head_frame):
        head = find_head_frame(take, markerset, method=stabilize, robust=robust,
                               guard_deg=guard_deg).stabilization
    in_head = take if head is None else head.take
    on_face = neutrals.find_neutral(in_head, frame, labels=markerset.face_markers)
    index = on_face.frame
    neutral = neutrals.find_neutral(in_head, index, labels=labels, window=on_face.window)
    pose = neutral.pose
    if head is not None and not head_frame:
        pose = (take.positions[index, take.indices(labels)] if neutral.window == 1 else
                apply_transform(head.rotation[index], head.translation[index], pose))
    binding = bind_markers(pose, labels, markerset.landmarks, mesh, mesh_landmarks,
                           icp=icp, skin_offset=skin_offset, max_distance_warn=max_distance_warn)
    return BoundTake(binding=binding, frame=neutral.frame, window=neutral.window)


__getattr__ = moved_names(__name__, BIND_NAMES)
