"""Implausible marker samples: teleports, duplicate labels, ghost slides, off-rest.

Capture software sometimes puts a label on the wrong marker for a while (a
*teleport*: a jump away and a jump back), gives one marker two labels (a
*duplicate*), or invents samples by interpolating between two places (a
*ghost slide*: a straight line at constant speed). :func:`find_implausible_samples`
flags those samples and :func:`remove_implausible_samples` sets them to NaN so
that :func:`mocap.clean.fill_gaps` fills them again. Pairwise label-swap repair
(:mod:`mocap.clean.swaps`) cannot undo these: no other label holds the lost
trajectory.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.clean._tracks import (
    last_visible,
    long_gap_starts,
    typical_step,
)
from mocap.errors import InputError
from mocap.gaps import find_gaps
from mocap.stabilize import stabilize
from mocap.take import Take, as_take
from mocap.util.arrays import read_only
from mocap.util.order_statistics import nan_column_medians
from mocap.util.validation import as_int, as_positive_float

__all__ = ["REASONS", "ImplausibleRun", "ImplausibleSamples",
           "find_implausible_samples", "remove_implausible_samples"]

#: Why a sample is implausible, in order of precedence: a sample that meets
#: several rules is reported under the first.
REASONS = ("duplicate", "ghost-slide", "teleport", "off-rest")

#: Floor of a marker's typical distance from its rest position, mm (below any
#: optical capture noise), so that a marker that never moves does not make
#: every noise excursion "off rest".
_MIN_SPREAD_MM = 0.1

#: Frames per chunk of the pairwise (frames, M, M) distance test.
_CHUNK_PAIRS = 1 << 22


@dataclass(frozen=True)
class ImplausibleRun:
    """A run of consecutive implausible samples of one marker, one reason.

    Attributes
    ----------
    marker : str
        Label of the marker.
    start, stop : int
        Frame indices (0-based) of the run, `stop` excluded.
    reason : str
        One of :data:`REASONS`.
    """

    marker: str
    start: int
    stop: int
    reason: str


@dataclass(frozen=True, eq=False)
class ImplausibleSamples:
    """Outcome of :func:`find_implausible_samples`.

    Attributes
    ----------
    mask : ndarray of bool, shape (n_frames, n_markers)
        True for an implausible sample (read-only).
    runs : tuple of ImplausibleRun
        The flagged samples as runs, ordered by start frame then marker.
    labels : tuple of str
        Marker labels of the take, one per column of `mask`.
    message : str
        One-line summary.
    """

    mask: np.ndarray
    runs: tuple
    labels: tuple
    message: str

    @property
    def n_flagged(self) -> int:
        """Number of flagged samples."""
        return int(self.mask.sum())


def _runs_of(mask: np.ndarray):
    """Runs of True per marker: arrays (marker, start, stop)."""
    runs = find_gaps(mask)
    return runs.marker, runs.start, runs.stop


def _window_any(flags: np.ndarray, marker, start, stop) -> np.ndarray:
    """Whether ``flags[start[i]:stop[i], marker[i]]`` holds a True, for arrays of runs (i)."""
    csum = np.concatenate([np.zeros((1, flags.shape[1]), np.int64),
                           np.cumsum(flags, axis=0)])
    return csum[stop, marker] - csum[start, marker] > 0


def _duplicates(pos, rest, z, *, near_mm, apart_mm):
    """Samples that share their place with another label whose rest is far away.

    Of each such pair, the label farther from its own rest (in units of its
    spread) is flagged; shape (n_frames, n_markers).
    """
    n_frames, n_markers = pos.shape[:2]
    apart = np.linalg.norm(rest[:, None] - rest[None], axis=2) >= apart_mm
    out = np.zeros((n_frames, n_markers), dtype=bool)
    chunk = max(1, _CHUNK_PAIRS // max(1, n_markers * n_markers))
    with np.errstate(invalid="ignore"):
        for lo in range(0, n_frames, chunk):
            p, zz = pos[lo:lo + chunk], z[lo:lo + chunk]
            close = np.linalg.norm(p[:, :, None] - p[:, None], axis=3) <= near_mm
            close &= apart
            out[lo:lo + chunk] = (close & (zz[:, :, None] >= zz[:, None])).any(axis=2)
    return out


def _teleports(pos, misplaced, typical, *, factor, max_gap):
    """Samples from a jump onto a misplaced sample up to the jump back.

    A jump is a move of more than ``factor * typical`` from the marker's last
    visible sample (at most `max_gap` frames back). A jump landing on a
    misplaced sample opens an interval; the next jump landing on a plausible
    sample closes it (that sample is plausible); with no such jump before the
    marker's next gap longer than `max_gap`, the interval ends there.
    """
    n_frames, n_markers = pos.shape[:2]
    prev, last = last_visible(pos)
    frame = np.arange(1, n_frames)[:, None]
    with np.errstate(invalid="ignore"):
        jump = np.linalg.norm(pos[1:] - prev, axis=2) > factor * typical
    jump &= (last >= 0) & (frame - last <= max_gap + 1)
    jump = np.vstack([np.zeros((1, n_markers), bool), jump])
    visible = ~np.isnan(pos[:, :, 0])
    out_t, out_m = np.nonzero(jump & misplaced)
    back = jump & visible & ~misplaced
    long_gaps = long_gap_starts(~visible, max_gap)
    flags = np.zeros((n_frames, n_markers), dtype=bool)
    for t0, m in zip(out_t, out_m):       # one iteration per event, not per frame
        ends = np.concatenate([np.flatnonzero(back[t0 + 1:, m]) + t0 + 1,
                               long_gaps[m][long_gaps[m] > t0], [n_frames]])
        flags[t0:ends.min(), m] = True
    return flags & visible


def _ghost_slides(pos, typical, anchored, *, speed, linear, min_frames):
    """Runs of at least `min_frames` samples moving in a straight line at constant
    velocity, faster than ``speed * typical``, next to an `anchored` sample."""
    n_frames, n_markers = pos.shape[:2]
    step = np.diff(pos, axis=0)
    vel = np.linalg.norm(step, axis=2)
    acc = np.linalg.norm(np.diff(step, axis=0), axis=2)
    noise = 3.0 * np.nan_to_num(nan_column_medians(acc), nan=0.0)
    v_in, v_out = vel[:-1], vel[1:]
    with np.errstate(invalid="ignore"):
        line = ((np.fmin(v_in, v_out) > speed * typical)
                & (acc <= linear * 0.5 * (v_in + v_out) + noise))
    line = np.vstack([np.zeros((1, n_markers), bool), line,
                      np.zeros((1, n_markers), bool)])
    m, start, stop = _runs_of(line)
    near = _window_any(anchored, m, np.maximum(start - 1, 0), np.minimum(stop + 1, n_frames))
    keep = (stop - start >= min_frames) & near
    flags = np.zeros((n_frames, n_markers), dtype=bool)
    for mm, a, b in zip(m[keep], start[keep], stop[keep]):   # one per run
        flags[a:b, mm] = True
    return flags


def find_implausible_samples(take: Take, *, head=None, off_rest: float = 25.0,
                             teleport: float = 30.0, duplicate_mm: float = 2.0,
                             duplicate_apart_mm: float = 20.0, slide_speed: float = 10.0,
                             linear: float = 0.15, min_slide: int = 8,
                             max_gap: int = 25) -> ImplausibleSamples:
    """Flag samples that cannot be a real marker: teleports, duplicates, ghost slides.

    Parameters
    ----------
    take : Take
        Positions (n_frames, n_markers, 3), mm, NaN where missing. Not modified.
    head : sequence of str, optional
        Head markers: when given, the rules work in the head frame
        (``mocap.stabilize.stabilize(take, head).take``), where each face
        marker has a compact rest region. Else in the capture frame, where
        "off rest" loses its meaning once the head moves more than the face.
    off_rest : float
        A sample is *off rest* when its distance from the marker's rest
        position (median over frames of each coordinate) exceeds `off_rest`
        times the marker's spread (median of that distance, at least 0.1 mm).
    teleport : float
        A *jump* moves more than `teleport` times the marker's typical step
        (median frame-to-frame motion, at least 0.05 mm) from its last visible
        sample (at most `max_gap` frames back).
    duplicate_mm, duplicate_apart_mm : float
        Two labels within `duplicate_mm` of each other whose rest positions are
        at least `duplicate_apart_mm` apart are one marker with two labels.
    slide_speed, linear : float
        A ghost-slide sample moves faster than `slide_speed` times the typical
        step on both sides, with a second difference at most `linear` times
        that speed plus three times the marker's median second difference (the
        noise).
    min_slide : int
        Shortest ghost slide, frames (at least 3).
    max_gap : int
        Longest gap a jump is measured across; a longer gap also ends a
        teleport whose jump back was not seen.

    Returns
    -------
    ImplausibleSamples
        Mask, runs with reasons, summary.

    Raises
    ------
    InputError
        `take` not a Take, `head` a single string, an option out of range.
    MarkerError
        A head marker is not in the take (from :func:`mocap.stabilize.stabilize`).

    Notes
    -----
    With ``x_m(t)`` the position, ``r_m`` the rest position, ``z_m(t) =
    |x_m(t) - r_m| / spread_m`` and ``s_m`` the typical step, vectorized over
    frames and markers:

    - **off-rest**: ``z_m(t) > off_rest``.
    - **duplicate**: ``|x_i(t) - x_j(t)| <= duplicate_mm`` and ``|r_i - r_j| >=
      duplicate_apart_mm``; the label with the larger ``z`` is flagged (both
      if equal). Off-rest and duplicate samples are *misplaced*.
    - **teleport**: a jump (``> teleport * s_m``) landing on a misplaced
      sample, and every sample after it up to the next jump that lands on a
      plausible sample (or the next gap longer than `max_gap`, or the end).
    - **ghost-slide**: at least `min_slide` consecutive samples whose steps in
      and out exceed ``slide_speed * s_m`` and whose second difference is at
      noise level (``<= linear * speed + 3 * median second difference``):
      a straight line at constant speed, which real skin markers do not keep
      for long at such speeds. Only runs touching (or next to) a misplaced or
      teleport sample are flagged: an interpolated ghost leads somewhere
      implausible.

    A genuine fast move (jaw, blink) is neither far from the marker's rest
    region by 25 spreads nor on another marker, and accelerates.

    NaN policy: missing samples are never flagged; they break runs and are
    bridged only by the jump rule (up to `max_gap` frames). In the head frame,
    frames without a head fit are missing.

    Examples
    --------
    >>> import numpy as np
    >>> from mocap import Take
    >>> rng = np.random.default_rng(0)
    >>> pos = np.array([[0.0, 0, 0], [40, 0, 0]]) + rng.normal(0, 0.2, (100, 2, 3))
    >>> pos[50:55, 0] = pos[50:55, 1]          # label "a" sits on marker "b"
    >>> found = find_implausible_samples(Take(("a", "b"), pos, rate=100.0))
    >>> [(r.marker, r.start, r.stop, r.reason) for r in found.runs]
    [('a', 50, 55, 'duplicate')]
    """
    take = as_take(take)
    if isinstance(head, str):
        raise InputError(f"head must be a sequence of marker labels, got the string {head!r}")
    off_rest = as_positive_float(off_rest, "off_rest")
    teleport = as_positive_float(teleport, "teleport")
    duplicate_mm = as_positive_float(duplicate_mm, "duplicate_mm")
    duplicate_apart_mm = as_positive_float(duplicate_apart_mm, "duplicate_apart_mm")
    if duplicate_apart_mm <= duplicate_mm:
        raise InputError(f"duplicate_apart_mm ({duplicate_apart_mm}) must exceed "
                         f"duplicate_mm ({duplicate_mm})")
    slide_speed = as_positive_float(slide_speed, "slide_speed")
    linear = as_positive_float(linear, "linear")
    min_slide = as_int(min_slide, "min_slide", minimum=3)
    max_gap = as_int(max_gap, "max_gap", minimum=0)

    pos = take.positions if head is None else stabilize(take, list(head)).take.positions
    n_frames, n_markers = pos.shape[:2]
    codes = np.zeros((n_frames, n_markers), dtype=np.int8)
    if n_frames >= 3:
        rest = nan_column_medians(pos)
        dist = np.linalg.norm(pos - rest, axis=2)
        spread = np.fmax(np.nan_to_num(nan_column_medians(dist), nan=0.0), _MIN_SPREAD_MM)
        z = dist / spread
        typical = typical_step(pos)
        with np.errstate(invalid="ignore"):
            off = z > off_rest
        dup = _duplicates(pos, rest, z, near_mm=duplicate_mm, apart_mm=duplicate_apart_mm)
        tele = _teleports(pos, off | dup, typical, factor=teleport, max_gap=max_gap)
        ghost = _ghost_slides(pos, typical, off | dup | tele, speed=slide_speed,
                              linear=linear, min_frames=min_slide)
        for code, flags in reversed(list(enumerate((dup, ghost, tele, off), start=1))):
            codes[flags] = code
    runs = []
    for code, reason in enumerate(REASONS, start=1):
        m, start, stop = _runs_of(codes == code)
        runs += [ImplausibleRun(take.labels[i], int(a), int(b), reason)
                 for i, a, b in zip(m, start, stop)]
    runs.sort(key=lambda r: (r.start, take.labels.index(r.marker)))
    mask = codes > 0
    n_flagged = int(mask.sum())
    counts = ", ".join(f"{reason} {int((codes == c).sum())}"
                       for c, reason in enumerate(REASONS, start=1) if (codes == c).any())
    message = (f"{n_flagged} implausible samples in {len(runs)} runs"
               + (f" ({counts})" if counts else "")
               + f", {'head' if head is not None else 'capture'} frame")
    return ImplausibleSamples(mask=read_only(mask), runs=tuple(runs), labels=take.labels,
                              message=message)


def remove_implausible_samples(take: Take, found: ImplausibleSamples) -> Take:
    """Set the flagged samples to NaN, ready for :func:`mocap.clean.fill_gaps`.

    Parameters
    ----------
    take : Take
        The take `found` was computed on, (n_frames, n_markers, 3), mm. Not modified.
    found : ImplausibleSamples
        From :func:`find_implausible_samples`.

    Returns
    -------
    Take
        A new take with the flagged samples NaN and their ``filled`` code 0;
        everything else carried over.

    Raises
    ------
    InputError
        `take` not a Take, `found` not an ImplausibleSamples, or made for a take
        with other labels or another number of frames.

    Notes
    -----
    NaN policy: adds NaN; samples already missing stay missing.
    """
    take = as_take(take)
    if not isinstance(found, ImplausibleSamples):
        raise InputError(f"found must be an ImplausibleSamples, got {type(found).__name__}")
    if tuple(found.labels) != take.labels or found.mask.shape != take.positions.shape[:2]:
        raise InputError(f"found was made for a take of {found.mask.shape[0]} frames and "
                         f"markers {list(found.labels)}; this take has {take.n_frames} "
                         f"frames and markers {list(take.labels)}")
    positions = take.positions.copy()
    filled = take.filled.copy()
    positions[found.mask] = np.nan
    filled[found.mask] = 0
    return take.replace(positions=read_only(positions), filled=read_only(filled))
