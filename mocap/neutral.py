"""The neutral frame of a take: the rest pose every displacement is measured from.

Picked on head-stabilized markers (the frame nearest the median pose, or the
neutral hold a session starts with) or given as a frame index; the rest pose
is the mean of the markers over a window centred on it (one frame, or the
hold's :func:`hold_window`), so that one frame's noise is not a bias of every
displacement. The binding, the retargeting, the gestures analysis and the
chain all find it here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.errors import InputError, MarkerError
from mocap.take import Take, as_take
from mocap.util.arrays import read_only
from mocap.util.order_statistics import nan_column_medians
from mocap.util.validation import as_float_array, as_int, as_positive_float

__all__ = ["Neutral", "find_neutral", "neutral_pose", "pick_neutral_frame",
           "resolve_neutral_frame", "hold_window", "NEUTRAL_METHODS", "PICKED_FRAMES", "HOLD_S"]


#: How :func:`pick_neutral_frame` finds the rest frame.
NEUTRAL_METHODS = ("median", "hold")
#: The neutral-frame options besides a frame index (:func:`resolve_neutral_frame`).
PICKED_FRAMES = ("auto", "hold")
#: Window of the stillness of a frame, and shortest neutral hold, s.
HOLD_S = 0.5


def pick_neutral_frame(positions, *, method: str = "median", rate: float | None = None,
                       markers=None) -> int:
    """The frame of a take closest to its rest pose.

    Parameters
    ----------
    positions : array_like of shape (n_frames, n_markers, 3), mm
        Head-stabilized marker positions (stabilize first: head motion would
        otherwise dominate), NaN where missing.
    method : {"median", "hold"}, default "median"
        "median": for takes that spend most of their time near rest (see
        Notes). "hold": for sessions that start with a neutral hold of at
        least ``HOLD_S`` seconds.
    rate : float, Hz
        Frame rate; needed by "hold".
    markers : array_like of int, optional
        The markers (indices into axis 1 of `positions`) to pick on, read where they
        are (no copy of their tracks); default all.

    Returns
    -------
    int
        Among the frames where every marker is visible: "median", the one of
        smallest root-mean-square distance to the rest pose, the per-marker
        median over every frame in which that marker is visible; "hold", the
        middle frame of the take's first still window (below).

    Raises
    ------
    InputError
        No frame has every marker visible; an unknown method; "hold" without
        a rate, on a take shorter than a hold, or with no hold-long run of
        complete frames.

    Notes
    -----
    A face spends most of a take near rest, so the per-marker median
    approximates the rest pose, robust to expressions that last less than half
    the take. The median is taken over all visible samples of each marker, not
    only over complete frames: gaps come more often with expressions (lips
    hidden by a smile, eyelids in a blink), so complete frames lean away from rest.

    A performer who never rests (a range-of-motion take) defeats the median;
    capture sessions start with a neutral hold for that. The stillness of a
    frame is the RMS distance of the marker samples in the ``HOLD_S`` window
    centred on it to their means over the window; windows up to twice the
    take's smallest stillness (the noise floor) are still. Only the start of
    the first run of still windows is sure to be the hold: a slow, small blend
    out of it can keep the windows still on into the performance.
    """
    positions = as_float_array(positions, "positions", shape=(None, None, 3), copy=False)
    if method not in NEUTRAL_METHODS:
        raise InputError(f"method must be one of {NEUTRAL_METHODS}, got {method!r}")
    picked = slice(None) if markers is None else _as_markers(markers, positions.shape[1])
    columns = (3 * np.arange(positions.shape[1])[picked, None] + np.arange(3)).reshape(-1)
    blocks = [slice(first, first + _FRAMES_PER_BLOCK)        # cache-sized, no (T, M, 3) temp
              for first in range(0, len(positions), _FRAMES_PER_BLOCK)]
    # per block, a (t, M) table of each marker's coordinate sums (NaN where it is missing)
    # or squared offsets, then its picked markers' columns: a 2-D gather, not a (T, M, 3) one
    complete = np.concatenate([~np.isnan(_sample_sums(positions[b])[:, picked]).any(axis=1)
                               for b in blocks]) if blocks else np.zeros(0, bool)
    if not complete.any():
        raise InputError("no frame has every marker visible; fill gaps first or select "
                         "markers")
    if method == "hold":
        return _first_hold(positions.reshape(len(positions), -1), columns, complete, rate)
    rest = np.zeros(positions.shape[1:])
    rest[picked] = nan_column_medians(positions, columns).reshape(-1, 3)
    squared = np.empty(len(positions))          # NaN where a marker is missing
    for b in blocks:
        offset = positions[b] - rest
        offset *= offset
        squared[b] = _sample_sums(offset)[:, picked].sum(axis=1)
    return int(np.argmin(np.where(complete, squared, np.inf)))


#: Frames read at a time when looking for the rest frame (~0.4 MB for 60 markers).
_FRAMES_PER_BLOCK = 256


def _as_markers(markers, n_markers: int) -> np.ndarray:
    """`markers` as a 1-D array of marker indices below `n_markers`; InputError if not."""
    picked = np.asarray(markers)
    if picked.ndim != 1 or not (picked.size == 0 or np.issubdtype(picked.dtype, np.integer)):
        raise InputError(f"markers must be a 1-D array of marker indices, got shape "
                         f"{picked.shape} dtype {picked.dtype}")
    if picked.size and (picked.min() < 0 or picked.max() >= n_markers):
        raise InputError(f"markers must index the {n_markers} markers, got "
                         f"{picked.min()}..{picked.max()}")
    return picked.astype(np.intp)


def _sample_sums(block: np.ndarray) -> np.ndarray:
    """Each sample's coordinate sum (t, M) of positions (t, M, 3), NaN where it is missing
    (by one BLAS product: a reduction over the last three is several times slower)."""
    return (block.reshape(-1, 3) @ np.ones(3)).reshape(block.shape[:2])


def resolve_neutral_frame(positions, frame, *, rate: float | None = None,
                          markers=None) -> int:
    """A neutral-frame option (``--frame``, ``bind.frame``) as a frame index.

    Parameters
    ----------
    positions : array_like of shape (n_frames, n_markers, 3), mm
        As in :func:`pick_neutral_frame`: the frames the index counts. Only
        read for ``"auto"`` and ``"hold"``.
    frame : int, "auto" or "hold"
        An index (returned as it is, without a check against `positions`),
        ``"auto"`` (:func:`pick_neutral_frame`, method "median") or
        ``"hold"`` (method "hold").
    rate : float, Hz, optional
        Frame rate of `positions`; needed by "hold".
    markers : array_like of int, optional
        The markers a frame is picked on (:func:`pick_neutral_frame`); default all.

    Returns
    -------
    int
        0-based frame index.

    Raises
    ------
    InputError
        An index below 0 or not an integer; the errors of :func:`pick_neutral_frame`.
    """
    if frame == "auto":
        return pick_neutral_frame(positions, rate=rate, markers=markers)
    if frame == "hold":
        return pick_neutral_frame(positions, method="hold", rate=rate, markers=markers)
    return as_int(frame, "frame", minimum=0)


def hold_window(rate: float) -> int:
    """Frames of a neutral hold's window: ``HOLD_S`` seconds at `rate`, odd, at least 3.

    Parameters
    ----------
    rate : float, Hz
        Frame rate of the take.

    Returns
    -------
    int
        The window length in frames, centred on a frame.

    Raises
    ------
    InputError
        `rate` not a positive finite number.
    """
    return max(3, int(round(HOLD_S * as_positive_float(rate, "rate"))) | 1)


#: Bytes of the coordinates' cumulative sums :func:`_first_hold` forms at a time.
_HOLD_BLOCK_BYTES = 1 << 21


def _first_hold(table, columns, complete, rate) -> int:
    """The middle frame of the first still window (see :func:`pick_neutral_frame`) of the
    `columns` (3M,) of `table` (T, 3 × markers), whose frames `complete` (T,) have all
    M markers."""
    if rate is None:
        raise InputError("method 'hold' needs the take's frame rate")
    window = hold_window(rate)
    if len(table) < window:
        raise InputError(f"a neutral hold is {HOLD_S} s ({window} frames); the take has "
                         f"only {len(table)}")
    # spread of every coordinate over the window centred on each frame, by
    # cumulative sums (about the median pose, for accuracy), summed over the
    # coordinates a cache-sized block of them at a time; windows with an
    # incomplete frame in them do not count
    medians = nan_column_medians(table, columns)
    spread = np.zeros(len(table) - window + 1)
    width = max(1, _HOLD_BLOCK_BYTES // (8 * (len(table) + 1)))
    for first in range(0, len(columns), width):
        part = slice(first, first + width)
        block = np.nan_to_num(table[:, columns[part]] - medians[part])
        sums, squares = (np.zeros((len(block) + 1, block.shape[1])) for _ in range(2))
        np.cumsum(block, axis=0, out=sums[1:])
        np.cumsum(block * block, axis=0, out=squares[1:])
        mean = (sums[window:] - sums[:-window]) / window
        var = (squares[window:] - squares[:-window]) / window - mean ** 2
        spread += np.maximum(var, 0.0).sum(axis=1)
    stillness = np.sqrt(spread / (len(columns) // 3))
    gaps = np.cumsum(np.r_[0, ~complete])
    stillness[gaps[window:] > gaps[:-window]] = np.nan
    centre = np.arange(window // 2, len(table) - window // 2)
    if np.isnan(stillness).all():
        raise InputError(f"no {window} consecutive frames have every marker visible: "
                         "fill gaps before looking for a neutral hold")
    still = stillness <= 2.0 * np.nanmin(stillness)
    return int(centre[np.argmax(still)])


def neutral_pose(positions, frame: int, window: int = 1) -> np.ndarray:
    """The rest pose: the mean of the marker positions over a window around a frame.

    Parameters
    ----------
    positions : array_like of shape (n_frames, n_markers, 3), mm
        Marker positions; NaN propagates (a marker missing in one frame of
        the window is NaN in the rest pose).
    frame : int
        0-based index of the window's centre.
    window : int, default 1
        Frames averaged, centred on `frame` and cut at the ends of the take
        (1: the frame itself).

    Returns
    -------
    ndarray of shape (n_markers, 3), mm

    Raises
    ------
    InputError
        `positions` not of that shape, `frame` beyond the take, `window` below 1.

    Examples
    --------
    >>> positions = np.arange(5.0)[:, None, None] * np.ones((5, 2, 3))
    >>> neutral_pose(positions, 2, window=3)[0]
    array([2., 2., 2.])
    """
    positions = np.asarray(positions, dtype=np.float64)      # no copy of a whole take
    if positions.ndim != 3 or positions.shape[2] != 3:
        raise InputError(f"positions must have shape (n_frames, n_markers, 3), got "
                         f"{positions.shape}")
    frame = as_int(frame, "neutral frame", minimum=0)
    if frame >= len(positions):
        raise InputError(f"neutral frame index {frame} is beyond the take's {len(positions)} "
                         "frames")
    window = as_int(window, "neutral_window", minimum=1)
    return positions[max(0, frame - window // 2):frame + window // 2 + 1].mean(axis=0)


@dataclass(frozen=True, eq=False)
class Neutral:
    """The neutral frame of a take and its rest pose.

    Attributes
    ----------
    frame : int
        0-based index of the neutral frame (the centre of the window).
    window : int
        Frames averaged into the rest pose, centred on `frame`.
    pose : ndarray of shape (M, 3), mm
        The rest pose of `labels`, in the frame of the positions it was taken
        from (the head frame for a stabilized take). No NaN.
    labels : tuple of str
    """

    frame: int
    window: int
    pose: np.ndarray
    labels: tuple


def find_neutral(take: Take, frame="auto", *, labels=None, window: int | None = None) -> Neutral:
    """The neutral frame of a take (picked or given) and the rest pose around it.

    Parameters
    ----------
    take : Take
        Head-stabilized for a picked frame (head motion would otherwise
        dominate the pick); positions (T, M, 3), mm.
    frame : int, "auto" or "hold"
        A 0-based index, or picked on `labels`: :func:`resolve_neutral_frame`.
    labels : sequence of str, optional
        The markers the frame is picked on and whose rest pose is returned
        (default: every marker of the take).
    window : int, optional
        Frames averaged into the rest pose; default the hold's
        :func:`hold_window` for ``"hold"``, else 1.

    Returns
    -------
    Neutral

    Raises
    ------
    InputError
        An index beyond the take; the errors of :func:`pick_neutral_frame`.
    MarkerError
        A marker missing in the window (named, with the frame number and index).

    Examples
    --------
    >>> take = Take(("a", "b"), np.zeros((10, 2, 3)), rate=100.0, first_frame=1)
    >>> neutral = find_neutral(take, 4)
    >>> neutral.frame, neutral.window, neutral.pose.shape
    (4, 1, (2, 3))
    """
    take = as_take(take)
    labels = take.labels if labels is None else tuple(labels)
    markers = take.indices(labels, distinct=True)
    positions = take.positions                  # the markers read where they are, not copied
    index = resolve_neutral_frame(positions, frame, rate=take.rate, markers=markers)
    source = take.source.path or "the take"
    if index >= take.n_frames:
        raise InputError(f"{source}: neutral frame index {index} is beyond the take's "
                         f"{take.n_frames} frames")
    if window is None:
        window = hold_window(take.rate) if frame == "hold" else 1
    pose = neutral_pose(positions, index, window)[markers]
    missing = np.flatnonzero(np.isnan(pose).any(axis=1))
    if missing.size:
        where = (f"is missing (NaN) in the neutral frame {take.first_frame + index} (index "
                 f"{index}) of {source}" if window == 1 else
                 f"is missing in the {window} frames around the neutral frame "
                 f"{take.first_frame + index} (index {index}) of {source}: the rest pose is "
                 "their mean")
        raise MarkerError(labels[missing[0]], where)
    return Neutral(frame=int(index), window=int(window), pose=read_only(pose), labels=labels)
