"""Rigid-cluster fill: carry a marker along with the donors of its cluster.

The rigid transform that takes the donors from a reference frame (where the
target was seen) to each frame of the gap is fitted for all gap frames at once
with a batched, weighted Kabsch solve (one stacked 3x3 SVD).
"""

from __future__ import annotations

import numpy as np

#: Donors a rigid fit needs in a frame (and in the reference frame).
MIN_DONORS = 3


def kabsch(source: np.ndarray, target: np.ndarray, weights: np.ndarray):
    """Batched weighted rigid fit ``target ≈ R @ source + t``, no scaling, no reflection.

    Parameters
    ----------
    source, target : ndarray of shape (n_fits, n_points, 3)
        Point sets; entries with zero weight may be NaN.
    weights : ndarray of shape (n_fits, n_points)
        Non-negative; each row needs at least three non-collinear points with
        positive weight.

    Returns
    -------
    rotation : ndarray of shape (n_fits, 3, 3)
    translation : ndarray of shape (n_fits, 3)
    """
    w = np.asarray(weights, dtype=np.float64)[..., None]
    src = np.where(w > 0, source, 0.0)
    dst = np.where(w > 0, target, 0.0)
    total = w.sum(axis=1)
    c_src = (w * src).sum(axis=1) / total
    c_dst = (w * dst).sum(axis=1) / total
    cov = np.einsum("fki,fkj->fij", w * (src - c_src[:, None]), dst - c_dst[:, None])
    u, _, vt = np.linalg.svd(cov)
    # R = V diag(1, 1, d) U^T with d = sign det(V U^T): the proper rotation.
    d = np.where(np.linalg.det(u @ vt) < 0, -1.0, 1.0)
    vt[:, 2, :] *= d[:, None]
    rotation = np.swapaxes(u @ vt, 1, 2)
    translation = c_dst - np.einsum("fij,fj->fi", rotation, c_src)
    return rotation, translation


def _carry(positions, visible, target, donors, ref, frames):
    """Target at `frames` carried rigidly from frame `ref`; NaN where < 3 donors."""
    w = visible[frames][:, donors] & visible[ref, donors]
    ok = w.sum(axis=1) >= MIN_DONORS
    out = np.full((len(frames), 3), np.nan)
    if ok.any():
        n = int(ok.sum())
        src = np.broadcast_to(positions[ref, donors], (n, len(donors), 3))
        dst = positions[frames[ok]][:, donors]
        rot, trans = kabsch(src, dst, w[ok])
        out[ok] = rot @ positions[ref, target] + trans
    return out


def fill_rigid(positions: np.ndarray, visible: np.ndarray, target: int, start: int,
               stop: int, donors: np.ndarray) -> np.ndarray:
    """Rigid-body estimate of marker `target` over frames ``start:stop``.

    Parameters
    ----------
    positions : ndarray of shape (n_frames, n_markers, 3), mm, NaN where missing
    visible : ndarray of bool, shape (n_frames, n_markers)
    target : int
        Column of the missing marker.
    start, stop : int
        The gap, frame indices.
    donors : ndarray of int
        The other markers of the target's rigid cluster.

    Returns
    -------
    ndarray of shape (stop - start, 3), mm
        NaN in frames where no reference could be used (fewer than three
        donors visible in both the frame and the reference frame).

    Notes
    -----
    The references are the nearest frames before and after the gap where the
    target and at least three donors are visible. From each, the donors'
    rigid motion into every gap frame (one batched Kabsch fit) carries the
    target's reference position along; the two estimates are blended
    linearly in time (one alone where only one exists). On noise-free rigid
    data both estimates are exact. (Averaging the cluster shape over several
    reference frames was tried on facial-sing.c3d and did not help: its head
    markers deform slowly rather than jitter.)
    """
    frames = np.arange(start, stop)
    ref_ok = visible[:, target] & (visible[:, donors].sum(axis=1) >= MIN_DONORS)
    refs = np.flatnonzero(ref_ok)
    i = np.searchsorted(refs, start)
    sides = [(ref, _carry(positions, visible, target, donors, ref, frames))
             for ref in (refs[i - 1:i] if i > 0 else refs[:0]).tolist() + refs[i:i + 1].tolist()]
    if not sides:
        return np.full((len(frames), 3), np.nan)
    if len(sides) == 1:
        return sides[0][1]
    (t0, before), (t1, after) = sides
    alpha = ((frames - t0) / (t1 - t0))[:, None]
    blend = (1 - alpha) * before + alpha * after
    return np.where(np.isnan(blend), np.where(np.isnan(before), after, before), blend)
