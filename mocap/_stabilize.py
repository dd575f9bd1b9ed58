"""The numerics of :func:`mocap.stabilize.stabilize`: generalized Procrustes and robust
reweighting of every frame at once, on frames-last arrays.

Kept beside the public module: the result types, validation and reporting
live in :mod:`mocap.stabilize`.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from mocap.rigid import fit_frames_last, frames_last

__all__ = ["solve", "noise_scale", "residuals", "interpolate"]

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


def solve(head, base, reference, ref_index, robust, max_iter):
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
        fit, settled = settle_shape(fit, noise_scale(residuals(shape, fit, y, seen), base))
    sigma = noise_scale(residuals(shape, fit, y, seen), base)
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
        new_w = _robust_weights(residuals(shape, part, y[..., frames], seen[:, frames])
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


def residuals(shape, fit, y, seen) -> np.ndarray:
    """Distances (n_head, n_frames), mm, from the posed shape to the markers; NaN if unseen."""
    rotation, translation, _ = fit
    posed = np.stack([shape @ rotation[i] for i in range(3)]) + translation[:, None]
    return np.where(seen, np.sqrt(((posed - y) ** 2).sum(axis=0)), np.nan)


def noise_scale(residuals, base) -> float:
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


def interpolate(rotation, translation, valid) -> tuple:
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
