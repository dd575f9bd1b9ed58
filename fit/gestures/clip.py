"""Reference clips of the gesture palette: features of an analysed take and its speech intensity.

A clip holds, per frame: the speech intensity S(t), the blend weights c(t),
the head motion (rotation vector and translation relative to the clip's mean
head pose) and the detail groups D_j(t). Saved as ``.npz``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np
from scipy.spatial.transform import Rotation

from fit.gestures.analysis import GestureAnalysis
from fit.gestures.features import DETAIL_FEATURES, weight_columns
from fit.gestures.speech import OPENING_WINDOW_S, speech_intensity
from mocap.errors import FileFormatError, InputError
from mocap.synth.performance import Performance, performance_weights, resample_performance
from mocap.util.arrays import read_only
from mocap.util.atomic import atomic_path
from mocap.util.npz import read_npz
from mocap.util.validation import as_float_array, as_positive_float

__all__ = ["GestureClip", "clip_from_analysis", "clip_from_performance", "save_clip",
           "load_clip", "ACTIVITY_COLUMNS"]

#: Performance columns whose sum stands in for speech loudness in a clip
#: recorded without audio: mouth opening tracks the energy of speech.
ACTIVITY_COLUMNS = ("JawOpen",)
#: RMS window of the activity proxy, s (a few frames at 30 Hz).
ACTIVITY_WINDOW_S = OPENING_WINDOW_S

_FORMAT = "mocap2mesh-gesture-clip-1"


@dataclass(frozen=True, eq=False)
class GestureClip:
    """One reference clip (a "style") of the palette.

    Attributes
    ----------
    name : str
        Style name used by timelines.
    rate : float, Hz
    intensity : ndarray of shape (n_frames,)
        S(t), dB (or any loudness proxy: it is standardized per clip).
    weights : ndarray of shape (n_frames, n_shapes)
        c(t); NaN frames are never matched nor copied.
    names : tuple of str
        Shape names.
    head : ndarray of shape (n_frames, 6) or None
        Rotation vector r (rad) and translation τ (mm) of the head relative to
        the clip's mean pose, in the head frame: a head-frame point x is at
        ``exp(r(t)) x + τ(t)`` in the frame of the mean pose, i.e.
        ``R(t) = R_mean exp(r(t))`` and ``T(t) = T_mean + R_mean τ(t)``.
    details : mapping of str to ndarray of shape (n_frames, n_group_markers, 3), mm
        D_j(t) per detail group (head frame).
    detail_labels : mapping of str to tuple of str
        Marker labels of each detail group.
    intensity_source : str
        What S(t) was made of (speech, an analog channel, a stand-in), for the record.
    """

    name: str
    rate: float
    intensity: np.ndarray
    weights: np.ndarray
    names: tuple
    head: np.ndarray | None = None
    details: Mapping[str, np.ndarray] = field(default_factory=dict)
    detail_labels: Mapping[str, tuple] = field(default_factory=dict)
    intensity_source: str = ""

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise InputError(f"a clip name must be a non-empty string, got {self.name!r}")
        object.__setattr__(self, "rate", as_positive_float(self.rate, "rate"))
        intensity = as_float_array(self.intensity, "intensity", ndim=1)
        n = len(intensity)
        names = tuple(str(x) for x in self.names)
        weights = as_float_array(self.weights, "weights", shape=(n, len(names)))
        object.__setattr__(self, "intensity", read_only(intensity))
        object.__setattr__(self, "weights", read_only(weights))
        object.__setattr__(self, "names", names)
        if self.head is not None:
            head = as_float_array(self.head, "head", shape=(n, 6))
            object.__setattr__(self, "head", read_only(head))
        details, labels = {}, {}
        for group, values in self.details.items():
            if group not in DETAIL_FEATURES:
                raise InputError(f"unknown detail group {group!r}; expected one of "
                                 f"{list(DETAIL_FEATURES)}")
            values = as_float_array(values, f"details[{group!r}]", shape=(n, None, 3))
            members = tuple(self.detail_labels.get(group, ()))
            if len(members) != values.shape[1]:
                raise InputError(f"detail group {group!r} has {values.shape[1]} markers but "
                                 f"{len(members)} labels")
            details[group], labels[group] = read_only(values), members
        object.__setattr__(self, "details", details)
        object.__setattr__(self, "detail_labels", labels)

    @property
    def n_frames(self) -> int:
        """Number of frames T."""
        return len(self.intensity)

    def features(self, weight_groups: Mapping | None = None) -> dict:
        """Feature name (:data:`fit.gestures.features.FEATURES`) to values (n_frames, d).

        The blend weights are split into ``weights``, ``blinks`` and ``brows``
        by :func:`fit.gestures.features.weight_columns` (`weight_groups`).
        """
        out = {f: self.weights[:, cols]
               for f, cols in weight_columns(self.names, weight_groups).items()}
        if self.head is not None:
            out["head"] = self.head
        out.update({g: v.reshape(self.n_frames, -1) for g, v in self.details.items()})
        return out


def clip_from_analysis(analysis: GestureAnalysis, intensity, *, name: str,
                       intensity_source: str = "") -> GestureClip:
    """A palette clip from an analysed take and its speech intensity.

    Parameters
    ----------
    analysis : GestureAnalysis
    intensity : array_like of shape (analysis.n_frames,), dB
        S(t) at the take's frames (:mod:`fit.gestures.speech`).
    name : str
    intensity_source : str, optional
        What `intensity` was made of (kept in the clip).

    Returns
    -------
    GestureClip
        Head motion relative to the mean rotation R_mean (chordal L2 mean) and
        mean translation T_mean of the frames with a transform, in the head
        frame (see :class:`GestureClip`); NaN where there is none.
    """
    if not isinstance(analysis, GestureAnalysis):
        raise InputError(f"analysis must be a GestureAnalysis, got {type(analysis).__name__}")
    intensity = as_float_array(intensity, "intensity", shape=(analysis.n_frames,))
    valid = np.isfinite(analysis.rotation).all(axis=(1, 2))
    head = np.full((analysis.n_frames, 6), np.nan)
    if valid.any():
        rot = Rotation.from_matrix(analysis.rotation[valid])
        mean = rot.mean()
        head[valid, :3] = (mean.inv() * rot).as_rotvec()
        trans = analysis.translation[valid]
        head[valid, 3:] = mean.inv().apply(trans - trans.mean(axis=0))
    return GestureClip(name, analysis.rate, intensity, analysis.weights, analysis.names,
                       head=head, details=dict(analysis.details),
                       detail_labels={g: analysis.groups[g] for g in analysis.details},
                       intensity_source=str(intensity_source))


def clip_from_performance(performance: Performance, *, name: str, rate: float, shapes=None,
                          activity=ACTIVITY_COLUMNS,
                          window: float = ACTIVITY_WINDOW_S) -> GestureClip:
    """A palette clip from a weight performance recorded without audio (e.g. ARKit).

    Parameters
    ----------
    performance : Performance
        :func:`mocap.synth.performance.read_performance`; resampled to `rate`.
    name : str
    rate : float, Hz
    shapes : sequence of str, optional
        Basis shape names to map the columns onto (:func:`performance_weights`);
        default: the performance's own columns.
    activity : sequence of str
        Columns whose sum stands in for the speech signal: S(t) is its RMS in
        dB over `window` (:func:`fit.gestures.speech.speech_intensity`).
    window : float, s

    Returns
    -------
    GestureClip
        Weights only (no head motion, no details). Where the performance lost
        tracking the clip's weights and intensity are NaN (never matched nor
        copied by the synthesis), and so is the intensity of the frames whose
        window reaches into such a gap.

    Raises
    ------
    InputError
        An activity column the performance does not have.
    """
    if not isinstance(performance, Performance):
        raise InputError(f"performance must be a Performance, got {type(performance).__name__}")
    grid = resample_performance(performance, rate)
    absent = [c for c in activity if c not in grid.names]
    if absent or not activity:
        raise InputError(f"{performance.path or 'performance'}: no activity column "
                         f"{absent or list(activity)} to stand in for speech")
    signal = grid.weights[:, [grid.names.index(c) for c in activity]].sum(axis=1)
    intensity = speech_intensity(np.nan_to_num(signal), rate, frame_rate=rate,
                                 n_frames=grid.n_frames, window=window)
    if grid.lost.any():
        reach = int(np.ceil(window * rate / 2))
        near = np.convolve(grid.lost, np.ones(2 * reach + 1), mode="same") > 0
        intensity[near] = np.nan
    if shapes is None:
        return GestureClip(name, rate, intensity, grid.weights, grid.names)
    shapes = tuple(str(x) for x in shapes)
    return GestureClip(name, rate, intensity, performance_weights(grid, shapes), shapes)


def save_clip(path, clip: GestureClip, *, inputs=()) -> None:
    """Write a clip as ``.npz``, atomically and never over one of `inputs` (:func:`load_clip`)."""
    if not isinstance(clip, GestureClip):
        raise InputError(f"clip must be a GestureClip, got {type(clip).__name__}")
    arrays = dict(format=np.array(_FORMAT), name=np.array(clip.name),
                  rate=np.float64(clip.rate), intensity=clip.intensity, weights=clip.weights,
                  names=np.array(clip.names, dtype=str),
                  intensity_source=np.array(clip.intensity_source))
    if clip.head is not None:
        arrays["head"] = clip.head
    for group, values in clip.details.items():
        arrays[f"details.{group}"] = values
        arrays[f"labels.{group}"] = np.array(clip.detail_labels[group], dtype=str)
    with atomic_path(path, inputs=inputs) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)


def load_clip(path) -> GestureClip:
    """Read a clip written by :func:`save_clip`.

    Raises
    ------
    FileFormatError
        Missing or unreadable file, not a gesture clip, inconsistent arrays.
    """
    path = Path(path)
    data = read_npz(path, "gesture clip", version=("format", _FORMAT))
    groups = [k.split(".", 1)[1] for k in data if k.startswith("details.")]
    try:
        return GestureClip(
            str(data["name"]), float(data["rate"]), data["intensity"], data["weights"],
            tuple(data["names"].tolist()), head=data.get("head"),
            details={g: data[f"details.{g}"] for g in groups},
            detail_labels={g: tuple(data[f"labels.{g}"].tolist()) for g in groups},
            intensity_source=str(data.get("intensity_source", "")))
    except (KeyError, InputError) as exc:
        raise FileFormatError(path, f"inconsistent gesture clip: {exc}") from None
