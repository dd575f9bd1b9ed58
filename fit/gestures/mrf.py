"""Speech-driven synthesis of facial gestures by a Markov random field (Ju & Lee 2008, sec. 5.1).

Each feature (:mod:`fit.gestures.features`: the blend weights c, the blink and
the brow weights, head motion, each detail group D_j) is its own Markov chain
over the frames of the reference clips of the palette: the next output frame
copies reference frame t̂, chosen among the best few candidates
of ``dist(t, t̂) = α Σ_j |S̃(t − j) − S(t̂ − j)|² + Σ_j |c̃(t − j) − c(t̂ − j)|²``
with probability ∝ exp(−dist/σ). A timeline assigns styles (clips) to time
segments, per feature.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from fit.gestures import _mrf
from fit.gestures.clip import GestureClip
from fit.gestures.features import DETAIL_FEATURES, FEATURES, weight_columns
from fit.gestures.timeline import Timeline
from mocap.errors import InputError
from mocap.util.validation import as_float_array, as_int, as_positive_float

__all__ = ["GestureSynthesis", "synthesize_gestures", "candidate_distances",
           "pick_candidate"]


@dataclass(frozen=True, eq=False)
class GestureSynthesis:
    """Synthesized gestures.

    Attributes
    ----------
    weights : ndarray of shape (n_frames, n_shapes)
        c̃(t), within the palette's range of each shape.
    names : tuple of str
    head_rotation : ndarray of shape (n_frames, 3, 3) or None
        R̃(t) relative to the mean head pose, in the head frame (None: no clip
        had head motion): a head-frame point x moves to ``R̃(t) x + T̃(t)``.
    head_translation : ndarray of shape (n_frames, 3) or None, mm
        T̃(t).
    details : mapping of str to ndarray of shape (n_frames, n_group_markers, 3), mm
        D̃_j(t), head frame of the reference subject.
    detail_labels : mapping of str to tuple of str
    intensity : ndarray of shape (n_frames,)
        The driving S̃(t), as given.
    rate : float, Hz
    sources : mapping of str to ndarray of shape (n_frames, 2), int
        For each feature, the (palette index, frame) each output frame copies.
    transitions : mapping of str to int
        Output frames where a feature jumps to a non-consecutive source frame.
    warps : mapping of str to int
        Of those, the frames copying a frame less than h from the continuation
        of the same clip: a stall (the frame just copied again), a short replay
        or a skip, i.e. a time warp of the reference rather than a transition.
    clip_names : tuple of str
        Names of the palette clips, in palette order.
    message : str
    """

    weights: np.ndarray
    names: tuple
    head_rotation: np.ndarray | None
    head_translation: np.ndarray | None
    details: Mapping[str, np.ndarray]
    detail_labels: Mapping[str, tuple]
    intensity: np.ndarray
    rate: float
    sources: Mapping[str, np.ndarray]
    transitions: Mapping[str, int]
    warps: Mapping[str, int]
    clip_names: tuple
    message: str

    @property
    def n_frames(self) -> int:
        """Number of frames T."""
        return len(self.weights)


def _palette(palette, rate) -> tuple:
    clips = tuple(palette) if not isinstance(palette, GestureClip) else (palette,)
    if not clips or not all(isinstance(c, GestureClip) for c in clips):
        raise InputError("palette must be a non-empty sequence of GestureClip")
    names = [c.name for c in clips]
    if len(set(names)) != len(names):
        raise InputError(f"palette clip names must be unique, got {names}")
    for clip in clips:
        if not np.isclose(clip.rate, rate, rtol=1e-6):
            raise InputError(f"clip {clip.name!r} is at {clip.rate:g} Hz, the output at "
                             f"{rate:g} Hz: resample the clip first")
        if clip.names != clips[0].names:
            raise InputError(f"clip {clip.name!r} has other shapes than clip "
                             f"{clips[0].name!r}: a palette shares one basis")
    return clips


def _features(clips, values, features) -> tuple:
    """The features to synthesize; `values`: each clip's :meth:`GestureClip.features`."""
    have = [set(v) for v in values]
    common = set.intersection(*have)
    if features is None:
        return tuple(f for f in FEATURES if f in common)
    features = tuple(features)
    for feature in features:
        if feature not in FEATURES:
            raise InputError(f"unknown feature {feature!r}; expected one of {list(FEATURES)}")
        lacking = [c.name for c, h in zip(clips, have) if feature not in h]
        if lacking:
            raise InputError(f"feature {feature!r} is missing from clips {lacking}")
    for group in set(features) & set(DETAIL_FEATURES):
        if len({c.detail_labels[group] for c in clips}) > 1:
            raise InputError(f"detail group {group!r} has other markers in different clips")
    return features


def _spans(timeline, feature, n_frames, rate, clip_index) -> list:
    every = tuple(range(len(clip_index)))
    if timeline is None:
        return [(0, n_frames, every)]
    return [(a, b, every if style is None else (clip_index[style],))
            for a, b, style in timeline.spans(feature, n_frames, rate)]


def synthesize_gestures(intensity, palette: Sequence[GestureClip], *, rate: float,
                        timeline: Timeline | None = None, features=None, history: int = 10,
                        alpha: float = 1.0, sigma: float = 0.05, n_candidates: int = 3,
                        run: int = 1, blend: int = 4, time_warps: bool = True,
                        weight_groups=None, seed=0) -> GestureSynthesis:
    """Generate c̃(t), R̃(t), T̃(t) and D̃_j(t) driven by a speech intensity.

    Parameters
    ----------
    intensity : array_like of shape (n_frames,)
        S̃(t) of the driving speech at `rate` (:mod:`fit.gestures.speech`). No NaN.
    palette : sequence of GestureClip
        Reference clips at `rate`, sharing one basis.
    rate : float, Hz
        Output frame rate.
    timeline : Timeline, optional
        Styles per feature and time; default: every clip everywhere.
    features : sequence of str, optional
        Features to synthesize (:data:`fit.gestures.features.FEATURES`), each by
        its own chain; default: those every clip has. Weight columns of a
        feature not synthesized are 0.
    history : int, default 10
        h, frames matched (paper: 10).
    alpha : float, default 1
        Weight of the speech term.
    sigma : float, default 0.05
        σ of ``exp(−dist/σ)``, in the standardized units below; 0 picks the nearest.
    n_candidates : int, default 3
        Candidates drawn from (paper: 2 to 4).
    run : int, default 1
        Frames copied per pick (1: the paper's per-frame chain; more: motion-graph
        style blocks, faster, fewer decisions).
    blend : int, default 4
        Frames over which the offset of a jump is faded out (0: none, every
        output frame a reference frame, and every jump between two reference
        frames shows; ``bench/bench_gestures.py`` counts the large jumps).
    time_warps : bool, default True
        True (the paper): every local minimum of dist is a candidate, also the
        frames next to the continuation, whose copy stalls, replays or skips
        the stretch being copied. False: the candidates of a step are the
        continuation and the local minima at least h frames from it (motion-graph
        style: continue, or transition). Time warps are how the chain holds
        a reference moment the speech asks for longer than the reference does,
        at the price of slowed motion; without them motion keeps its speed,
        but a reference with few smooth transitions jumps more often
        (``bench/bench_gestures.py`` measures both).
    weight_groups : mapping of str to sequence of str, optional
        Shapes of the ``blinks`` and ``brows`` features
        (:func:`fit.gestures.features.weight_columns`); default: by name;
        ``{}``: every weight in the one ``weights`` chain.
    seed : int or numpy.random.Generator
        The result is deterministic for a given seed. Each feature draws from
        its own stream (spawned in :data:`FEATURES` order), so the choices of
        one chain do not depend on which other features are synthesized.

    Returns
    -------
    GestureSynthesis

    Raises
    ------
    InputError
        Bad options, a palette of another rate or basis, a timeline style not in
        the palette, a feature missing from a clip, clips not longer than h.

    Notes
    -----
    Units: every intensity curve (the driving one and each clip's) is floored
    60 dB below its 95th percentile and standardized to zero mean and unit
    variance, so only relative loudness is matched; each feature is divided
    by the square root of its total variance over the palette (the head's
    rotation and translation separately). The speech window is frames
    t − h + 1 .. t (the paper: t − h .. t − 1; the driving speech is known in
    advance, so the frame being chosen is matched on it too); the feature
    window is t − h .. t − 1. Candidates are the local minima of dist over t̂
    within a clip (the k nearest of them), as in motion graphs, so that the
    neighbours of the best frame do not crowd out real alternatives
    (``time_warps=False``: minus the frames less than h from the continuation,
    plus the continuation itself). The loop
    runs over picks (one per `run` frames), each a fixed number of numpy
    calls over all candidates at once.

    References
    ----------
    Ju & Lee, "Expressive facial gestures from motion capture data", sec. 5.1.
    """
    intensity = as_float_array(intensity, "intensity", ndim=1, allow_nan=False)
    rate = as_positive_float(rate, "rate")
    clips = _palette(palette, rate)
    per_clip = [c.features(weight_groups) for c in clips]
    features = _features(clips, per_clip, features)
    h = as_int(history, "history", minimum=1)
    run = as_int(run, "run", minimum=1)
    k = as_int(n_candidates, "n_candidates", minimum=1)
    blend = as_int(blend, "blend", minimum=0)
    if not isinstance(time_warps, (bool, np.bool_)):
        raise InputError(f"time_warps must be True or False, got {time_warps!r}")
    alpha, sigma = float(alpha), float(sigma)
    if not (np.isfinite(alpha) and alpha >= 0 and np.isfinite(sigma) and sigma >= 0):
        raise InputError(f"alpha and sigma must be finite and >= 0, got {alpha}, {sigma}")
    if len(intensity) <= h:
        raise InputError(f"intensity has {len(intensity)} frames; the synthesis needs more "
                         f"than history = {h}")
    clip_index = {c.name: i for i, c in enumerate(clips)}
    if timeline is not None:
        if not isinstance(timeline, Timeline):
            raise InputError(f"timeline must be a Timeline, got {type(timeline).__name__}")
        unknown = sorted(timeline.styles() - set(clip_index))
        if unknown:
            raise InputError(f"timeline styles {unknown} are not clips of the palette "
                             f"({', '.join(clip_index)})")
    streams = dict(zip(FEATURES, np.random.default_rng(seed).spawn(len(FEATURES))))
    target = _mrf.standardize_intensity(intensity)
    speech = [_mrf.standardize_intensity(c.intensity) for c in clips]
    values, sources, transitions, warps = {}, {}, {}, {}
    for feature in features:
        raw = [v[feature] for v in per_clip]
        parts = [slice(0, 3), slice(3, 6)] if feature == "head" else [slice(None)]
        scale = _mrf.part_scales(raw, parts)
        spans = _spans(timeline, feature, len(target), rate, clip_index)
        src = _mrf.chain(target, speech, [f / scale for f in raw], spans, h=h, run=run,
                         alpha=alpha, k=k, sigma=sigma, warps=time_warps,
                         rng=streams[feature])
        values[feature], transitions[feature] = _assemble(raw, src, blend)
        sources[feature], warps[feature] = src, _mrf.time_warps(src, h)
    return _result(values, sources, transitions, warps, clips, intensity, rate,
                   weight_groups)


def _assemble(raw: list, src: np.ndarray, blend: int) -> tuple:
    """Copied values (T, d) with jumps blended, and the number of transitions."""
    offsets = np.concatenate([[0], np.cumsum([len(f) for f in raw])])
    stacked = np.concatenate(raw)
    lengths = offsets[1:] - offsets[:-1]
    values = stacked[offsets[src[:, 0]] + src[:, 1]]
    jump = np.zeros(len(src), bool)
    jump[1:] = (src[1:, 0] != src[:-1, 0]) | (src[1:, 1] != src[:-1, 1] + 1)
    prev = src[:-1][jump[1:]]
    following = np.minimum(prev[:, 1] + 1, lengths[prev[:, 0]] - 1)
    offsets_at = np.zeros_like(values)
    offsets_at[jump] = stacked[offsets[prev[:, 0]] + following] - values[jump]
    offsets_at = np.nan_to_num(offsets_at)
    blended = _mrf.transition_blend(values, offsets_at, blend)
    low, high = np.nanmin(stacked, axis=0), np.nanmax(stacked, axis=0)
    return np.clip(blended, low, high), int(jump.sum())


def _result(values, sources, transitions, warps, clips, intensity, rate,
            weight_groups) -> GestureSynthesis:
    head_rotation = head_translation = None
    if "head" in values:
        head_rotation = Rotation.from_rotvec(values["head"][:, :3]).as_matrix()
        head_translation = values["head"][:, 3:]
    n = len(intensity)
    weights = np.zeros((n, len(clips[0].names)))
    for feature, cols in weight_columns(clips[0].names, weight_groups).items():
        if feature in values:
            weights[:, cols] = values[feature]
    details = {g: v.reshape(n, -1, 3) for g, v in values.items() if g in DETAIL_FEATURES}
    labels = {g: clips[0].detail_labels[g] for g in details}
    message = (f"{n} frames at {rate:g} Hz from {len(clips)} clips; transitions (of them "
               f"time warps): " + ", ".join(f"{f} {c} ({warps[f]})"
                                            for f, c in transitions.items()))
    return GestureSynthesis(
        weights=weights,
        names=clips[0].names, head_rotation=head_rotation, head_translation=head_translation,
        details=details, detail_labels=labels, intensity=intensity, rate=rate,
        sources=sources, transitions=transitions, warps=warps,
        clip_names=tuple(c.name for c in clips), message=message)


def candidate_distances(intensity_history, feature_history, ref_intensity, ref_features, *,
                        alpha: float = 1.0) -> np.ndarray:
    """dist(t, t̂) of one output frame against every frame t̂ of a reference.

    Parameters
    ----------
    intensity_history : array_like of shape (h,)
        S̃(t − h + 1 .. t), oldest first.
    feature_history : array_like of shape (h, d)
        c̃(t − h .. t − 1), oldest first.
    ref_intensity : array_like of shape (T,)
    ref_features : array_like of shape (T, d)
    alpha : float, default 1

    Returns
    -------
    ndarray of shape (T,)
        ``α Σ_{j=0}^{h−1} |S̃(t−j) − S(t̂−j)|² + Σ_{j=1}^{h} |c̃(t−j) − c(t̂−j)|²`` for
        t̂ = h .. T − 1; inf before (no full history) and where a window has NaN.
        Values as given (no standardization).
    """
    s_hist = as_float_array(intensity_history, "intensity_history", ndim=1, allow_nan=False)
    h = len(s_hist)
    f_hist = as_float_array(feature_history, "feature_history", shape=(h, None),
                            allow_nan=False)
    ref_s = as_float_array(ref_intensity, "ref_intensity", ndim=1)
    ref_f = as_float_array(ref_features, "ref_features", shape=(len(ref_s), f_hist.shape[1]))
    bank = _mrf.build_bank([ref_s], [ref_f], (0,), h=h, alpha=float(alpha))
    out = np.full(len(ref_s), np.inf)
    cross = _mrf.cross_terms(f_hist @ bank.features.T)
    out[bank.frame] = _mrf.distances(bank, np.sqrt(alpha) * s_hist, cross,
                                     float(np.sum(f_hist ** 2)))
    return out


def pick_candidate(distances, *, n_candidates: int = 3, sigma: float = 0.05, rng=None) -> int:
    """Draw one of the `n_candidates` nearest local minima of `distances`, P ∝ exp(−dist/σ).

    Parameters
    ----------
    distances : array_like of shape (n,)
        dist over consecutive candidate frames of one clip (inf: not a candidate).
    n_candidates : int, default 3
    sigma : float, default 0.05
        0 picks the nearest.
    rng : numpy.random.Generator or int, optional

    Returns
    -------
    int
        Index into `distances`.
    """
    dist = as_float_array(distances, "distances", ndim=1)
    dist = np.where(np.isnan(dist), np.inf, dist)
    first = np.zeros(len(dist), bool)
    first[:1] = True
    sigma = float(sigma)
    if not np.isfinite(sigma) or sigma < 0:
        raise InputError(f"sigma must be finite and >= 0, got {sigma}")
    return _mrf.pick(dist, _mrf.local_minima(dist, first),
                     as_int(n_candidates, "n_candidates", minimum=1), sigma,
                     np.random.default_rng(rng))
