"""Marker label swaps: two nearby markers exchange labels for a run of frames.

:func:`find_label_swaps` finds the runs, :func:`fix_label_swaps` exchanges the
columns back. Detection works on the positions as given (capture frame or head
frame); it is sharper after head stabilization
(``mocap.stabilize.stabilize(take, head).take``) but does not need it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.clean._tracks import last_visible, long_gap_starts, typical_step
from mocap.errors import InputError, MarkerError
from mocap.take import Take, as_take
from mocap.util.arrays import read_only
from mocap.util.order_statistics import nan_column_medians
from mocap.util.validation import as_int, as_positive_float

__all__ = ["LabelSwap", "find_label_swaps", "fix_label_swaps"]



@dataclass(frozen=True)
class LabelSwap:
    """A run of frames where the labels of two markers are exchanged.

    Attributes
    ----------
    marker_a, marker_b : str
        Labels of the two markers (``marker_a`` comes first in the take).
    start, stop : int
        Frame indices (0-based) of the run, `stop` excluded; ``stop ==
        n_frames`` for a swap that lasts to the end of the take.
    jump_mm : float
        Mean jump of the two labelled trajectories where the run starts (and
        ends, if it does), ``|a(t) - a(t-1)| + |b(t) - b(t-1)|`` halved, mm.
    residual_mm : float
        Largest jump left at those frames once the labels are exchanged,
        ``|a(t) - b(t-1)| + |b(t) - a(t-1)|`` halved, mm.
    score : float
        Smallest gain of exchanging (jump minus residual, both summed over the
        two markers) at those frames, in units of the two markers' summed
        typical frame-to-frame motion.
    """

    marker_a: str
    marker_b: str
    start: int
    stop: int
    jump_mm: float
    residual_mm: float
    score: float


def _candidate_pairs(positions: np.ndarray, neighbours: int) -> np.ndarray:
    """Pairs (i < j) where one marker is among the other's `neighbours` nearest
    in the median pose; shape (n_pairs, 2)."""
    n_markers = positions.shape[1]
    median = nan_column_medians(positions)
    dist = np.linalg.norm(median[:, None] - median[None], axis=2)
    dist[np.isnan(dist)] = np.inf
    np.fill_diagonal(dist, np.inf)
    k = min(neighbours, n_markers - 1)
    if k < 1:
        return np.empty((0, 2), dtype=np.intp)
    nearest = np.argsort(dist, axis=1, kind="stable")[:, :k]
    rows = np.repeat(np.arange(n_markers), k)
    cols = nearest.ravel()
    keep = np.isfinite(dist[rows, cols])
    pairs = np.sort(np.stack([rows[keep], cols[keep]], axis=1), axis=1)
    return np.unique(pairs, axis=0)


def _carried(positions, prev, last, m, other):
    """Last visible position of markers `m` before each frame, carried along with
    the motion of their partners `other` since then (shape (n_frames - 1, K, 3)).

    Neighbours share the head's motion, so a marker back from a gap is compared
    with where it would be now, not where it was; where the partner was not
    seen at that frame, the last position is used as it is.
    """
    lm = last[:, m]
    shift = prev[:, other] - positions[np.maximum(lm, 0), other]
    shift[np.isnan(shift)] = 0.0
    return prev[:, m] + shift


def _events(positions, pairs, typical, *, threshold, max_ratio, max_gap):
    """Frames where exchanging a pair's labels makes both trajectories continuous.

    Returns arrays ``t, k, keep, cross, gain`` over the events (frame index,
    pair row, summed own jump, summed jump after exchanging, gain in units of
    typical motion), vectorized over frames and pairs.
    """
    prev, last = last_visible(positions)
    cur = positions[1:]
    frame = np.arange(1, positions.shape[0])[:, None]
    a, b = pairs[:, 0], pairs[:, 1]
    pa, pb = _carried(positions, prev, last, a, b), _carried(positions, prev, last, b, a)
    with np.errstate(invalid="ignore"):
        keep = np.linalg.norm(cur[:, a] - pa, axis=2) + np.linalg.norm(cur[:, b] - pb, axis=2)
        cross = np.linalg.norm(cur[:, a] - pb, axis=2) + np.linalg.norm(cur[:, b] - pa, axis=2)
        gain = (keep - cross) / (typical[a] + typical[b])
        fresh = ((last[:, a] >= 0) & (frame - last[:, a] <= max_gap + 1)
                 & (last[:, b] >= 0) & (frame - last[:, b] <= max_gap + 1))
        event = fresh & (gain > threshold) & (cross < max_ratio * keep)
    t, k = np.nonzero(event)
    return t + 1, k, keep[t, k], cross[t, k], gain[t, k]


def _runs(t: np.ndarray, events: np.ndarray, breaks: np.ndarray, n_frames: int):
    """Pair one marker pair's events (indices into `t`, in time order) into runs.

    A swap-in ends at the next event (its swap-out) unless a long gap of either
    marker starts first (a frame of `breaks`), or the take ends. Yields the
    events of each run (one or two) and its stop frame.
    """
    j = 0
    while j < len(events):
        start = t[events[j]]
        after = breaks[breaks > start]
        limit = after[0] if len(after) else n_frames
        if j + 1 < len(events) and t[events[j + 1]] <= limit:
            yield events[j:j + 2], t[events[j + 1]]
            j += 2
        else:
            yield events[j:j + 1], limit
            j += 1


def find_label_swaps(take: Take, *, neighbours: int = 4, threshold: float = 10.0,
                     max_ratio: float = 0.25, max_gap: int = 25) -> tuple[LabelSwap, ...]:
    """Find runs of frames where two nearby markers have exchanged labels.

    Parameters
    ----------
    take : Take
        Positions (n_frames, n_markers, 3), mm, NaN where missing; in the
        capture frame or, better, the head frame. Not modified.
    neighbours : int
        Candidate pairs: each marker with its `neighbours` nearest markers in
        the median pose (median over frames of each coordinate).
    threshold : float
        An exchange at frame t must shorten the two trajectories' summed jump
        by more than `threshold` times the two markers' summed typical
        frame-to-frame motion (median step of each marker, at least 0.05 mm).
    max_ratio : float
        ... and leave at most this fraction of that jump (0 < max_ratio < 1).
    max_gap : int
        A marker missing just before frame t is compared through its last
        visible sample if that is at most `max_gap` frames earlier (a gap
        next to a swap); older, the frame is not tested for that pair.

    Returns
    -------
    tuple of LabelSwap
        Ordered by start frame, then labels.

    Raises
    ------
    InputError
        `take` not a Take; an option out of range.

    Notes
    -----
    For a candidate pair (a, b) and every frame t (vectorized over frames and
    pairs), with ``a'``, ``b'`` the last visible positions before t::

        keep  = |a(t) - a'| + |b(t) - b'|      (labels as recorded)
        cross = |a(t) - b'| + |b(t) - a'|      (labels exchanged at t)

    An *event* is a frame where both markers are visible, ``keep - cross >
    threshold * (s_a + s_b)`` (s = typical step) and ``cross < max_ratio *
    keep``: both labels jump at once and each lands where the other was. Fast
    genuine motion (a blink, the jaw) moves one marker, or moves both without
    each landing on the other, and fails the test. A marker in two events at
    the same frame keeps the one with the larger gain. A pair's events in time
    order alternate swap-in, swap-out; a swap-in without a swap-out runs to
    the first gap longer than `max_gap` of either marker (the labeller sees
    the marker anew after it), or to the end of the take.

    NaN policy: frames where a label is missing are exchanged with the run
    like any other (the NaN moves to the other label); a swap cannot start at
    frame 0 (no previous frame). Chains of swaps through a third marker are
    reported as separate pairwise runs, which :func:`fix_label_swaps` applies
    in order.

    Examples
    --------
    >>> import numpy as np
    >>> from mocap import Take
    >>> t = np.arange(50)[:, None]
    >>> pos = np.stack([np.hstack([t * 0.1, 0 * t, 0 * t]),
    ...                 np.hstack([t * 0.1, 0 * t + 20, 0 * t])], axis=1)
    >>> pos[10:20] = pos[10:20, ::-1]
    >>> [(s.marker_a, s.marker_b, s.start, s.stop)
    ...  for s in find_label_swaps(Take(("a", "b"), pos, rate=100.0))]
    [('a', 'b', 10, 20)]
    """
    take = as_take(take)
    neighbours = as_int(neighbours, "neighbours", minimum=1)
    threshold = as_positive_float(threshold, "threshold")
    max_ratio = as_positive_float(max_ratio, "max_ratio")
    if max_ratio >= 1:
        raise InputError(f"max_ratio must be below 1, got {max_ratio}")
    max_gap = as_int(max_gap, "max_gap", minimum=0)
    positions = take.positions
    if take.n_frames < 2 or take.n_markers < 2:
        return ()
    pairs = _candidate_pairs(positions, neighbours)
    typical = typical_step(positions)
    t, k, keep, cross, gain = _events(positions, pairs, typical, threshold=threshold,
                                      max_ratio=max_ratio, max_gap=max_gap)
    # One event per marker and frame: the largest gain wins.
    chosen = []
    taken = set()
    for i in np.lexsort((-gain, t)):
        a, b = pairs[k[i]]
        if (t[i], a) in taken or (t[i], b) in taken:
            continue
        taken.update({(t[i], a), (t[i], b)})
        chosen.append(i)
    chosen = np.array(sorted(chosen, key=lambda i: (k[i], t[i])), dtype=np.intp)
    long_gaps = long_gap_starts(take.missing, max_gap)
    swaps = []
    for pair in np.unique(k[chosen]):
        a, b = pairs[pair]
        for ends, stop in _runs(t, chosen[k[chosen] == pair],
                                np.union1d(long_gaps[a], long_gaps[b]), take.n_frames):
            swaps.append(LabelSwap(
                marker_a=take.labels[a], marker_b=take.labels[b],
                start=int(t[ends[0]]), stop=int(stop),
                jump_mm=float(keep[ends].mean() / 2),
                residual_mm=float(cross[ends].max() / 2),
                score=float(gain[ends].min())))
    return tuple(sorted(swaps, key=lambda s: (s.start, s.marker_a, s.marker_b)))


def fix_label_swaps(take: Take, swaps) -> Take:
    """Exchange the columns of each swapped pair back over its run.

    Parameters
    ----------
    take : Take
        Positions (n_frames, n_markers, 3), mm. Not modified.
    swaps : iterable of LabelSwap
        Runs to undo (from :func:`find_label_swaps`, or written by hand),
        applied in the order given.

    Returns
    -------
    Take
        A new take with positions and the ``filled`` record of the two markers
        exchanged over ``start:stop`` for each swap; everything else carried over.

    Raises
    ------
    InputError
        An item is not a LabelSwap, or its frames are outside the take.
    MarkerError
        A swap names a marker the take lacks, or the same marker twice.

    Notes
    -----
    NaN policy: NaNs move with their samples (a missing sample of one label
    becomes a missing sample of the other).
    """
    take = as_take(take)
    swaps = tuple(swaps)
    plan = []
    for swap in swaps:
        if not isinstance(swap, LabelSwap):
            raise InputError(f"swaps must hold LabelSwap records, got {type(swap).__name__}")
        a, b = take.index(swap.marker_a), take.index(swap.marker_b)
        if a == b:
            raise MarkerError(swap.marker_a, "a label swap needs two different markers")
        if not 0 <= swap.start < swap.stop <= take.n_frames:
            raise InputError(f"swap of {swap.marker_a!r} and {swap.marker_b!r} covers frames "
                             f"{swap.start}:{swap.stop}; expected 0 <= start < stop <= "
                             f"{take.n_frames} (the take's frames)")
        plan.append((a, b, swap.start, swap.stop))
    positions = take.positions.copy()
    filled = take.filled.copy()
    for a, b, start, stop in plan:
        for arr in (positions, filled):
            arr[start:stop, [a, b]] = arr[start:stop, [b, a]]
    return take.replace(positions=read_only(positions), filled=read_only(filled))
