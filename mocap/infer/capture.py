"""Everything a first run needs, inferred from a capture and a face mesh never seen before.

:func:`infer_capture` strips the subject prefix, flags the markers not worth
keeping, finds the head markers (or, without them, the stabilization
markers), the face's axes, the regions, the landmark pairs and, when the mesh
comes without them, the mesh's landmarks; what it cannot decide becomes an
:class:`OpenQuestion`. ``mocap2mesh init`` writes the result as files
(:mod:`mocap.infer.files`) and pictures (:mod:`mocap.infer.picture`).
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass, field

import numpy as np

from mocap.bind import closest_surface_points
from mocap.errors import InputError
from mocap.head_frame import JAW_REGIONS, find_head_frame
from mocap.infer.alignment import Alignment, align_to_mesh
from mocap.infer.axes import FaceAxes, face_axes
from mocap.infer.landmark_pairs import pair_landmarks
from mocap.infer.mesh_landmarks import (
    MeshLandmarks,
    find_mesh_landmarks,
    mesh_axes_from_landmarks,
)
from mocap.infer.names import is_unlabeled, parse_name, split_prefix
from mocap.infer.regions import classify_markers, face_coordinates
from mocap.markerset import MarkerSet
from mocap.mesh.landmarks import check_mesh_landmarks
from mocap.mesh.mesh import Mesh
from mocap.stable_markers import (
    MIN_PRESENCE,
    StableMarkers,
    distance_variation,
    find_stable_markers,
)
from mocap.take import Take, as_take
from mocap.util.order_statistics import nan_column_medians

__all__ = ["OpenQuestion", "Inference", "infer_capture", "OFF_FACE_MM", "RIGID_HEAD_MM",
           "UP_DECISIVE"]

#: A marker this far from the aligned mesh surface is off the face (a headband).
OFF_FACE_MM = 10.0
#: Head markers whose pairwise distances vary (standard deviation) by more
#: than this do not move as one rigid body.
RIGID_HEAD_MM = 2.0
#: The mesh alignment decides up when the other orientation fits this many
#: times worse.
UP_DECISIVE = 1.25
#: A motion cue (correlation of marker motion with height) this strong decides up.
_MOTION_DECISIVE = 0.3


@dataclass(frozen=True)
class OpenQuestion:
    """Something inference could not decide: written into a file, refused by ``run``.

    Attributes
    ----------
    key : str
        Short name (the key in the file's ``[open_questions]`` table).
    file : {"markerset", "landmarks", "run"}
        The file it belongs to.
    text : str
        The question, with what to do.
    """

    key: str
    file: str
    text: str


@dataclass(frozen=True, eq=False)
class Inference:
    """What :func:`infer_capture` found.

    Attributes
    ----------
    labels : tuple of str
        The capture's labels.
    prefix : str
        Subject prefix stripped from the names ("" if none).
    hints : dict of str to NameHint
    flagged : tuple of (str, str)
        Markers not kept, each with the reason.
    head : tuple of str
        Head markers (rigid, apart from the face).
    face : tuple of str
        Face markers kept.
    stabilization : str
        ``"head"`` or ``"auto"``.
    stable : StableMarkers or None
        The ``auto`` choice (face markers that hold their shape best).
    neutral_frame : int
        0-based frame index nearest the rest pose.
    pose : ndarray of shape (n_kept, 3), mm
        Rest pose of the kept markers (face, then head) in the head frame:
        each marker's median there.
    axes : FaceAxes
        The markers' face axes (head frame).
    alignment : Alignment
    mesh_landmarks : MeshLandmarks
    regions : list of RegionGuess
        One per face marker.
    landmarks : list of LandmarkPair
    xy : ndarray of shape (n_kept, 2)
        Normalized face coordinates of the kept markers.
    questions : list of OpenQuestion
    notes : list of str
        Lines of the report beyond the fields above.
    """

    labels: tuple
    prefix: str
    hints: dict
    flagged: tuple
    head: tuple
    face: tuple
    stabilization: str
    stable: StableMarkers | None
    neutral_frame: int
    pose: np.ndarray
    axes: FaceAxes
    alignment: Alignment
    mesh_landmarks: MeshLandmarks
    regions: list
    landmarks: list
    xy: np.ndarray
    questions: list = field(default_factory=list)
    notes: list = field(default_factory=list)

    @property
    def kept(self) -> tuple:
        """Face markers, then head markers (the rows of `pose` and `xy`)."""
        return self.face + self.head

    def region_table(self) -> dict:
        """Region name -> labels (face markers only), in the order of the face markers."""
        table = {}
        for guess in self.regions:
            table.setdefault(guess.region, []).append(guess.label)
        return table

    def report(self) -> list:
        """The lines ``mocap2mesh init`` prints."""
        out = []
        if self.prefix:
            out.append(f"names: subject prefix {self.prefix!r} stripped for reading the names")
        for label, why in self.flagged:
            out.append(f"not kept: {label}: {why}")
        if self.stabilization == "head":
            out.append(f"head markers: {', '.join(self.head)}")
        else:
            out.append("head markers: none found; stabilize = 'auto' on "
                       + ", ".join(self.stable.labels))
            out.append(f"  {self.stable.message}")
            for label, var in zip(self.stable.labels, self.stable.marker_variation):
                out.append(f"  {label}: distance variation {var:.2f} mm")
        out.append(f"axes (head frame): left {_vec(self.axes.left)}, up {_vec(self.axes.up)}, "
                   f"forward {_vec(self.axes.forward)}")
        out += [f"  {e}" for e in self.axes.evidence]
        a = self.alignment
        units = a.units or "unknown (not a real-size face?)"
        out.append(f"alignment to the mesh: {a.scale:.5g} mesh units/mm (mesh units: {units}), "
                   f"rms {a.rms:.2f} mm (up reversed: {a.flipped_rms:.2f} mm)")
        counts = {"geometry": 0, "name": 0, "both": 0}
        for guess in self.regions:
            counts[guess.source] += 1
        out.append(f"regions: {counts['both']} by geometry and name, {counts['geometry']} by "
                   f"geometry, {counts['name']} by name")
        for region, labels in self.region_table().items():
            out.append(f"  {region:14s} {', '.join(labels)}")
        for guess in self.regions:
            if guess.source == "name":
                out.append(f"  {guess.label}: {guess.region} by its name (geometry: "
                           f"{guess.geometry})")
        out.append("landmark pairs (anatomical point: marker):")
        for pair in self.landmarks:
            on_mesh = "" if pair.point in self.mesh_landmarks.landmarks else \
                " (the mesh has no such landmark: unused by the binding)"
            out.append(f"  {pair.point:20s} {pair.label:16s} {pair.source}: {pair.how}"
                       f"{on_mesh}")
        where = "found from the mesh" if self.mesh_landmarks.found else "given"
        out.append(f"mesh landmarks ({where}): " + ", ".join(
            f"{p} {v}" for p, v in self.mesh_landmarks.landmarks.items()))
        out += self.notes
        for q in self.questions:
            out.append(f"OPEN QUESTION ({q.file}) {q.key}: {q.text}")
        return out


def _vec(v) -> str:
    return "(" + ", ".join(f"{c:+.2f}" for c in v) + ")"


def _flag(take: Take, prefix: str, names, others) -> tuple:
    """Markers not worth keeping, with the reason."""
    presence = (~take.missing).mean(axis=0)
    flagged = []
    for label, name, p in zip(take.labels, names, presence):
        if is_unlabeled(name):
            flagged.append((label, f"an unlabeled marker (visible in {100 * p:.0f} % of the "
                                   "frames)"))
        elif label in others:
            flagged.append((label, f"another subject's marker (not {prefix!r})"))
        elif p < MIN_PRESENCE:
            flagged.append((label, f"visible in {100 * p:.0f} % of the frames, under "
                                   f"{100 * MIN_PRESENCE:.0f} %"))
    return tuple(flagged)


def _rigid_spread(take: Take, labels) -> float:
    """Largest standard deviation (mm) of the distance between two of `labels` over the take."""
    _, std, _ = distance_variation(take.select(labels).positions)
    return float(std.max())


def _up_evidence(axes: FaceAxes, pose, motion, head_rows) -> tuple:
    """Sign (+1: up as is, -1: reversed, 0: no say) and strength of the motion and head cues."""
    height = axes.coordinates(pose)[:, 1]
    cues = []
    face = np.ones(len(pose), dtype=bool)
    face[head_rows] = False
    if face.sum() >= 4 and np.ptp(motion[face]) > 0:
        corr = float(np.corrcoef(height[face], motion[face])[0, 1])
        cues.append(("motion", -np.sign(corr), abs(corr),
                     f"the markers that move most sit {'low' if corr < 0 else 'high'} "
                     f"(correlation of motion with height {corr:+.2f}): jaw and lips are below"))
    if len(head_rows):
        above = float(height[head_rows].mean() - height[face].mean())
        cues.append(("head", np.sign(above), 1.0,
                     f"the head markers sit {abs(above):.0f} mm "
                     f"{'above' if above > 0 else 'below'} the face's centre"))
    return cues


def infer_capture(take: Take, mesh: Mesh, *, mesh_landmarks=None) -> Inference:
    """Infer the marker set, the stabilization and the landmark pairs of a capture.

    Parameters
    ----------
    take : Take
        The raw capture (mm, any frame, gaps as NaN).
    mesh : Mesh
        The neutral face mesh to bind to (any units, any orientation).
    mesh_landmarks : mapping of str to int, optional
        The mesh's landmarks, if it has some; otherwise they are found from
        the mesh (:func:`mocap.infer.mesh_landmarks.find_mesh_landmarks`).

    Returns
    -------
    Inference

    Raises
    ------
    InputError
        Fewer than 4 face markers kept; a mesh without landmarks and without
        the loops to find them.

    Notes
    -----
    Steps: names (:func:`mocap.infer.names.split_prefix`, :func:`parse_name`);
    markers not kept (unlabeled names, another subject's prefix, visible in
    under half the frames); a provisional head frame (the markers named as
    head markers, or the ``auto`` choice among all kept markers) and the rest
    pose in it (each marker's median); the face axes
    (:func:`mocap.infer.axes.face_axes`); the alignment to the mesh for both
    signs of up (:func:`mocap.infer.alignment.align_to_mesh`), kept when
    decisive (:data:`UP_DECISIVE`), else decided by where the markers that
    move most sit (the jaw is below) and where head markers sit; three or
    more markers farther than :data:`OFF_FACE_MM` from the aligned surface
    that hold their distances to within :data:`RIGID_HEAD_MM` are an open
    question (a headband whose names say nothing?); the regions
    (:func:`mocap.infer.regions.classify_markers`) and the landmark pairs
    (:func:`mocap.infer.landmark_pairs.pair_landmarks`); without head
    markers, the stabilization markers among the face markers outside the
    regions the jaw moves (:data:`mocap.head_frame.JAW_REGIONS`).
    """
    take = as_take(take)
    if not isinstance(mesh, Mesh):
        raise InputError(f"mesh must be a mocap.mesh.mesh.Mesh, got {type(mesh).__name__}")
    prefix, names, others = split_prefix(take.labels)
    hints = {label: parse_name(label, prefix) for label in take.labels}
    flagged = _flag(take, prefix, names, others)
    dropped = {label for label, _ in flagged}
    kept = [x for x in take.labels if x not in dropped]
    head = [x for x in kept if hints[x].region == "head"]
    questions, notes = [], []
    if 0 < len(head) < 3:
        notes.append(f"names: {', '.join(head)} look like head markers, but a rigid head fit "
                     "needs 3: taken as face markers")
        head = []
    marks = _mesh_marks(mesh, mesh_landmarks)

    face = [x for x in kept if x not in head]
    if len(face) < 4:
        raise InputError(f"{len(face)} face markers kept ({', '.join(face)}); inference "
                         "needs at least 4")
    pose, motion, in_head = _rest_pose(take, face, head)
    rows = np.arange(len(face))
    alignment = align_to_mesh(pose[rows], face_axes(pose[rows]), mesh, marks)
    cues = _up_evidence(alignment.axes, pose, motion, np.arange(len(face), len(pose)))
    axes, alignment, up_question = _decide_up(alignment, cues, pose[rows], mesh, marks)
    off = [face[i] for i in np.flatnonzero(alignment.distances > OFF_FACE_MM)]
    if len(off) >= 3:                            # the rigid part of what is off the face
        off = list(find_stable_markers(take, off).labels)
        if _rigid_spread(take, off) <= RIGID_HEAD_MM:
            questions.append(OpenQuestion(
                "head_markers", "markerset",
                f"{', '.join(off)} sit more than {OFF_FACE_MM:g} mm off the face and keep "
                f"their distances (within {_rigid_spread(take, off):.2f} mm): if they are on "
                "a headband or a helmet, move them (and any others of it) from [regions] to "
                "head = [...] and set stabilize = 'head' in run.toml"))
    if up_question is not None:
        questions.append(up_question)
    if head and _rigid_spread(take, head) > RIGID_HEAD_MM:
        questions.append(OpenQuestion(
            "rigid_head", "markerset",
            f"the head markers {', '.join(head)} do not move as one rigid body (their "
            f"distances vary by up to {_rigid_spread(take, head):.1f} mm): keep them as "
            "head = [...] or move them to [regions] and use stabilize = 'auto'"))
    neutral = int(np.nanargmin(np.nanmean(np.sum((in_head - pose) ** 2, axis=-1), axis=1)))

    xy_face, _ = face_coordinates(alignment.on_mesh, marks)
    regions = classify_markers(face, alignment.on_mesh, marks, hints)
    questions += [OpenQuestion(f"region_{g.label}", "markerset", g.question)
                  for g in regions if g.question]
    mirrored = _mirrored(regions, hints)
    if mirrored is not None:
        questions.append(mirrored)
    all_rows = face + head
    on_mesh_all = np.vstack([alignment.on_mesh,
                             _closest(mesh, alignment.to_mesh(pose[len(face):]))])
    xy = np.vstack([xy_face, face_coordinates(on_mesh_all[len(face):], marks)[0]])
    region_of = {g.label: g.region for g in regions} | {x: "head" for x in head}
    upper = [x for x in face if region_of[x] not in JAW_REGIONS]
    stable = None if head else find_stable_markers(take, upper if len(upper) >= 3 else face)
    height = _height(marks)
    landmarks = pair_landmarks(all_rows, region_of, xy, on_mesh_all, marks, mesh.vertices,
                               hints=hints, height=height)
    if sum(p.point in marks.landmarks for p in landmarks) < 3:
        questions.append(OpenQuestion(
            "landmarks", "markerset",
            "fewer than 3 landmark pairs were found (the binding needs 3 anatomical points "
            "named both in [landmarks] and by the mesh landmarks): name the markers on the "
            "mouth corners, the nose tip or the chin in [landmarks]"))
    return Inference(labels=take.labels, prefix=prefix, hints=hints, flagged=flagged,
                     head=tuple(head), face=tuple(face),
                     stabilization="head" if head else "auto", stable=stable,
                     neutral_frame=neutral, pose=pose, axes=axes, alignment=alignment,
                     mesh_landmarks=marks, regions=regions, landmarks=landmarks, xy=xy,
                     questions=questions, notes=notes)


def _rest_pose(take: Take, face, head) -> tuple:
    """Each marker's median in a provisional head frame (head markers, or the auto choice).

    Returns the pose (M, 3) and the motion (M,) of face + head markers, mm, and the
    positions in the head frame (T, M, 3).
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # provisional: the report comes later
        frame = find_head_frame(take, method="head" if head else "auto",
                                candidates=face + head, markerset=_head_set(head))
    in_head = frame.take.select(face + head).positions
    pose = nan_column_medians(in_head)
    motion = np.sqrt(np.nanmean(np.sum((in_head - pose) ** 2, axis=-1), axis=0))
    return pose, motion, in_head


def _head_set(head):
    """A minimal marker set naming `head` (for :func:`find_head_frame`), or None."""
    return MarkerSet(name="init", head=tuple(head), regions={}) if head else None


def _mesh_marks(mesh: Mesh, given) -> MeshLandmarks:
    if given is None:
        return find_mesh_landmarks(mesh)
    given = check_mesh_landmarks(given, mesh.n_vertices, where="mesh landmarks")
    try:                                   # the levels of the loops help the regions
        found = find_mesh_landmarks(mesh)
    except InputError:
        return mesh_axes_from_landmarks(mesh, given)
    from_file = mesh_axes_from_landmarks(mesh, given)
    return MeshLandmarks(landmarks=dict(given), axes=found.axes, levels=found.levels,
                         coordinates={n: found.axes.coordinates(mesh.vertices[v])
                                      for n, v in given.items()} | {
                             n: c for n, c in found.coordinates.items() if n not in given},
                         mouth=found.mouth, eyes=found.eyes, found=False,
                         notes=from_file.notes)


def _height(marks: MeshLandmarks) -> float:
    c = marks.coordinates
    mouth = (c["mouth_corner_left"][1] + c["mouth_corner_right"][1]) / 2
    eyes = np.mean([c[p][1] for p in ("eye_inner_left", "eye_outer_left", "eye_inner_right",
                                      "eye_outer_right")])
    return float(eyes - mouth)


def _closest(mesh: Mesh, points) -> np.ndarray:
    """Closest surface points (K, 3) of a mesh."""
    if len(points) == 0:
        return np.zeros((0, 3))
    faces, bary, _ = closest_surface_points(mesh, points)
    return np.einsum("mk,mkc->mc", bary, mesh.vertices[mesh.faces[faces]])


def _decide_up(alignment: Alignment, cues, points, mesh, marks) -> tuple:
    """Keep the alignment's up when decisive, else follow the cues; an open question if none."""
    ratio = alignment.flipped_rms / max(alignment.rms, 1e-9)
    evidence = [f"mesh: the other up fits {ratio:.2f} times worse "
                f"({alignment.flipped_rms:.1f} vs {alignment.rms:.1f} mm)"]
    evidence += [c[3] for c in cues]
    vote = sum(sign * strength for name, sign, strength, _ in cues
               if name == "head" or strength >= _MOTION_DECISIVE)
    question = None
    axes = alignment.axes
    if ratio < UP_DECISIVE:
        if vote < 0:                                     # the cues say the other way
            alignment = align_to_mesh(points, axes.flipped(), mesh, marks, both=False)
            evidence.append("up decided by the cues above (the mesh fit was not decisive)")
        elif vote == 0:
            question = OpenQuestion(
                "up", "markerset",
                f"which way is up could not be decided (the mesh fits both ways within "
                f"{100 * (ratio - 1):.0f} %, and the markers' motion says nothing): look at "
                "init.png; if the face is upside down, reverse the axis in the capture or "
                "give the mesh landmarks")
    elif vote < 0:
        evidence.append("the cues disagree with the mesh fit: the mesh fit was kept")
    axes = FaceAxes(alignment.axes.left, alignment.axes.up, alignment.axes.forward,
                    alignment.axes.origin, alignment.axes.symmetry_rms, tuple(evidence))
    return axes, dataclasses.replace(alignment, axes=axes), question


def _mirrored(regions, hints) -> OpenQuestion | None:
    """An open question when the names put most markers on the other side than geometry."""
    agree = disagree = 0
    for g in regions:
        side = hints[g.label].side
        if side is None or abs(g.x) < 0.1:
            continue
        if (side == "left") == (g.x > 0):
            agree += 1
        else:
            disagree += 1
    if disagree >= 3 and disagree > agree:
        return OpenQuestion(
            "mirrored", "markerset",
            f"{disagree} marker names give the other side than the geometry ({agree} agree): "
            "is the capture's coordinate system left-handed (mirrored)? Left and right below "
            "follow the geometry of a right-handed frame")
    return None

