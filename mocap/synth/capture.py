"""Capture simulation: a face mesh driven by a weight performance, seen by markers.

Ground truth for every stage: the mesh ``v(t) = v0 + Σ w_i(t) e_i`` is
evaluated at the few vertices a marker layout reads, the markers are placed
on it, moved rigidly with a smooth random head motion, scaled to millimetres,
blurred by noise and cut by occlusion gaps. :func:`simulate_capture` returns
the take and a :class:`CaptureTruth` with everything before noise and gaps.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from mocap.errors import FileFormatError, InputError
from mocap.mesh.layout import MarkerLayout
from mocap.synth.performance import Performance, performance_weights, resample_performance
from mocap.take import SourceInfo, Take
from mocap.units import mm_per_unit as _mm_per_unit
from mocap.util.arrays import read_only
from mocap.util.atomic import atomic_path
from mocap.util.npz import read_npz_with_meta
from mocap.util.validation import as_float_array, as_int, as_positive_float

__all__ = ["CaptureTruth", "SimulatedCapture", "simulate_capture", "load_capture_truth"]

_FORMAT = "mocap2mesh-synth-truth-1"
#: The head frame is the mesh frame (ICT: x the subject's left, y up, z forward);
#: the world is a capture volume's (z up, the face looking towards -y).
_WORLD_FROM_MESH = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
#: Where the head sits in the capture volume, mm (a standing subject).
_HEAD_HOME_MM = np.array([0.0, 0.0, 1600.0])
#: A head marker is this many times less likely to be occluded than a face marker.
_HEAD_GAP_ODDS = 0.1
#: Frames evaluated per block (the layout's normals take ~170 kB of temporaries per frame).
_CHUNK = 512


@dataclass(frozen=True, eq=False)
class CaptureTruth:
    """What a simulated capture really was.

    ``world = rotation[t] @ head + translation[t]`` for every marker, with
    ``head`` the mesh frame scaled to millimetres.

    Attributes
    ----------
    labels : tuple of str
        Marker labels (the layout's), M of them.
    head_markers : tuple of str
        Markers that moved rigidly with the head (placed on the neutral).
    shape_names : tuple of str
        Basis shapes, n of them.
    weights : ndarray of shape (T, n)
        Weight of each shape at each frame; NaN where the performance lost tracking.
    rotation : ndarray of shape (T, 3, 3)
    translation : ndarray of shape (T, 3), mm
    markers_world : ndarray of shape (T, M, 3), mm
        True marker positions in the capture volume, before noise and gaps.
    markers_head : ndarray of shape (T, M, 3), mm
        The same in the head frame (the mesh frame, in mm).
    missing : ndarray of bool, shape (T, M)
        Occluded samples and the face markers of frames where the performance
        lost tracking (NaN in the take).
    rate : float, Hz
    mm_per_unit : float
        Millimetres per mesh unit (10 for a mesh in cm).
    noise_mm : float
        Standard deviation of the noise added to each coordinate, mm.
    seed : int
    layout_name, mesh : str
        The layout's name and the neutral mesh's file.
    """

    labels: tuple
    head_markers: tuple
    shape_names: tuple
    weights: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    markers_world: np.ndarray
    markers_head: np.ndarray
    missing: np.ndarray
    rate: float
    mm_per_unit: float
    noise_mm: float
    seed: int
    layout_name: str = ""
    mesh: str = ""

    def __post_init__(self):
        for name in ("labels", "head_markers", "shape_names"):
            object.__setattr__(self, name, tuple(str(x) for x in getattr(self, name)))
        n_frames, n_markers = len(self.weights), len(self.labels)
        shapes = {"weights": (n_frames, len(self.shape_names)), "rotation": (n_frames, 3, 3),
                  "translation": (n_frames, 3), "markers_world": (n_frames, n_markers, 3),
                  "markers_head": (n_frames, n_markers, 3), "missing": (n_frames, n_markers)}
        for name, shape in shapes.items():
            if np.shape(getattr(self, name)) != shape:
                raise InputError(f"truth {name} must have shape {shape}, "
                                 f"got {np.shape(getattr(self, name))}")
            object.__setattr__(self, name, read_only(getattr(self, name), copy=True))

    @property
    def n_frames(self) -> int:
        """Number of frames T."""
        return len(self.weights)

    def save(self, path, *, inputs=()) -> None:
        """Write the truth to a ``.npz`` archive atomically (see :func:`load_capture_truth`)."""
        meta = {"format": _FORMAT, "rate": self.rate, "mm_per_unit": self.mm_per_unit,
                "noise_mm": self.noise_mm, "seed": self.seed, "layout_name": self.layout_name,
                "mesh": self.mesh}
        arrays = {name: getattr(self, name) for name in (
            "weights", "rotation", "translation", "markers_world", "markers_head", "missing")}
        arrays.update({name: np.array(getattr(self, name), dtype=str)
                       for name in ("labels", "head_markers", "shape_names")})
        with atomic_path(path, inputs=inputs) as tmp:
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, meta=np.array(json.dumps(meta)), **arrays)


def load_capture_truth(path) -> CaptureTruth:
    """Read a truth archive written by :meth:`CaptureTruth.save`.

    Raises
    ------
    FileFormatError
        Not such an archive, damaged, or with inconsistent shapes.
    """
    path = Path(path)
    meta, arrays = read_npz_with_meta(path, "capture-truth archive", _FORMAT)
    try:
        return CaptureTruth(rate=float(meta["rate"]), mm_per_unit=float(meta["mm_per_unit"]),
                            noise_mm=float(meta["noise_mm"]), seed=int(meta["seed"]),
                            layout_name=str(meta["layout_name"]), mesh=str(meta["mesh"]),
                            **arrays)
    except (KeyError, TypeError, InputError) as exc:
        raise FileFormatError(path, f"bad or missing truth field: {exc}") from None


@dataclass(frozen=True, eq=False)
class SimulatedCapture:
    """Result of :func:`simulate_capture`.

    Attributes
    ----------
    take : Take
        The capture as a system would record it: mm, world frame, noise, NaN gaps.
    truth : CaptureTruth
    """

    take: Take
    truth: CaptureTruth


def _subset_layout(layout: MarkerLayout) -> tuple[np.ndarray, MarkerLayout]:
    """The vertices a layout reads (K,) and the same layout on just those vertices.

    A marker reads its triangle's corners and, when it sits off the skin, the
    faces around those corners (for the normals): the sub-layout keeps exactly
    these faces, so it gives the same positions from K vertices as the layout
    from all N.
    """
    corners = np.unique(layout.vertex_ids[layout.offsets != 0])
    faces = layout.faces[np.isin(layout.faces, corners).any(axis=1)]
    needed = np.unique(np.concatenate([layout.vertex_ids.ravel(), faces.ravel()]))
    sub = MarkerLayout(layout.labels, np.searchsorted(needed, layout.vertex_ids),
                       layout.weights, layout.face_ids, layout.offsets,
                       np.searchsorted(needed, faces), len(needed), units=layout.units,
                       name=layout.name)
    return needed, sub


def _band_limited(rng: np.random.Generator, n_frames: int, rate: float, cutoff_hz: float,
                  n_channels: int) -> np.ndarray:
    """Smooth zero-mean signals (n_frames, n_channels), each peaking at exactly 1.

    White noise with its spectrum cut above `cutoff_hz` (at least the lowest
    non-zero frequency is kept), then scaled to a peak absolute value of 1.
    """
    noise = rng.standard_normal((n_frames, n_channels))
    spectrum = np.fft.rfft(noise, axis=0)
    freqs = np.fft.rfftfreq(n_frames, d=1.0 / rate)
    keep = (freqs <= cutoff_hz) | (np.arange(len(freqs)) == 1)
    keep[0] = False
    signal = np.fft.irfft(spectrum * keep[:, None], n=n_frames, axis=0)
    peak = np.abs(signal).max(axis=0)
    return np.divide(signal, peak, out=np.zeros_like(signal), where=peak > 0)


def _head_motion(rng, n_frames, rate, degrees, mm, cutoff_hz):
    """Rotations (T, 3, 3) and translations (T, 3) mm of a smooth random head motion."""
    signals = _band_limited(rng, n_frames, rate, cutoff_hz, 6)
    rotvec = np.deg2rad(degrees) * signals[:, :3]
    motion = Rotation.from_rotvec(rotvec).as_matrix().reshape(n_frames, 3, 3)
    rotation = _WORLD_FROM_MESH @ motion
    translation = _HEAD_HOME_MM + mm * signals[:, 3:]
    return rotation, translation


def _gap_mask(rng, n_frames, n_markers, n_gaps, max_frames, head_idx) -> np.ndarray:
    """Occlusion mask (T, M): `n_gaps` seeded gaps, log-uniform lengths of 1..max_frames.

    Head markers are picked :data:`_HEAD_GAP_ODDS` times as often as face
    markers, and a head gap overlapping another head gap is dropped, so that
    at most one head marker is missing at a time.
    """
    mask = np.zeros((n_frames, n_markers), dtype=bool)
    if n_gaps == 0 or n_frames == 0:
        return mask
    odds = np.ones(n_markers)
    odds[head_idx] = _HEAD_GAP_ODDS
    marker = rng.choice(n_markers, size=n_gaps, p=odds / odds.sum())
    max_frames = min(max_frames, n_frames)
    length = np.clip(np.floor(np.exp(rng.uniform(0, np.log(max_frames + 1), n_gaps))),
                     1, max_frames).astype(np.int64)
    start = np.floor(rng.uniform(0, 1, n_gaps) * (n_frames - length + 1)).astype(np.int64)
    stop = start + length
    keep = ~np.isin(marker, head_idx)
    taken = np.zeros(n_frames, dtype=bool)
    for g in np.flatnonzero(~keep):            # a few head gaps, not frames
        if not taken[start[g]:stop[g]].any():
            taken[start[g]:stop[g]] = keep[g] = True
    edges = np.zeros((n_frames + 1, n_markers), dtype=np.int64)
    np.add.at(edges, (start[keep], marker[keep]), 1)
    np.add.at(edges, (stop[keep], marker[keep]), -1)
    return np.cumsum(edges[:-1], axis=0) > 0


def _with_neutral_lead(weights, n_lead, rate):
    """``weights`` (T, n) after ``n_lead`` frames of a neutral hold that blends into frame 0."""
    if n_lead == 0:
        return weights
    n_blend = min(int(round(0.5 * rate)), n_lead // 2)
    ramp = np.zeros(n_lead)
    if n_blend:
        ramp[n_lead - n_blend:] = 0.5 - 0.5 * np.cos(np.pi * np.arange(1, n_blend + 1)
                                                      / (n_blend + 1))
    # a lost first frame is not known: the hold then stays neutral until it
    return np.concatenate([ramp[:, None] * np.nan_to_num(weights[:1]), weights])


def _check_basis(basis, layout):
    for attr in ("names", "neutral", "displacements"):
        if not hasattr(basis, attr):
            raise InputError(f"basis must have names, neutral and displacements (an "
                             f"ArtistBasis), got {type(basis).__name__}")
    neutral = basis.neutral
    displacements = np.asarray(basis.displacements, dtype=np.float64)
    if displacements.shape != (len(basis.names), neutral.n_vertices, 3):
        raise InputError(f"basis displacements must have shape ({len(basis.names)}, "
                         f"{neutral.n_vertices}, 3), got {displacements.shape}")
    if not isinstance(layout, MarkerLayout):
        raise InputError(f"layout must be a MarkerLayout, got {type(layout).__name__}")
    if layout.n_vertices != neutral.n_vertices or not np.array_equal(layout.faces,
                                                                     neutral.faces):
        raise InputError(f"layout {layout.name!r} was made for a mesh of {layout.n_vertices} "
                         f"vertices and {len(layout.faces)} triangles, but the neutral has "
                         f"{neutral.n_vertices} and {neutral.n_faces}")
    return neutral, displacements


def simulate_capture(basis, performance: Performance, layout: MarkerLayout, head_markers, *,
                     rate: float = 100.0, start: float = 0.0, duration: float | None = None,
                     noise_mm: float = 0.2, n_gaps: int = 0, max_gap_s: float = 1.0,
                     head_rotation_deg: float = 15.0, head_translation_mm: float = 30.0,
                     head_cutoff_hz: float = 0.5, mm_per_unit: float | None = None,
                     neutral_lead_s: float = 0.0, seed: int = 0) -> SimulatedCapture:
    """Simulate an optical capture of a face driven by a weight performance.

    Parameters
    ----------
    basis : ArtistBasis
        Any object with ``names`` (n), ``neutral`` (a :class:`mocap.mesh.mesh.Mesh`,
        N vertices) and ``displacements`` (n, N, 3), mesh units
        (:func:`basis.artist.load_artist_basis`).
    performance : Performance
        Weights over time; resampled to `rate` and mapped onto the shapes by
        :func:`mocap.synth.performance.performance_weights` (warns about unmatched names).
        Where its tracking was lost (NaN weights) the face is unknown: the face
        markers are missing in those frames (head markers are seen), the truth
        holds NaN there, and a warning says so; fill the performance first
        (:func:`mocap.synth.performance_gaps.fill_tracking_gaps`) to have a face
        everywhere.
    layout : MarkerLayout
        Markers on the neutral's topology (M of them).
    head_markers : sequence of str
        Layout markers that sit on the rigid head (a marker set's ``head``):
        placed on the neutral at every frame instead of on the deformed skin.
    rate : float, default 100, Hz
    start : float, default 0, s
        Where in the performance the capture starts.
    duration : float, optional, s
        Length of the capture (default: to the end of the performance).
    noise_mm : float, default 0.2
        Standard deviation of the Gaussian noise of each coordinate, mm (0: none).
    n_gaps : int, default 0
        Occlusion gaps to cut (overlapping gaps merge; head gaps that would
        leave two head markers missing at once are dropped).
    max_gap_s : float, default 1
        Longest gap, s; lengths are log-uniform from one frame, so most are short.
    head_rotation_deg, head_translation_mm : float, default 15 and 30
        Peak of each rotation-vector component (deg) and of each translation
        component (mm) of the head motion about its home pose (0: none).
    head_cutoff_hz : float, default 0.5
        Band limit of the head motion.
    mm_per_unit : float, optional
        Millimetres per mesh unit; default from ``layout.units`` (:mod:`mocap.units`).
    neutral_lead_s : float, default 0, s
        Start the capture with this long a neutral hold, as a capture session
        does: every weight 0, then, over the hold's last ``min(0.5 s, half)``,
        a raised-cosine blend into the performance's first frame (head motion,
        noise and gaps go on throughout). The performance follows, so the
        take is this much longer; ``truth.weights`` covers the lead-in too.
    seed : int, default 0
        Head motion, noise and gaps use independent streams of this seed.

    Returns
    -------
    SimulatedCapture
        ``take``: positions (T, M, 3) mm in the world frame, NaN in the gaps,
        labels of the layout, `rate`. ``truth``: :class:`CaptureTruth`.

    Raises
    ------
    InputError
        A layout of another mesh, unknown units, a head marker absent from the
        layout, no performance column matching a shape, bad option values.

    Notes
    -----
    Head frame: the mesh frame in mm. World: ``R(t) = A @ exp(θ(t))``, ``t(t) =
    h + d(t)``, with A turning the mesh's y-up, z-forward frame into a z-up
    capture volume where the face looks towards -y, h = (0, 0, 1600) mm, and
    θ(t), d(t) white noise low-passed at `head_cutoff_hz` and scaled to their
    peaks. The mesh is evaluated only at the K vertices the layout reads,
    ``v_K(t) = v0_K + W(t) E_K``, in blocks of frames.
    """
    neutral, displacements = _check_basis(basis, layout)
    head_markers = tuple(str(h) for h in head_markers)
    head_idx = np.array([layout.index(h) for h in head_markers], dtype=np.int64)
    rate = as_positive_float(rate, "rate")
    noise_mm = float(as_float_array(noise_mm, "noise_mm", ndim=0, allow_nan=False))
    head_rotation_deg = float(as_float_array(head_rotation_deg, "head_rotation_deg", ndim=0,
                                             allow_nan=False))
    head_translation_mm = float(as_float_array(head_translation_mm, "head_translation_mm",
                                               ndim=0, allow_nan=False))
    if min(noise_mm, head_rotation_deg, head_translation_mm) < 0:
        raise InputError("noise_mm, head_rotation_deg and head_translation_mm must be >= 0")
    n_gaps = as_int(n_gaps, "n_gaps", minimum=0)
    max_gap = max(1, int(round(as_positive_float(max_gap_s, "max_gap_s") * rate)))
    head_cutoff_hz = as_positive_float(head_cutoff_hz, "head_cutoff_hz")
    neutral_lead_s = float(as_float_array(neutral_lead_s, "neutral_lead_s", ndim=0,
                                          allow_nan=False))
    if neutral_lead_s < 0:
        raise InputError(f"neutral_lead_s must be >= 0, got {neutral_lead_s}")
    seed = as_int(seed, "seed", minimum=0)
    if mm_per_unit is None:
        if layout.units is None:
            raise InputError(f"the units of layout {layout.name!r} (and its mesh) are unknown: "
                             "load the mesh with units= (mocap2mesh synth --units) or pass mm_per_unit")
        mm_per_unit = _mm_per_unit(layout.units, where=f"layout {layout.name!r}")
    scale = as_positive_float(mm_per_unit, "mm_per_unit")

    grid = resample_performance(performance, rate, start=start, duration=duration)
    weights = _with_neutral_lead(performance_weights(grid, basis.names),
                                 int(round(neutral_lead_s * rate)), rate)
    n_frames, n_markers = len(weights), layout.n_markers
    lost = np.isnan(weights).any(axis=1)
    if lost.any():
        warnings.warn(f"{performance.path or 'performance'}: tracking was lost in {lost.sum()} "
                      f"of the capture's {n_frames} frames ({lost.sum() / rate:.2f} s): its face "
                      "markers are missing there and the truth's weights NaN; fill the "
                      "performance's gaps to have a face in every frame", UserWarning,
                      stacklevel=2)

    needed, sub = _subset_layout(layout)
    v0 = neutral.vertices[needed]
    local = displacements[:, needed].reshape(len(basis.names), -1)
    skin = np.empty((n_frames, n_markers, 3))
    known = np.nan_to_num(weights)                        # the lost frames are cut below
    for lo in range(0, n_frames, _CHUNK):                  # blocks of frames
        block = (known[lo:lo + _CHUNK] @ local).reshape(-1, len(needed), 3) + v0
        skin[lo:lo + _CHUNK] = sub.positions(block)
    skin[lost] = np.nan
    skin[:, head_idx] = sub.positions(v0)[head_idx]
    markers_head = scale * skin

    motion_rng, noise_rng, gap_rng = (np.random.default_rng(s)
                                      for s in np.random.SeedSequence(seed).spawn(3))
    rotation, translation = _head_motion(motion_rng, n_frames, rate, head_rotation_deg,
                                         head_translation_mm, head_cutoff_hz)
    world = np.einsum("tij,tmj->tmi", rotation, markers_head) + translation[:, None]
    missing = _gap_mask(gap_rng, n_frames, n_markers, n_gaps, max_gap, head_idx)
    missing |= np.isnan(world[:, :, 0])
    observed = world + noise_mm * noise_rng.standard_normal(world.shape)
    observed[missing] = np.nan

    mesh_name = neutral.path or ""
    take = Take(layout.labels, observed, rate, source=SourceInfo(
        format="memory", producer="mocap2mesh synth",
        extra={"seed": seed, "layout": layout.name, "mesh": mesh_name,
               "neutral_lead_s": neutral_lead_s,
               "performance": performance.path or ""}))
    truth = CaptureTruth(labels=layout.labels, head_markers=head_markers,
                         shape_names=basis.names, weights=weights, rotation=rotation,
                         translation=translation, markers_world=world,
                         markers_head=markers_head, missing=missing, rate=rate,
                         mm_per_unit=scale, noise_mm=noise_mm, seed=seed,
                         layout_name=layout.name, mesh=mesh_name)
    return SimulatedCapture(take, truth)
