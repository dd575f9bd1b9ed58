"""Head stabilization: per-frame rigid motion of the head markers, removed from a take.

``world = R(t) @ head + t(t)``: :func:`stabilize` finds R(t), t(t) for every
frame at once (weighted, robust to a slipping head marker) and expresses the
whole take in the head frame.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from mocap._stabilize import interpolate, solve
from mocap.errors import InputError, MarkerError
from mocap.gaps import find_gaps
from mocap.rigid import apply_inverse_transform, apply_transform
from mocap.take import Take, as_take
from mocap.util.arrays import read_only
from mocap.util.validation import as_choice, as_float_array, as_int, as_positive_float

__all__ = ["stabilize", "Stabilization", "Slip", "Disagreement", "REFERENCES",
           "INVALID_POLICIES", "ROBUST_GUARD_DEG"]

#: Reference head shapes: the generalized-Procrustes mean of all frames, or one frame.
REFERENCES = ("mean", "frame")
#: What to do with frames that have no rigid fit (fewer than 3 visible head
#: markers, or collinear ones): leave NaN, interpolate the transform, or raise.
INVALID_POLICIES = ("nan", "interpolate", "raise")
#: Default guard of the robust fit, degrees: frames where the robust and the
#: plain least-squares head rotations differ by more are reported. A slipping
#: marker of a headband of 4-6 markers moves the plain fit by well under this
#: (up to 1.6 deg on facial-sing.c3d, where the robust fit discounts 28
#: slips); beyond it the two fits follow different rigid bodies, and neither
#: is to be trusted silently.
ROBUST_GUARD_DEG = 2.0


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
class Disagreement:
    """A run of frames where the robust and the plain rigid fits of the head disagree.

    Attributes
    ----------
    start, stop : int
        Frame indices (0-based) of the run, `stop` excluded.
    max_angle : float
        Largest angle between the two head rotations in the run, degrees.
    """

    start: int
    stop: int
    max_angle: float


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
    robust : bool
        Whether the robust (slip-tolerant) fit made the transforms.
    disagreements : tuple of Disagreement
        With `robust` and a guard: runs of frames where the plain
        least-squares fit turns the head by more than the guard angle away
        from the robust one (reported, and warned about).
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
    robust: bool = True
    disagreements: tuple = ()

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
              guard_deg: float | None = ROBUST_GUARD_DEG, slip_threshold: float = 1.0,
              min_slip_frames: int = 5, invalid: str = "nan",
              max_iter: int = 100) -> Stabilization:
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
    guard_deg : float or None, default ROBUST_GUARD_DEG (2)
        With `robust`, also make the plain least-squares fit and report the
        runs of frames where the two head rotations differ by more than this
        many degrees (``disagreements``, and a warning naming them); None: no
        guard. A robust fit that disagrees with the plain one is either
        discounting a slipping marker or following the wrong rigid body (a
        stand-in head of face markers that move together): only the user can
        tell, so the frames are reported rather than either fit trusted silently.
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

    Warns
    -----
    UserWarning
        The robust and the plain fits disagree by more than `guard_deg` (the
        runs of frames are named).

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
    if guard_deg is not None:
        guard_deg = as_positive_float(guard_deg, "guard_deg")
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

    solution = solve(head, base, reference, ref_index, robust, max_iter)
    rotation, translation, valid, shape, robust_w, sigma, n_iter, converged = solution
    disagreements = ()
    if robust and guard_deg is not None:
        plain = solve(head, base, reference, ref_index, False, max_iter)
        disagreements = _disagreements(rotation, valid, plain[0], plain[2], guard_deg)
        if disagreements:
            _warn_disagreements(disagreements, labels, guard_deg, take.first_frame)
    if invalid == "raise" and not valid.all():
        raise _missing_error(labels, base > 0, valid, take.first_frame)
    interpolated = np.zeros(n_frames, dtype=bool)
    if invalid == "interpolate" and not valid.all():
        rotation, translation = interpolate(rotation, translation, valid)
        interpolated = ~valid
    residuals = np.linalg.norm(apply_transform(rotation, translation, shape) - head, axis=-1)
    slips = _slips(residuals, valid, labels, slip_threshold, min_slip_frames)
    head_take = take.replace(positions=read_only(apply_inverse_transform(
        rotation, translation, take.positions)))
    used = np.where(valid[:, None], base * robust_w, 0.0)
    n_bad = int(n_frames - valid.sum())
    message = (f"{'converged' if converged else 'did not converge'} in {n_iter} fit passes; "
               f"{n_bad} of {n_frames} frames without a fit; {len(slips)} slips; "
               f"noise {sigma:.3g} mm")
    if disagreements:
        message += f"; robust and plain fits disagree in {len(disagreements)} runs of frames"
    return Stabilization(
        rotation=read_only(rotation, copy=True), translation=read_only(translation, copy=True),
        reference_shape=read_only(shape, copy=True), head_markers=labels,
        head_residuals=read_only(residuals, copy=True), valid=read_only(valid, copy=True),
        interpolated=read_only(interpolated, copy=True), weights=read_only(used, copy=True),
        slips=slips,
        take=head_take, reference_frame=ref_index, noise=sigma, n_iter=n_iter,
        converged=converged, message=message, robust=robust, disagreements=disagreements)


def _disagreements(rotation, valid, plain_rotation, plain_valid, guard_deg) -> tuple:
    """Runs of frames where two fits' rotations differ by more than `guard_deg` degrees."""
    both = valid & plain_valid
    angle = np.zeros(len(rotation))
    if both.any():
        relative = np.swapaxes(rotation[both], -1, -2) @ plain_rotation[both]
        angle[both] = np.degrees(Rotation.from_matrix(relative).magnitude())
    gaps = find_gaps((angle > guard_deg)[:, None])
    return tuple(Disagreement(start=int(a), stop=int(b), max_angle=float(angle[a:b].max()))
                 for a, b in zip(gaps.start, gaps.stop))


def _warn_disagreements(runs, labels, guard_deg, first_frame) -> None:
    worst = sorted(runs, key=lambda r: -r.max_angle)[:5]
    where = ", ".join(f"{_frames_text(r.start, r.stop, first_frame)} up to {r.max_angle:.1f} deg"
                      for r in worst)
    n_frames = sum(r.stop - r.start for r in runs)
    warnings.warn(
        f"the robust and the plain rigid fits of the stabilization markers "
        f"({', '.join(labels)}) disagree by more than {guard_deg:g} deg in {n_frames} frames "
        f"({len(runs)} runs; worst: {where}): a marker slips there, or the markers do not "
        "move as one rigid body; check their residuals (head_residuals.png) before trusting "
        "either fit, or choose other stabilization markers", stacklevel=3)


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


def _slips(residuals, valid, labels, threshold, min_frames) -> tuple:
    """Runs of at least `min_frames` frames where a head marker's residual exceeds `threshold`."""
    over = np.where(valid[:, None], np.nan_to_num(residuals) > threshold, False)
    gaps = find_gaps(over)
    keep = gaps.length >= min_frames
    return tuple(
        Slip(marker=labels[m], start=int(a), stop=int(b),
             max_residual=float(residuals[a:b, m].max()))
        for m, a, b in zip(gaps.marker[keep], gaps.start[keep], gaps.stop[keep]))
