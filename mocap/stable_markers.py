"""Stabilization markers found from the take itself, for captures without head markers.

Facial solvers stabilize on the least-deforming face markers when there is
no headband (forehead, nose bridge, temples, inner eye corners):
:func:`find_stable_markers` finds them in a take from how the distances
between markers vary over it, the choice that ``stabilize = "auto"`` fits
rigidly (:func:`mocap.head_frame.find_head_frame`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from mocap.errors import InputError, MarkerError
from mocap.take import Take, as_take
from mocap.util.arrays import read_only
from mocap.util.validation import as_int

__all__ = ["StableMarkers", "find_stable_markers", "distance_variation", "MIN_PRESENCE"]

#: A candidate must be visible in at least this fraction of the frames: a
#: marker seen in under half the take cannot hold the head frame through it.
MIN_PRESENCE = 0.5
#: A set whose two smaller principal variances sum to less than this fraction of
#: the largest is collinear (a 1 um offset over 100 mm).
_COLLINEAR = 1e-10
#: Bytes of pairwise-distance temporaries per block of frames.
_BLOCK_BYTES = 64 * 2 ** 20


@dataclass(frozen=True, eq=False)
class StableMarkers:
    """The stabilization markers chosen from a take, and why.

    Attributes
    ----------
    labels : tuple of str
        The markers chosen (at least 3), in the take's order.
    candidates : tuple of str
        Markers that were considered (visible in enough frames).
    excluded : tuple of (str, str)
        Markers left out before the choice, each with the reason.
    variation : ndarray of shape (n_candidates, n_candidates), mm
        Standard deviation over the take of the distance between two
        candidates (over the frames where both are visible; inf where never).
    marker_variation : ndarray of shape (n_chosen,), mm
        Of each chosen marker: the root mean square of its distance
        variations to the other chosen markers.
    criterion : float, degrees
        What the choice minimizes: the RMS distance variation within the set
        over its lever arm (see :func:`find_stable_markers`). A pessimistic
        size of the head rotation error the set's deformation could cause
        (every variation at once, none discounted by the robust fit).
    message : str
    """

    labels: tuple
    candidates: tuple
    excluded: tuple
    variation: np.ndarray
    marker_variation: np.ndarray
    criterion: float
    message: str


def distance_variation(positions, *, block_frames: int | None = None) -> tuple:
    """Mean and standard deviation over frames of the distance of every pair of markers.

    Parameters
    ----------
    positions : ndarray of shape (n_frames, n_markers, 3), mm
        NaN where missing.
    block_frames : int, optional
        Frames per block (default: a 64 MiB budget of temporaries).

    Returns
    -------
    mean, std : ndarray of shape (n_markers, n_markers), mm
        Over the frames where both markers are visible; NaN (mean) and inf
        (std) for a pair never visible together, 0 on the diagonal.
    count : ndarray of int, shape (n_markers, n_markers)
        Frames where both are visible.

    Notes
    -----
    One pass over the frames in blocks, accumulating the sums of the distances
    and of their squares about a per-pair shift (the first block's mean), so
    that the variance does not cancel.

    Examples
    --------
    >>> pos = np.array([[[0., 0, 0], [10, 0, 0]], [[0, 0, 0], [12, 0, 0]]])
    >>> mean, std, count = distance_variation(pos)
    >>> float(mean[0, 1]), float(std[0, 1]), int(count[0, 1])
    (11.0, 1.0, 2)
    """
    n_frames, n_markers = positions.shape[:2]
    if block_frames is None:
        block_frames = max(1, _BLOCK_BYTES // (48 * n_markers * n_markers))
    total = np.zeros((n_markers, n_markers))
    square = np.zeros((n_markers, n_markers))
    count = np.zeros((n_markers, n_markers), dtype=np.int64)
    shift = None
    for lo in range(0, n_frames, block_frames):
        block = positions[lo:lo + block_frames]
        visible = ~np.isnan(block[..., 0])
        seen = visible[:, :, None] & visible[:, None, :]
        # |a - b|^2 = |a|^2 + |b|^2 - 2 a.b about each frame's centroid: one
        # batched matrix product instead of an (F, M, M, 3) difference
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)    # frames with nothing visible
            centred = np.nan_to_num(block - np.nanmean(block, axis=1, keepdims=True))
        norm2 = (centred * centred).sum(axis=-1)
        d = norm2[:, :, None] + norm2[:, None, :] - 2.0 * centred @ np.swapaxes(centred, 1, 2)
        d = np.where(seen, np.sqrt(np.maximum(d, 0.0)), np.nan)
        if shift is None:
            with np.errstate(invalid="ignore"):
                shift = np.nan_to_num(np.nansum(d, axis=0) / seen.sum(axis=0))
        d = np.where(seen, d - shift, 0.0)
        total += d.sum(axis=0)
        square += (d * d).sum(axis=0)
        count += seen.sum(axis=0)
    safe = np.maximum(count, 1)
    mean = np.where(count > 0, shift + total / safe, np.nan)
    var = np.maximum(square / safe - (total / safe) ** 2, 0.0)
    std = np.where(count > 0, np.sqrt(var), np.inf)
    np.fill_diagonal(mean, 0.0)
    np.fill_diagonal(std, 0.0)
    return mean, std, count


def _rest_shape(mean_distance: np.ndarray) -> np.ndarray:
    """A 3-D configuration (n, 3) whose distances best match the mean distances (classical MDS)."""
    d2 = np.nan_to_num(mean_distance, nan=np.nanmax(mean_distance)) ** 2
    n = len(d2)
    centring = np.eye(n) - 1.0 / n
    gram = -0.5 * centring @ d2 @ centring
    values, vectors = np.linalg.eigh(gram)
    top = np.argsort(values)[::-1][:3]
    return vectors[:, top] * np.sqrt(np.maximum(values[top], 0.0))


def _lever(shape: np.ndarray) -> float:
    """sqrt(l2 + l3), mm: the spread that pins a rotation about the set's longest axis."""
    centred = shape - shape.mean(axis=0)
    values = np.linalg.eigvalsh(centred.T @ centred / len(shape))
    if values[0] + values[1] <= _COLLINEAR * values[2]:      # a line pins no rotation about it
        return 0.0
    return float(np.sqrt(values[0] + values[1]))


def _criterion(deform2: np.ndarray, noise2: float, shape: np.ndarray,
               members: np.ndarray) -> float:
    """Expected rotation error of a rigid fit to `members`, radians (inf if collinear).

    ``sqrt(mean deformation^2 + noise^2 / n) / lever``: the deformation of the
    set is not averaged away by more markers, the noise is.
    """
    n = len(members)
    deform = deform2[np.ix_(members, members)].sum() / (n * (n - 1))
    lever = _lever(shape[members])
    return float(np.sqrt(deform + noise2 / n) / lever) if lever > 0 else np.inf


def find_stable_markers(take: Take, labels=None, *, min_markers: int = 3,
                        min_presence: float = MIN_PRESENCE) -> StableMarkers:
    """The largest set of markers whose distances vary least over the take, relative to its size.

    Parameters
    ----------
    take : Take
        Positions (n_frames, n_markers, 3), mm, NaN where missing; any frame
        (the head may move: only distances between markers are used).
    labels : sequence of str, optional
        Candidates (default: every marker of the take); typically a marker
        set's face markers.
    min_markers : int, default 3
        Fewest markers chosen.
    min_presence : float, default MIN_PRESENCE (0.5)
        Candidates visible in fewer than this fraction of the frames are
        left out (and reported in ``excluded``).

    Returns
    -------
    StableMarkers

    Raises
    ------
    InputError
        Fewer than `min_markers` candidates, or a bad option.
    MarkerError
        A label not in the take; fewer than `min_markers` candidates visible
        in enough frames (the message names the rarest).

    Notes
    -----
    For every pair of candidates the standard deviation v_ij of their distance
    over the take measures how much the two move relative to each other
    (:func:`distance_variation`; a rigid pair varies only by the noise,
    about 1.4 sigma). A set S is scored by ``sqrt(mean_{i != j in S} v_ij^2)
    / sqrt(l2 + l3)``: its RMS distance variation over its lever arm, where
    l1 >= l2 >= l3 are the principal variances of the set's rest shape (a
    classical multidimensional scaling of the mean distances); a rotation
    about the set's longest axis is pinned only by the spread across it,
    so a compact or collinear set (a nose, a row of eye corners) scores badly
    however rigid it is. The choice is a backward elimination: from all
    candidates, the marker whose removal lowers the score most goes, until
    no removal lowers it (or `min_markers` remain). Markers that deform with
    expressions (lips, jaw, brows) go first; a wide set that holds its shape
    (forehead, nose bridge, temples, inner eye corners) stays.

    Examples
    --------
    A rigid tetrahedron of markers and one that wanders:

    >>> rng = np.random.default_rng(0)
    >>> rigid = np.array([[0., 0, 0], [80, 0, 0], [0, 80, 0], [0, 0, 80]])
    >>> wander = 40 + 10 * np.sin(np.linspace(0, 6, 400))[:, None] * [1, 1, 0]
    >>> pos = np.concatenate([np.broadcast_to(rigid, (400, 4, 3)), wander[:, None]], axis=1)
    >>> take = Take(("a", "b", "c", "d", "e"), pos + 0.1 * rng.standard_normal(pos.shape), 100)
    >>> find_stable_markers(take).labels
    ('a', 'b', 'c', 'd')
    """
    take = as_take(take)
    labels = take.labels if labels is None else tuple(labels)
    if isinstance(labels, str) or len(set(labels)) != len(labels):
        raise InputError(f"labels must be a sequence of distinct marker labels, got {labels!r}")
    min_markers = as_int(min_markers, "min_markers", minimum=3)
    if not 0 <= min_presence <= 1:
        raise InputError(f"min_presence must be in [0, 1], got {min_presence!r}")
    if len(labels) < min_markers:
        raise InputError(f"{len(labels)} candidate markers; choosing stabilization markers "
                         f"needs at least {min_markers}")
    positions = take.select(labels).positions
    presence = (~np.isnan(positions[..., 0])).mean(axis=0)
    keep = presence >= min_presence
    excluded = tuple((label, f"visible in {100 * p:.0f} % of the frames")
                     for label, p, k in zip(labels, presence, keep) if not k)
    if keep.sum() < min_markers:
        rarest = labels[int(np.argmin(presence))]
        raise MarkerError(rarest, f"is visible in {100 * presence.min():.0f} % of the frames; "
                                  f"only {int(keep.sum())} candidates are visible in "
                                  f"{100 * min_presence:.0f} % or more, fewer than the "
                                  f"{min_markers} a rigid fit needs")
    candidates = tuple(x for x, k in zip(labels, keep) if k)
    mean, std, _ = distance_variation(positions[:, keep])
    var2 = np.where(np.isfinite(std), std ** 2, 1e12)
    noise2 = float(np.min(var2[~np.eye(len(var2), dtype=bool)]))
    deform2 = np.maximum(var2 - noise2, 0.0)
    shape = _rest_shape(mean)
    members = np.arange(len(candidates))
    score = _criterion(deform2, noise2, shape, members)
    while len(members) > min_markers:
        trials = [_criterion(deform2, noise2, shape, np.delete(members, k))
                  for k in range(len(members))]
        best = int(np.argmin(trials))
        if not trials[best] < score:
            break
        members, score = np.delete(members, best), trials[best]
    if not np.isfinite(score):
        raise InputError(f"the candidate markers {', '.join(candidates)} are collinear or never "
                         "visible together: no rigid stabilization set")
    sub = var2[np.ix_(members, members)]
    marker_variation = np.sqrt(sub.sum(axis=1) / (len(members) - 1))
    order = np.argsort([take.labels.index(candidates[k]) for k in members], kind="stable")
    members, marker_variation = members[order], marker_variation[order]
    chosen = tuple(candidates[k] for k in members)
    criterion = float(np.degrees(score))
    message = (f"{len(chosen)} of {len(candidates)} candidates hold their distances best "
               f"({', '.join(chosen)}): distance variation "
               f"{float(np.sqrt(sub.sum() / (len(members) * (len(members) - 1)))):.2f} mm RMS, "
               f"criterion {criterion:.2f} deg")
    return StableMarkers(labels=chosen, candidates=candidates, excluded=excluded,
                         variation=read_only(std), marker_variation=read_only(marker_variation),
                         criterion=criterion, message=message)
