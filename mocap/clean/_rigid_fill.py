"""Rigid-cluster fill: carry a marker along with the donors of its cluster.

The donors' rigid motion over the gap is found by :func:`mocap.stabilize.stabilize`
(one batched fit of all frames to their generalized-Procrustes mean shape),
with each donor weighted by how rigidly it moved with the target next to the
gap. The target's position in the donors' local frame, known at the frames
just before and after the gap, is interpolated linearly over the gap and
carried back to the world.
"""

from __future__ import annotations

import numpy as np

from mocap.stabilize import stabilize
from mocap.take import Take

#: Donors a rigid fit needs in a frame (and in a reference frame).
MIN_DONORS = 3
#: Frames on each side of the gap over which a donor's rigidity with the target is measured.
RIGIDITY_FRAMES = 100
#: Floor of the standard deviation of a donor-target distance, mm (about the
#: marker noise): below it a donor is as good as perfectly rigid.
RIGIDITY_FLOOR_MM = 0.1
#: Frame rate given to the windows passed to ``stabilize`` (it does not use it), Hz.
_RATE = 100.0


def donor_weights(positions: np.ndarray, target: int, start: int, stop: int,
                  donors: np.ndarray) -> np.ndarray:
    """Weight of each donor: the inverse variance of its distance to the target near the gap.

    Parameters
    ----------
    positions : ndarray of shape (n_frames, n_markers, 3), mm, NaN where missing
    target : int
    start, stop : int
        The gap, frame indices.
    donors : ndarray of int, shape (n_donors,)

    Returns
    -------
    ndarray of shape (n_donors,)
        ``1 / (var d + RIGIDITY_FLOOR_MM**2)``, with ``d`` the distance to the
        target over the ``RIGIDITY_FRAMES`` frames before and after the gap
        where both are visible. A donor seen there with the target fewer than
        twice gets the smallest weight of the others (all 1 if none is).
    """
    n_frames = positions.shape[0]
    side = np.r_[max(start - RIGIDITY_FRAMES, 0):start, stop:min(stop + RIGIDITY_FRAMES, n_frames)]
    dist = np.linalg.norm(positions[side][:, donors] - positions[side, target, None], axis=-1)
    seen = ~np.isnan(dist)
    count = seen.sum(axis=0)
    assessed = count >= 2
    if not assessed.any():
        return np.ones(len(donors))
    d = np.where(seen, dist, 0.0)
    mean = d.sum(axis=0) / np.maximum(count, 1)
    var = (np.where(seen, d - mean, 0.0) ** 2).sum(axis=0) / np.maximum(count, 1)
    weights = 1.0 / (var + RIGIDITY_FLOOR_MM ** 2)
    return np.where(assessed, weights, weights[assessed].min())


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
        NaN in frames with fewer than three donors visible, or without a
        reference frame on either side.

    Notes
    -----
    The reference frames are the nearest frames before and after the gap
    where the target and at least three donors are visible. Over the frames
    from one to the other, ``stabilize(reference="mean", robust=False)``
    fits the donors' mean shape to every frame, each donor weighted by
    :func:`donor_weights`; the target's local position is known at the
    reference frames and interpolated linearly in time between them (held
    when there is only one). Interpolating in the donors' frame, not in the
    world, follows the slow drift of a head band, and the weights keep a
    donor that slips relative to the target from turning the whole cluster.
    On noise-free rigid data the fill is exact. (Robust reweighting within
    the gap, ``robust=True``, was tried on facial-sing.c3d: its head markers
    deform with the face, and the fill got worse.)
    """
    frames = np.arange(start, stop)
    ref_ok = visible[:, target] & (visible[:, donors].sum(axis=1) >= MIN_DONORS)
    refs = np.flatnonzero(ref_ok)
    i = np.searchsorted(refs, start)
    before = int(refs[i - 1]) if i > 0 else None
    after = int(refs[i]) if i < len(refs) else None
    if before is None and after is None:
        return np.full((len(frames), 3), np.nan)
    lo = start if before is None else before
    hi = stop if after is None else after + 1
    # Donors never visible in a frame with 3 visible donors cannot be placed.
    window = visible[lo:hi, donors]
    usable = donors[(window & (window.sum(axis=1) >= MIN_DONORS)[:, None]).any(axis=0)]
    columns = np.append(usable, target)
    labels = tuple(str(c) for c in columns)
    take = Take(labels, positions[lo:hi, columns], rate=_RATE)
    st = stabilize(take, labels[:-1], robust=False,
                   weights=donor_weights(positions, target, start, stop, usable))
    local = st.take.positions[:, -1]
    path = np.full((hi - lo, 3), np.nan)
    if before is None or after is None:
        path[start - lo:stop - lo] = local[0 if after is None else -1]
    else:
        alpha = ((frames - before) / (after - before))[:, None]
        path[start - lo:stop - lo] = (1.0 - alpha) * local[0] + alpha * local[-1]
    return st.to_world(path[:, None])[start - lo:stop - lo, 0]
