"""Head stabilization: per-frame rigid motion of the head markers, removed from a take.

``world = R(t) @ head + t(t)``: :func:`stabilize` finds R(t), t(t) for every
frame at once (weighted, robust to a slipping head marker) and expresses the
whole take in the head frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from mocap.errors import InputError, MarkerError
from mocap.gaps import find_gaps
from mocap.rigid import apply_inverse_transform, apply_transform, fit_frames_last, frames_last
from mocap.take import Take, as_take
from mocap.util.arrays import read_only
from mocap.util.validation import as_choice, as_float_array, as_int, as_positive_float

__all__ = ["stabilize", "Stabilization", "Slip", "REFERENCES", "INVALID_POLICIES"]

#: Reference head shapes: the generalized-Procrustes mean of all frames, or one frame.
REFERENCES = ("mean", "frame")
#: What to do with frames that have no rigid fit (fewer than 3 visible head
#: markers, or collinear ones): leave NaN, interpolate the transform, or raise.
INVALID_POLICIES = ("nan", "interpolate", "raise")

#: Median of the norm of a standard 3-D normal vector: turns the median
#: residual norm into a per-coordinate noise scale sigma.
_CHI3_MEDIAN = 1.5382
#: Noise scale floor, mm: below any optical capture noise; keeps exact data
#: from giving a zero scale.
_MIN_SIGMA_MM = 1e-3
#: Huber threshold (warm-up, convex); knee and cut-off of the redescending
#: weight (Tukey's biweight on the excess over the knee), in sigma. Samples
#: below the knee keep weight 1, so only frames with a suspect sample move.
_HUBER_K = 3.0
_TUKEY_KNEE = 4.0
_TUKEY_C = 10.0
#: Robust weights never go below this, so a frame never loses its rank.
_WEIGHT_FLOOR = 1e-3
#: Convergence: largest change of a robust weight in the Huber warm-up and in
#: the final Tukey phase, and of the mean shape as a fraction of the noise
#: scale (1e-7 mm at the noise floor; far below the mean's own uncertainty,
#: about sigma / sqrt(n_frames)).
_HUBER_TOL = 1e-2
_WEIGHT_TOL = 1e-7
_SHAPE_RTOL = 1e-4
#: Frames of the first, cheap Procrustes pass that starts the mean shape.
_START_FRAMES = 1024


@dataclass(frozen=True)
class Slip:
    """A run of frames where one head marker moved relative to the others.

    Attributes
    ----------
    marker : str
        Label of the head marker.
    start, stop : int
        Frame indices (0-based) of the run, `stop` excluded.
    max_residual : float
        Largest distance of the marker from its place on the fitted head, mm.
    """

    marker: str
    start: int
    stop: int
    max_residual: float


@dataclass(frozen=True)
class Stabilization:
    """Result of :func:`stabilize`: head motion, its quality, and the stabilized take.

    Attributes
    ----------
    rotation : ndarray of shape (n_frames, 3, 3)
        R(t), proper rotations, with ``world = R(t) @ head + t(t)``. NaN in
        frames without a fit (unless interpolated).
    translation : ndarray of shape (n_frames, 3), mm
        t(t).
    reference_shape : ndarray of shape (n_head, 3), mm
        Head markers in the head frame.
    head_markers : tuple of str
        Labels of the head markers, in the order of the columns above.
    head_residuals : ndarray of shape (n_frames, n_head), mm
        ``|R(t) @ reference + t(t) - marker|``; NaN where the marker is missing
        or the frame has no transform.
    valid : ndarray of bool, shape (n_frames,)
        Frames fitted from at least 3 visible, non-collinear head markers.
    interpolated : ndarray of bool, shape (n_frames,)
        Frames whose transform was interpolated (``invalid="interpolate"``).
    weights : ndarray of shape (n_frames, n_head)
        Final weight of each head-marker sample in the fit: the caller's weight
        times the robust weight; 0 where missing or in frames without a fit.
    slips : tuple of Slip
        Runs of frames where a head marker's residual exceeds the slip threshold.
    take : Take
        Every marker of the take in the head frame (mm); NaN kept, ``filled`` kept.
    reference_frame : int
        Frame index at which the head frame coincides with the world frame.
    noise : float
        Robust per-coordinate noise scale of the head markers, mm
        (median residual / 1.5382).
    n_iter : int
        Fit passes done (over all frames, or over the frames still changing).
    converged : bool
        Whether the robust weights and the mean shape stopped changing.
    message : str
        A one-line summary.
    """

    rotation: np.ndarray
    translation: np.ndarray
    reference_shape: np.ndarray
    head_markers: tuple
    head_residuals: np.ndarray
    valid: np.ndarray
    interpolated: np.ndarray
    weights: np.ndarray
    slips: tuple
    take: Take
    reference_frame: int
    noise: float
    n_iter: int
    converged: bool
    message: str

    def to_world(self, points) -> np.ndarray:
        """Head-frame points to world positions, ``R(t) @ p + t(t)``.

        Parameters
        ----------
        points : array_like of shape (n_frames, K, 3) or (K, 3), mm
            A (K, 3) array is one rigid set of points carried by the head.

        Returns
        -------
        ndarray of shape (n_frames, K, 3), mm
            NaN where the point is NaN or the frame has no transform.
        """
        return apply_transform(self.rotation, self.translation, self._points(points))

    def to_head(self, points) -> np.ndarray:
        """World positions to the head frame, ``R(t).T @ (p - t(t))``.

        Parameters
        ----------
        points : array_like of shape (n_frames, K, 3) or (K, 3), mm

        Returns
        -------
        ndarray of shape (n_frames, K, 3), mm
            NaN where the point is NaN or the frame has no transform.
        """
        return apply_inverse_transform(self.rotation, self.translation, self._points(points))

    def _points(self, points) -> np.ndarray:
        points = as_float_array(points, "points")
        n_frames = self.rotation.shape[0]
        if points.ndim == 2 and points.shape[1] == 3:
            return np.broadcast_to(points, (n_frames,) + points.shape)
        if points.ndim != 3 or points.shape[0] != n_frames or points.shape[2] != 3:
            raise InputError(f"points must have shape ({n_frames}, K, 3) or (K, 3), "
                             f"got {points.shape}")
        return points


def stabilize(take: Take, head_markers, *, reference: str = "mean",
              reference_frame: int | None = None, weights=None, robust: bool = True,
              slip_threshold: float = 1.0, min_slip_frames: int = 5,
              invalid: str = "nan", max_iter: int = 100) -> Stabilization:
    """Remove the rigid head motion from a take.

    Parameters
    ----------
    take : Take
        Positions (n_frames, n_markers, 3), mm, NaN where missing.
    head_markers : sequence of str
        Labels of at least 3 markers that move rigidly with the head.
    reference : {"mean", "frame"}
        Reference head shape: the generalized-Procrustes mean of all valid
        frames (iterate: fit every frame to the mean, re-average), or the
        head markers of `reference_frame` as they are.
    reference_frame : int, optional
        Frame index (0-based) where the head frame equals the world frame. Required for
        ``"frame"`` (every head marker must be visible there); for ``"mean"``
        it poses the mean shape and defaults to the first valid frame.
    weights : array_like of shape (n_head,) or (n_frames, n_head), optional
        Non-negative confidence of each head marker (or sample); default 1.
    robust : bool, default True
        Down-weight samples of head markers that move relative to the others
        (iteratively reweighted least squares, all frames at once).
    slip_threshold : float, default 1.0
        Residual (mm) above which a head marker is reported as slipped.
    min_slip_frames : int, default 5
        Shortest run of frames reported as a slip. A slip is sustained; a
        shorter excursion (a spike, or a filter's end effect) is still
        down-weighted by the robust fit but not reported.
    invalid : {"nan", "interpolate", "raise"}
        Frames without a fit: NaN transform; transform interpolated from the
        nearest valid frames (slerp for R, linear for t, the nearest valid
        transform held before the first and after the last); or raise.
    max_iter : int, default 100
        Most fit passes.

    Returns
    -------
    Stabilization

    Raises
    ------
    MarkerError
        A head marker is not in the take, is missing in the reference frame,
        is never visible in a frame with a fit, or (``invalid="raise"``, or
        when no frame at all can be fitted) a run of frames has fewer than 3
        visible head markers: the message names the marker missing there.
    InputError
        No frames, unknown options, fewer than 3 head markers, bad weights or
        frame index.

    Notes
    -----
    NaN policy: missing samples get weight 0. A frame needs 3 visible,
    non-collinear head markers; other frames are flagged (``valid`` False)
    and handled by `invalid`. Markers of the stabilized take stay NaN where
    they were missing or the frame has no transform.

    Every frame is fitted to the reference at once (:func:`mocap.rigid.fit_rigid`:
    rigid, no scale, never a reflection). For ``"mean"`` the reference is
    the generalized-Procrustes mean: started from at most 1024 frames spread
    over the take, then re-averaged in the head frame over all frames and
    re-posed onto `reference_frame` until it moves less than 1e-4 times the
    noise scale ``sigma = median(r) / 1.5382`` (at least 1 um) of the
    residuals r. With `robust`, sigma is then fixed and each sample is
    reweighted by Huber's function (``k = 3 sigma``) until the weights
    settle to 1e-2, then by a redescending weight: 1 up to ``4 sigma``,
    Tukey's biweight on the excess, 0 beyond ``10 sigma`` (floored at 1e-3
    so that no frame loses its rank), to 1e-7, alternating with the mean
    shape until both settle. Only frames whose weights still change are
    refitted. Slips are reported from the final residuals, also without
    `robust` (detected, not down-weighted).

    Examples
    --------
    >>> import numpy as np
    >>> head = np.array([[0., 0, 0], [100, 0, 0], [0, 80, 0], [0, 0, 60]])
    >>> c, s = np.cos(0.3), np.sin(0.3)
    >>> rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    >>> pos = np.stack([head, head @ rz.T + [5, 0, 0]])
    >>> st = stabilize(Take(("a", "b", "c", "d"), pos, rate=100), ["a", "b", "c", "d"])
    >>> np.allclose(st.take.positions[1], head), np.allclose(st.rotation[1], rz)
    (True, True)
    """
    take = as_take(take)
    if take.n_frames == 0:
        raise InputError(f"{take.source.path or 'the take'}: the take has no frames to stabilize")
    labels = _head_labels(take, head_markers)
    reference = as_choice(reference, "reference", REFERENCES)
    invalid = as_choice(invalid, "invalid", INVALID_POLICIES)
    slip_threshold = as_positive_float(slip_threshold, "slip_threshold")
    min_slip_frames = as_int(min_slip_frames, "min_slip_frames", minimum=1)
    max_iter = as_int(max_iter, "max_iter", minimum=1)
    if not isinstance(robust, bool):
        raise InputError(f"robust must be True or False, got {robust!r}")
    head = take.positions[:, take.indices(labels)]
    n_frames, n_head = head.shape[:2]
    base = _sample_weights(weights, n_frames, n_head) * ~np.isnan(head[..., 0])
    possible = np.count_nonzero(base > 0, axis=1) >= 3
    if not possible.any() or (invalid == "raise" and not possible.all()):
        raise _missing_error(labels, base > 0, possible, take.first_frame)
    ref_index = _reference_index(reference, reference_frame, n_frames, possible, base, labels,
                                 take.first_frame)
    never = ~(base[possible] > 0).any(axis=0)
    if never.any():
        raise MarkerError(labels[int(np.argmax(never))],
                          "is never visible together with 2 other head markers: "
                          "it cannot be placed on the head")

    solution = _solve(head, base, reference, ref_index, robust, max_iter)
    rotation, translation, valid, shape, robust_w, sigma, n_iter, converged = solution
    if invalid == "raise" and not valid.all():
        raise _missing_error(labels, base > 0, valid, take.first_frame)
    interpolated = np.zeros(n_frames, dtype=bool)
    if invalid == "interpolate" and not valid.all():
        rotation, translation = _interpolate(rotation, translation, valid)
        interpolated = ~valid
    residuals = np.linalg.norm(apply_transform(rotation, translation, shape) - head, axis=-1)
    slips = _slips(residuals, valid, labels, slip_threshold, min_slip_frames)
    head_take = take.replace(positions=apply_inverse_transform(rotation, translation,
                                                               take.positions))
    used = np.where(valid[:, None], base * robust_w, 0.0)
    n_bad = int(n_frames - valid.sum())
    message = (f"{'converged' if converged else 'did not converge'} in {n_iter} fit passes; "
               f"{n_bad} of {n_frames} frames without a fit; {len(slips)} slips; "
               f"noise {sigma:.3g} mm")
    return Stabilization(
        rotation=read_only(rotation, copy=True), translation=read_only(translation, copy=True),
        reference_shape=read_only(shape, copy=True), head_markers=labels,
        head_residuals=read_only(residuals, copy=True), valid=read_only(valid, copy=True),
        interpolated=read_only(interpolated, copy=True), weights=read_only(used, copy=True),
        slips=slips,
        take=head_take, reference_frame=ref_index, noise=sigma, n_iter=n_iter,
        converged=converged, message=message)


def _head_labels(take: Take, head_markers) -> tuple:
    if isinstance(head_markers, str):
        raise InputError("head_markers must be a sequence of labels, not one string")
    labels = tuple(head_markers)
    if len(labels) < 3:
        raise InputError(f"head_markers must name at least 3 markers, got {len(labels)}")
    if len(set(labels)) != len(labels):
        raise InputError(f"head_markers lists a marker twice: {list(labels)}")
    take.indices(labels)                       # MarkerError for an unknown label
    return labels


def _sample_weights(weights, n_frames: int, n_head: int) -> np.ndarray:
    if weights is None:
        return np.ones((n_frames, n_head))
    weights = as_float_array(weights, "weights", allow_nan=False)
    if weights.shape not in ((n_head,), (n_frames, n_head)):
        raise InputError(f"weights must have shape ({n_head},) or ({n_frames}, {n_head}), "
                         f"got {weights.shape}")
    if (weights < 0).any():
        raise InputError("weights must be non-negative")
    return np.broadcast_to(weights, (n_frames, n_head)).copy()


def _frames_text(start: int, stop: int, first_frame: int) -> str:
    """'frames 121-180 (indices 120-179)' for indices start..stop-1."""
    return (f"frames {first_frame + start}-{first_frame + stop - 1} "
            f"(indices {start}-{stop - 1})")


def _missing_error(labels, visible, fitted, first_frame) -> MarkerError:
    """MarkerError for the first run of frames without a fit, naming its most-missing marker."""
    gaps = find_gaps(~fitted[:, None])
    start, stop = int(gaps.start[0]), int(gaps.stop[0])
    worst = int(np.argmax((~visible[start:stop]).sum(axis=0)))
    if visible[start:stop, worst].all():
        return MarkerError(labels[worst], f"head markers are collinear in "
                           f"{_frames_text(start, stop, first_frame)}: a rigid fit needs "
                           "3 non-collinear head markers")
    return MarkerError(labels[worst], f"is missing in {_frames_text(start, stop, first_frame)}: "
                       "a rigid fit needs 3 visible head markers")


def _reference_index(reference, reference_frame, n_frames, possible, base, labels,
                     first_frame) -> int:
    if reference_frame is None:
        if reference == "frame":
            raise InputError('reference="frame" needs reference_frame (a frame index)')
        return int(np.argmax(possible))
    index = as_int(reference_frame, "reference_frame", minimum=0)
    if index >= n_frames:
        raise InputError(f"reference_frame must be below the take's {n_frames} frames, "
                         f"got {index}")
    seen = base[index] > 0
    if reference == "frame" and not seen.all():
        raise MarkerError(labels[int(np.argmin(seen))],
                          f"is missing in the reference frame {first_frame + index} "
                          f"(index {index}): the reference shape needs every head marker")
    if not possible[index]:
        raise MarkerError(labels[int(np.argmin(seen))],
                          f"is missing in the reference frame {first_frame + index} "
                          f"(index {index}): a rigid fit needs 3 visible head markers")
    return index


def _solve(head, base, reference, ref_index, robust, max_iter):
    """Generalized Procrustes and robust reweighting, all frames at once.

    Works on frames-last arrays: y (3, n_head, n_frames). The mean shape
    starts from a subsample of frames; without `robust` it is iterated to
    convergence. With `robust`, after one full fit and re-average the noise
    scale is fixed, the Huber weights are iterated (shape fixed), the shape
    re-averaged once, then the Tukey weights and the shape until both
    settle, refitting only the frames whose weights still change. Returns
    rotation (n_frames, 3, 3), translation (n_frames, 3), valid, shape,
    robust weights (n_frames, n_head), noise scale, number of fit passes and
    convergence flag.
    """
    y = frames_last(head)
    seen = ~np.isnan(head[..., 0]).T
    base = base.T
    if reference == "frame":
        shape = head[ref_index].copy()
    else:
        start = int(np.argmax(np.count_nonzero(base > 0, axis=0)))
        shape = np.where(seen[:, start, None] & (base[:, start, None] > 0), head[start], np.nan)
    robust_w = np.ones(base.shape)
    state = {"passes": 0}

    def fit_all():
        known = ~np.isnan(shape[:, 0])
        state["passes"] += 1
        rot, trans, _, _, ok = fit_frames_last(np.where(known[:, None], shape, 0.0), y,
                                               base * robust_w * known[:, None])
        return rot, trans, ok

    def settle_shape(fit, sigma):
        """Re-average the mean shape until it moves less than the tolerance.

        The fit returned is the last one, made with the shape before the last
        (sub-tolerance) move: no pass is spent only to confirm convergence.
        """
        nonlocal shape
        while reference == "mean" and state["passes"] < max_iter:
            new = _mean_shape(y, base * robust_w, fit, ref_index, shape)
            change = np.abs(new - shape).max() if not np.isnan(shape).any() else np.inf
            shape = new
            if change <= _SHAPE_RTOL * sigma:
                return fit, True
            fit = fit_all()
        return fit, reference == "frame"

    if reference == "mean":
        shape = _start_shape(y, base, shape, ref_index)
        state["passes"] += 1
    fit, settled = fit_all(), reference == "frame"
    if not settled and robust:    # one re-average; the robust phases settle the shape
        shape = _mean_shape(y, base, fit, ref_index, shape)
    elif not settled:             # a first noise scale, for the tolerance only
        fit, settled = settle_shape(fit, _noise_scale(_residuals(shape, fit, y, seen), base))
    sigma = _noise_scale(_residuals(shape, fit, y, seen), base)
    if robust:
        # Huber warm-up with the shape fixed, one re-average, then Tukey weights
        # and mean shape until both settle.
        _reweight(shape, fit, y, seen, base, robust_w, sigma, "huber", _HUBER_TOL, state,
                  max_iter)
        if reference == "mean":
            shape = _mean_shape(y, base * robust_w, fit, ref_index, shape)
        settled = False
        while not settled and state["passes"] < max_iter:
            done = _reweight(shape, fit, y, seen, base, robust_w, sigma, "tukey", _WEIGHT_TOL,
                             state, max_iter)
            fit, settled = settle_shape(fit, sigma)
            settled = settled and done
    rotation, translation, valid = fit
    return (np.moveaxis(rotation, -1, 0), translation.T, valid, shape, robust_w.T, sigma,
            state["passes"], settled)


def _start_shape(y, base, shape, ref_index) -> np.ndarray:
    """A first mean shape, posed onto `ref_index`: at most _START_FRAMES frames fitted to `shape`.

    Close to the mean of all frames (within about sigma / sqrt(_START_FRAMES)),
    so that the full fits that follow start near convergence.
    """
    fitted = np.flatnonzero(np.count_nonzero(base > 0, axis=0) >= 3)
    sub = np.union1d(fitted[np.linspace(0, len(fitted) - 1, min(_START_FRAMES, len(fitted)))
                            .astype(np.intp)], [ref_index])
    known = ~np.isnan(shape[:, 0])
    rot, trans, _, _, ok = fit_frames_last(np.where(known[:, None], shape, 0.0), y[..., sub],
                                           base[:, sub] * known[:, None])
    return _mean_shape(y[..., sub], base[:, sub], (rot, trans, ok),
                       int(np.searchsorted(sub, ref_index)), shape)


def _reweight(shape, fit, y, seen, base, robust_w, sigma, loss, tol, state, max_iter) -> bool:
    """IRLS with the shape fixed, in place on `fit` and `robust_w`; refits only changing frames.

    Returns whether the weights settled (every change below `tol`).
    """
    rotation, translation, valid = fit
    everything = slice(None)                # views, not copies, on the first round
    frames = everything
    while state["passes"] < max_iter:
        part = (rotation[..., frames], translation[:, frames], valid[frames])
        new_w = _robust_weights(_residuals(shape, part, y[..., frames], seen[:, frames])
                                / sigma, loss)
        change = np.where(base[:, frames] > 0, np.abs(new_w - robust_w[:, frames]), 0.0)
        robust_w[:, frames] = new_w
        moving = change.max(axis=0) > tol
        frames = np.flatnonzero(moving) if frames is everything else frames[moving]
        if frames.size == 0:
            return True
        state["passes"] += 1
        rot, trans, _, _, ok = fit_frames_last(shape, y[..., frames],
                                               base[:, frames] * robust_w[:, frames])
        rotation[..., frames], translation[:, frames], valid[frames] = rot, trans, ok
    return False


def _residuals(shape, fit, y, seen) -> np.ndarray:
    """Distances (n_head, n_frames), mm, from the posed shape to the markers; NaN if unseen."""
    rotation, translation, _ = fit
    posed = np.stack([shape @ rotation[i] for i in range(3)]) + translation[:, None]
    return np.where(seen, np.sqrt(((posed - y) ** 2).sum(axis=0)), np.nan)


def _noise_scale(residuals, base) -> float:
    """Robust per-coordinate noise scale, mm: median residual norm / 1.5382, floored."""
    used = residuals[(base > 0) & ~np.isnan(residuals)]
    return max(float(np.median(used)) / _CHI3_MEDIAN, _MIN_SIGMA_MM)


def _robust_weights(u, loss) -> np.ndarray:
    """Huber or Tukey weights of residuals in units of sigma, floored; 1 where u is NaN."""
    if loss == "huber":
        w = _HUBER_K / np.maximum(u, _HUBER_K)
    else:
        excess = np.clip(u - _TUKEY_KNEE, 0.0, _TUKEY_C - _TUKEY_KNEE)
        w = np.square(1.0 - np.square(excess / (_TUKEY_C - _TUKEY_KNEE)))
    return np.where(np.isnan(u), 1.0, np.maximum(w, _WEIGHT_FLOOR))


def _mean_shape(y, weights, fit, ref_index, old) -> np.ndarray:
    """Weighted mean (n_head, 3) of all frames in the head frame, posed onto `ref_index`.

    ``sum_t w R(t)^T (y - t(t)) / sum_t w`` by matrix products over frames.
    """
    rotation, translation, valid = fit
    rot = np.where(valid, rotation, 0.0)
    trans = np.where(valid, translation, 0.0)
    w = weights * valid
    acc = sum((w * y[i]) @ rot[i].T for i in range(3))
    acc -= w @ (trans[:, None] * rot).sum(axis=0).T
    total = w.sum(axis=1)
    shape = np.where(total[:, None] > 0, acc / np.where(total > 0, total, 1.0)[:, None], old)
    rot_ref, trans_ref, _, _, _ = fit_frames_last(shape, y[..., ref_index:ref_index + 1],
                                                  weights[:, ref_index:ref_index + 1])
    return shape @ rot_ref[..., 0].T + trans_ref[:, 0]


def _interpolate(rotation, translation, valid) -> tuple:
    """Fill frames without a fit: slerp of R, linear t, nearest valid held at the ends."""
    keys = np.flatnonzero(valid)
    todo = np.flatnonzero(~valid)
    rotation = rotation.copy()
    translation = translation.copy()
    if len(keys) == 1:
        rotation[todo] = rotation[keys[0]]
        translation[todo] = translation[keys[0]]
        return rotation, translation
    slerp = Slerp(keys, Rotation.from_matrix(rotation[keys]))
    rotation[todo] = slerp(np.clip(todo, keys[0], keys[-1])).as_matrix()
    for axis in range(3):
        translation[todo, axis] = np.interp(todo, keys, translation[keys, axis])
    return rotation, translation


def _slips(residuals, valid, labels, threshold, min_frames) -> tuple:
    """Runs of at least `min_frames` frames where a head marker's residual exceeds `threshold`."""
    over = np.where(valid[:, None], np.nan_to_num(residuals) > threshold, False)
    gaps = find_gaps(over)
    keep = gaps.length >= min_frames
    return tuple(
        Slip(marker=labels[m], start=int(a), stop=int(b),
             max_residual=float(residuals[a:b, m].max()))
        for m, a, b in zip(gaps.marker[keep], gaps.start[keep], gaps.stop[keep]))
