"""PCA fill from marker intercorrelations (after Gløersen & Federolf 2016).

A gap of one marker is filled from the markers visible throughout it (the
donors): the coordinate matrix of target and donors is centred, normalised
and weighted by each donor's distance to the target; its principal components
come from the frames where all of them are visible (or, when those are too
few, from all frames by iterative PCA imputation); in each gap frame the
donors' coordinates give the component scores by least squares, and the
scores give the target.
"""

from __future__ import annotations

import numpy as np

#: Markers that must be visible throughout a gap for a PCA fill.
MIN_DONORS = 4
#: Fraction of the (weighted, normalised) variance the kept components explain.
VARIANCE = 0.999
#: Iterative PCA stops when the imputed entries change by less than this
#: (relative, in normalised units) or after EM_MAX_ITER iterations.
EM_TOL = 1e-10
EM_MAX_ITER = 500
#: Frames on each side of a gap that its PCA model is learnt from (the whole
#: take when shorter): the cost of a fill stops growing with the take's length,
#: and over a long session marker correlations drift anyway (new expressions,
#: slipping markers), so nearby frames are the better teachers.
WINDOW_FRAMES = 2000
#: Looser stop while the number of components is still being chosen.
EM_TOL_ROUGH = 1e-6
EM_MAX_ITER_ROUGH = 20


def pca_donors(visible: np.ndarray, target: int, start: int, stop: int) -> np.ndarray:
    """Columns of the markers visible in every frame of ``start:stop``, target excluded."""
    seen = visible[start:stop].all(axis=0)
    seen[target] = False
    return np.flatnonzero(seen)


def _n_components(s: np.ndarray, limit: int) -> int:
    """Fewest components whose variance reaches VARIANCE, at most `limit`."""
    var = s ** 2
    if var.sum() <= 0:
        return 0
    k = int(np.searchsorted(np.cumsum(var) / var.sum(), VARIANCE)) + 1
    return min(k, limit, len(s))


def _distance_weights(x: np.ndarray, vis: np.ndarray) -> np.ndarray:
    """exp(-d²/2σ²) per donor; d = mean distance to the target, σ = median d."""
    both = vis[:, 1:] & vis[:, :1]
    # one coordinate at a time, so that every operation runs along the donors (not
    # along the 3 coordinates of each frame's donor); NaN where either is missing
    flat = x.reshape(len(x), -1)
    length = np.zeros(both.shape)
    for c in range(3):
        gap = flat[:, 3 + c::3] - flat[:, c:c + 1]
        gap *= gap
        length += gap
    np.sqrt(length, out=length)
    n = both.sum(axis=0)
    dist = np.where(both, length, 0.0).sum(axis=0) / np.maximum(n, 1)
    sigma = np.median(dist[n > 0]) if (n > 0).any() else 0.0
    if sigma <= 0:
        return (n > 0).astype(np.float64)
    return np.where(n > 0, np.exp(-0.5 * (dist / sigma) ** 2), 0.0)


def _moments(flat: np.ndarray, mask: np.ndarray):
    """Column mean and scale (:func:`_scale`) over the entries where `mask`."""
    n = mask.sum(axis=0)
    mean = np.where(mask, flat, 0.0).sum(axis=0) / n
    std = np.sqrt((np.where(mask, flat - mean, 0.0) ** 2).sum(axis=0) / n)
    return mean, _scale(std, mean)


def _standardized_axes(seen: np.ndarray, weight: np.ndarray):
    """Column mean and scale (:func:`_scale`) of the complete rows `seen` (frames, cols),
    and the singular values and principal axes (:func:`_principal_axes`) of the rows
    centred, divided by the scale and times `weight`.

    The rows are centred in `seen`'s memory; the scale and the weight are applied to
    their scatter matrix (its diagonal gives the scale), not to the rows: two passes over
    them less.
    """
    mean = seen.mean(axis=0)
    seen -= mean
    scatter = seen.T @ seen
    scale = _scale(np.sqrt(np.diag(scatter) / len(seen)), mean)
    factor = weight / scale
    scatter *= factor
    scatter *= factor[:, None]
    return mean, scale, *_eigen_axes(scatter)


def _scale(std: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """The standard deviation, or 1 for a column that does not vary (relative to its mean)."""
    return np.where(std > 1e-12 * np.maximum(np.abs(mean), 1.0), std, 1.0)


def _principal_axes(centred: np.ndarray):
    """Singular values (n_cols,) and principal axes (n_cols, n_cols), largest first.

    From the eigenvectors of the small (n_cols, n_cols) scatter matrix rather
    than an SVD of the tall matrix: one GEMM and a small eigensolve.
    """
    return _eigen_axes(centred.T @ centred)


def _eigen_axes(scatter: np.ndarray):
    """:func:`_principal_axes` from the scatter matrix (n_cols, n_cols)."""
    evals, evecs = np.linalg.eigh(scatter)
    return np.sqrt(np.clip(evals[::-1], 0.0, None)), evecs[:, ::-1]


def _em(z, mask, k, tol, max_iter):
    """Refine the imputed entries of `z` for a rank-k model; returns z, mu, axes, model."""
    for _ in range(max_iter):
        mu = z.mean(axis=0)
        centred = z - mu
        axes = _principal_axes(centred)[1][:, :k]
        model = mu + (centred @ axes) @ axes.T
        change = np.linalg.norm((model - z)[~mask])
        z = np.where(mask, z, model)
        if change <= tol * max(np.linalg.norm(z), 1.0):
            break
    return z, mu, axes, model


def _components_iterative(z: np.ndarray, mask: np.ndarray, limit: int):
    """Mean and principal axes of `z` with entries ~mask unknown (EM imputation).

    The unknown entries start as linear interpolations in time of each
    column. Starting from one component, the imputed entries are refined (roughly)
    for k components, and k grows until the model explains VARIANCE of the
    variance of the imputed matrix; then they are refined to EM_TOL.
    """
    frames = np.arange(len(z))
    z = z.copy()
    for c in np.flatnonzero(~mask.all(axis=0)):
        seen = mask[:, c]
        z[~seen, c] = np.interp(frames[~seen], frames[seen], z[seen, c])
    for k in range(1, limit + 1):
        z, mu, axes, model = _em(z, mask, k, EM_TOL_ROUGH, EM_MAX_ITER_ROUGH)
        residual = np.linalg.norm((model - z)[mask]) ** 2
        if residual <= (1 - VARIANCE) * np.linalg.norm(z - mu) ** 2:
            break
    _, mu, axes, _ = _em(z, mask, axes.shape[1], EM_TOL, EM_MAX_ITER)
    return mu, axes.T


def _drop_to_complete(vis: np.ndarray) -> np.ndarray:
    """Donor columns (of `vis`, target first) kept so that enough frames are complete.

    Drops the donors missing most often, one at a time, while fewer than
    3 (1 + n_donors) frames see the target and every kept donor, keeping at
    least MIN_DONORS; the caller falls back to iterative PCA if still short.
    """
    keep = np.arange(1, vis.shape[1])
    order = np.argsort(vis[:, 1:].sum(axis=0), kind="stable")   # most missing first
    for drop in range(len(keep) - MIN_DONORS + 1):
        kept = np.sort(keep[order[drop:]] if drop else keep)
        cols = np.concatenate(([0], kept))
        if vis[:, cols].all(axis=1).sum() >= 3 * len(cols):
            return kept
    return keep


def fill_pca(positions: np.ndarray, visible: np.ndarray, target: int, start: int,
             stop: int, donors: np.ndarray) -> np.ndarray:
    """PCA estimate of marker `target` over frames ``start:stop``.

    Parameters
    ----------
    positions : ndarray of shape (n_frames, n_markers, 3), mm, NaN where missing
    visible : ndarray of bool, shape (n_frames, n_markers)
    target : int
        Column of the missing marker.
    start, stop : int
        The gap, frame indices.
    donors : ndarray of int
        Markers visible in every frame of the gap (:func:`pca_donors`).

    Returns
    -------
    ndarray of shape (stop - start, 3), mm
        NaN if the target is never visible.

    Notes
    -----
    With X the (n_frames, 3 n_used) matrix of target and donors, each column
    is centred and divided by its standard deviation, then multiplied by the
    donor's weight exp(-d²/2σ²) (d: mean distance to the target, σ: median
    of d), which lets the nearby markers dominate the components, as in the
    paper's distance weighting. Only the WINDOW_FRAMES frames on each side of
    the gap are used. The components V (k of them, explaining
    VARIANCE of the variance) come from the frames where every used marker is
    visible, if there are at least 3 n_used of them (the donors missing most
    often are dropped, down to MIN_DONORS, to get there); else from all
    frames by iterative PCA (impute, re-fit, until the imputed values stop
    changing). In a gap frame the scores solve min ‖V_d z − x_d‖ over the
    donor coordinates, and the target is V_t z. Unlike the paper, the
    reconstruction error seen at the nearest complete frames before and after
    the gap (within one gap length) is blended linearly across the gap, so
    the fill meets the track without a jump.
    """
    lo, hi = max(0, start - WINDOW_FRAMES), min(len(positions), stop + WINDOW_FRAMES)
    positions, visible, start, stop = positions[lo:hi], visible[lo:hi], start - lo, stop - lo
    if not visible[:, target].any():
        return np.full((stop - start, 3), np.nan)
    cols = np.concatenate(([target], donors))
    cols = np.concatenate(([target], cols[_drop_to_complete(visible[:, cols])]))
    donors = cols[1:]
    # np.take, not [:, cols]: whole-row gathers, several times faster on axis 1
    vis = np.take(visible, cols, axis=1)
    x = np.take(positions, cols, axis=1)
    flat = x.reshape(len(x), -1)
    weight = np.repeat(np.concatenate(([1.0], _distance_weights(x, vis))), 3)
    limit = 3 * len(donors)
    complete = vis.all(axis=1)
    if complete.sum() >= 3 * len(cols):
        mean, scale, sv, axes = _standardized_axes(flat[complete], weight)
        mu = np.zeros(flat.shape[1])
        axes = axes[:, :_n_components(sv, limit)].T
    else:
        mask = np.repeat(vis, 3, axis=1)
        mean, scale = _moments(flat, mask)
        z = np.where(mask, (flat - mean) / scale * weight, 0.0)
        mu, axes = _components_iterative(z, mask, limit)

    length = stop - start
    rows_complete = np.flatnonzero(complete)
    i = np.searchsorted(rows_complete, start)
    before = rows_complete[i - 1:i] if i > 0 else rows_complete[:0]
    after = rows_complete[i:i + 1]
    before = before[start - before <= length]
    after = after[after - stop < length]
    rows = np.concatenate((np.arange(start, stop), before, after))

    zd = (flat[rows, 3:] - mean[3:]) / scale[3:] * weight[3:] - mu[3:]
    scores = np.linalg.lstsq(axes[:, 3:].T, zd.T, rcond=None)[0]
    pred = ((axes[:, :3].T @ scores).T + mu[:3]) * scale[:3] + mean[:3]

    fill = pred[:length]
    residual = flat[rows[length:], :3] - pred[length:]
    if len(residual) == 2:
        alpha = ((np.arange(start, stop) - before[0]) / (after[0] - before[0]))[:, None]
        fill = fill + (1 - alpha) * residual[0] + alpha * residual[1]
    elif len(residual) == 1:
        fill = fill + residual[0]
    return fill
