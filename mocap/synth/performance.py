"""Weight performances: per-frame blendshape weights read from a CSV file.

A performance file is a CSV table with one time column and one column per
shape, e.g. a Live Link Face export (``Timecode`` as ``HH:MM:SS:FF.fff`` on a
60 fps base, ~30 samples per second with a few dropped frames, 52 ARKit
weights in PascalCase like ``JawOpen``, ``EyeBlinkLeft``)::

    Timecode,BlendShapeCount,EyeBlinkLeft,...,JawOpen,...,HeadYaw,...
    13:13:04:31.652,61,0.1236,...,0.0191,...,0.0,...

Times come from the time column, never from the row index, so dropped frames
keep their place in time. :func:`resample_performance` puts the weights on a
uniform grid and :func:`performance_weights` maps the columns onto the shape
names of a basis (``EyeBlinkLeft`` -> ``eyeBlink_L``; one ``BrowInnerUp``
column drives both ``browInnerUp_L`` and ``browInnerUp_R``).

Rows where the phone lost the face (``16:48:52:29.134,0``: a BlendShapeCount of
0 and no values, for seconds at a time in real exports) are samples with every
weight NaN: gaps, reported with their spans (:meth:`Performance.gaps`, and a
warning when read), carried through resampling as NaN, and filled only when
asked (:func:`mocap.synth.performance_gaps.fill_tracking_gaps`).
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocap.errors import FileFormatError, InputError
from mocap.util.arrays import read_only
from mocap.util.validation import as_float_array, as_positive_float

__all__ = ["Performance", "TrackingGap", "read_performance", "resample_performance",
           "match_shape_names", "performance_weights", "TIME_COLUMNS", "NON_WEIGHT_COLUMNS"]

#: Time column names (case-insensitive) and how they are read: ``"timecode"``
#: is ``HH:MM:SS:FF[.fff]`` at ``timecode_rate`` frames per second, ``"seconds"``
#: a number of seconds.
TIME_COLUMNS = {"timecode": "timecode", "time": "seconds", "time_s": "seconds",
                "seconds": "seconds", "t": "seconds"}
#: Columns of Live Link Face exports that are not shape weights (case-insensitive):
#: kept out of :attr:`Performance.names` and listed in :attr:`Performance.ignored`.
NON_WEIGHT_COLUMNS = ("blendshapecount", "headyaw", "headpitch", "headroll", "lefteyeyaw",
                      "lefteyepitch", "lefteyeroll", "righteyeyaw", "righteyepitch",
                      "righteyeroll")

#: The Live Link Face column counting the shapes tracked in a row: 0 when the face was lost.
COUNT_COLUMN = "blendshapecount"

_TIMECODE = re.compile(r"^(\d+):(\d{2}):(\d{2})[:;](\d+(?:\.\d*)?)$")
_SIDE = re.compile(r"(?:_([LlRr])|_?([Ll]eft|[Rr]ight))$")


@dataclass(frozen=True)
class TrackingGap:
    """A run of samples where tracking was lost (every weight NaN).

    Attributes
    ----------
    start, stop : int
        Sample indices, stop exclusive.
    start_time : float, s
        Time of the first lost sample.
    end_time : float, s
        Time of the first tracked sample after the run (the last lost
        sample's time plus one nominal step when the run ends the performance).
    """

    start: int
    stop: int
    start_time: float
    end_time: float

    @property
    def n_samples(self) -> int:
        """Samples lost."""
        return self.stop - self.start

    @property
    def duration(self) -> float:
        """Time without tracking, s: ``end_time - start_time``."""
        return self.end_time - self.start_time


@dataclass(frozen=True, eq=False)
class Performance:
    """Per-frame shape weights over time.

    Attributes
    ----------
    names : tuple of str
        Weight column names, n of them, as in the file.
    times : ndarray of shape (T,), s
        Sample times, strictly increasing (from 0 for a performance read or
        resampled here).
    weights : ndarray of shape (T, n)
        Weights as recorded (not clipped: ARKit weights may exceed 1); a row
        of NaN where tracking was lost (a row is all NaN or all finite).
    rate : float, Hz
        The grid rate for a resampled performance; for one read from a file,
        the nominal rate ``1 / median(diff(times))``.
    ignored : tuple of str
        Columns of the file that are neither the time nor a weight.
    path : str or None
        The file read.
    """

    names: tuple
    times: np.ndarray
    weights: np.ndarray
    rate: float
    ignored: tuple = ()
    path: str | None = None

    def __post_init__(self):
        names = tuple(str(n) for n in self.names)
        times = as_float_array(self.times, "times", ndim=1, allow_nan=False)
        weights = as_float_array(self.weights, "weights", shape=(len(times), len(names)))
        if len(times) == 0:
            raise InputError("a performance needs at least one sample")
        lost = np.isnan(weights)
        partly = np.flatnonzero(lost.any(axis=1) & ~lost.all(axis=1))
        if len(partly):
            raise InputError(f"weights of sample {partly[0]} are partly NaN: a sample is "
                             "either tracked (every weight a number) or lost (every weight NaN)")
        if lost.all():
            raise InputError("every sample of the performance is lost (NaN): nothing to play")
        if np.any(np.diff(times) <= 0):
            raise InputError("performance times must be strictly increasing")
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "times", read_only(times))
        object.__setattr__(self, "weights", read_only(weights))
        object.__setattr__(self, "rate", as_positive_float(self.rate, "rate"))
        object.__setattr__(self, "ignored", tuple(self.ignored))

    @property
    def n_frames(self) -> int:
        """Number of samples T."""
        return len(self.times)

    @property
    def duration(self) -> float:
        """Time from the first to the last sample, s."""
        return float(self.times[-1] - self.times[0])

    @property
    def lost(self) -> np.ndarray:
        """Samples where tracking was lost (weights NaN), bool of shape (T,)."""
        return np.isnan(self.weights[:, 0]) if self.weights.shape[1] else \
            np.zeros(self.n_frames, dtype=bool)

    def gaps(self) -> tuple:
        """The runs of lost samples, in time order: a tuple of :class:`TrackingGap`.

        Examples
        --------
        >>> w = np.array([[0.1], [np.nan], [np.nan], [0.4]])
        >>> Performance(("JawOpen",), [0.0, 0.5, 1.0, 1.5], w, 2.0).gaps()
        (TrackingGap(start=1, stop=3, start_time=0.5, end_time=1.5),)
        """
        edges = np.diff(np.concatenate([[0], self.lost.astype(np.int8), [0]]))
        starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        times = self.times
        return tuple(TrackingGap(int(a), int(b), float(times[a]),
                                 float(times[b]) if b < len(times) else
                                 float(times[-1] + 1.0 / self.rate))
                     for a, b in zip(starts, stops))


def _timecode_seconds(path, cells, timecode_rate: float) -> np.ndarray:
    """Seconds of ``HH:MM:SS:FF.fff`` strings (T,), frames at `timecode_rate`."""
    import pandas as pd

    fields = pd.Series(cells, dtype=str).str.strip().str.extract(_TIMECODE)
    fields = fields.astype(np.float64).to_numpy()
    bad = np.flatnonzero(np.isnan(fields).any(axis=1))
    if len(bad):
        raise FileFormatError(path, f"timecode {cells[bad[0]]!r} is not HH:MM:SS:FF[.fff]",
                              line=int(bad[0]) + 2)
    late = np.flatnonzero(fields[:, 3] >= timecode_rate)
    if len(late):
        raise FileFormatError(path, f"timecode {cells[late[0]]!r} counts {fields[late[0], 3]:g} "
                                    f"frames, not below the {timecode_rate:g} fps base",
                              line=int(late[0]) + 2)
    return fields[:, 0] * 3600 + fields[:, 1] * 60 + fields[:, 2] + fields[:, 3] / timecode_rate


def read_performance(path, *, timecode_rate: float = 60.0) -> Performance:
    """Read a weight performance from a CSV file.

    Parameters
    ----------
    path : str or os.PathLike
        CSV with a header row: one time column (see :data:`TIME_COLUMNS`) and
        numeric weight columns. Columns of :data:`NON_WEIGHT_COLUMNS` and
        non-numeric columns are ignored (listed in ``Performance.ignored``).
    timecode_rate : float, default 60
        Frame rate of the timecode's frame field (Live Link Face: 60).

    Returns
    -------
    Performance
        Times from the first sample, s; weights as recorded, NaN in the rows
        where tracking was lost.

    Raises
    ------
    FileFormatError
        Unreadable or empty file, no time column, a malformed timecode or
        time, times not strictly increasing (the line is named), no weight
        column, an empty or non-numeric weight cell in a tracked row, or no
        tracked row at all.

    Warns
    -----
    UserWarning
        Rows where tracking was lost: how many, in how many runs, and the
        longest (samples, lines, times).

    Notes
    -----
    Dropped frames are kept where they are in time: a sample's time is read
    from its own timecode, so a missing row is a longer step, not a shift.
    A row is lost when its ``BlendShapeCount`` is 0 or every weight cell is
    empty (Live Link Face writes ``16:48:52:29.134,0``); it keeps its time.
    """
    import pandas as pd

    path = Path(path)
    timecode_rate = as_positive_float(timecode_rate, "timecode_rate")
    try:
        table = pd.read_csv(path, dtype=str, keep_default_na=False, skipinitialspace=True)
    except FileNotFoundError:
        raise FileFormatError(path, "no such file") from None
    except (OSError, UnicodeDecodeError, pd.errors.ParserError,
            pd.errors.EmptyDataError) as exc:
        raise FileFormatError(path, f"cannot read performance CSV: {exc}") from None
    if len(table) == 0:
        raise FileFormatError(path, "no samples below the header")
    columns = [str(c).strip() for c in table.columns]
    time_cols = [c for c in columns if c.lower() in TIME_COLUMNS]
    if len(time_cols) != 1:
        raise FileFormatError(path, f"needs exactly one time column among "
                                    f"{sorted(TIME_COLUMNS)} (any case), found {time_cols}",
                              line=1)
    time_col = time_cols[0]
    cells = table.iloc[:, columns.index(time_col)].to_numpy()
    if TIME_COLUMNS[time_col.lower()] == "timecode":
        times = _timecode_seconds(path, cells, timecode_rate)
    else:
        times = _numbers(path, cells, time_col)
    steps = np.diff(times)
    back = np.flatnonzero(steps <= 0)
    if len(back):
        raise FileFormatError(path, f"time {cells[back[0] + 1]!r} does not follow "
                                    f"{cells[back[0]]!r}: times must increase", line=back[0] + 3)
    candidates = [j for j, name in enumerate(columns)
                  if name != time_col and name.lower() not in NON_WEIGHT_COLUMNS]
    cells = table.iloc[:, candidates].to_numpy(dtype=str)
    lost = (np.char.strip(cells) == "").all(axis=1) if candidates else \
        np.zeros(len(table), dtype=bool)
    counts = [j for j, name in enumerate(columns) if name.lower() == COUNT_COLUMN]
    if counts:
        count = pd.to_numeric(table.iloc[:, counts[0]], errors="coerce").to_numpy()
        lost |= count == 0
    if lost.all():
        raise FileFormatError(path, f"tracking was lost in every one of its {len(lost)} rows "
                                    "(no weights): nothing to play")
    names, ignored, values = [], [], []
    for j, name in enumerate(columns):
        if name == time_col:
            continue
        column = table.iloc[:, j].to_numpy()
        if name.lower() in NON_WEIGHT_COLUMNS or pd.to_numeric(
                pd.Series(column[~lost]), errors="coerce").isna().all():
            ignored.append(name)
            continue
        names.append(name)
        values.append(_numbers(path, column, name, lost))
    if not names:
        raise FileFormatError(path, f"no weight column besides the time column {time_col!r}")
    tracked = np.diff(times[~lost]) if (~lost).sum() > 1 else steps
    rate = 1.0 / float(np.median(tracked)) if len(tracked) else 1.0
    performance = Performance(tuple(names), times - times[0], np.stack(values, axis=1), rate,
                              ignored=tuple(ignored), path=str(path))
    if lost.any():
        warnings.warn(_lost_notice(performance, cells=table.iloc[:, columns.index(time_col)]
                                   .to_numpy()), UserWarning, stacklevel=2)
    return performance


def _lost_notice(performance: Performance, *, cells) -> str:
    """One sentence on the rows where tracking was lost (file lines are sample + 2)."""
    gaps = performance.gaps()
    worst = max(gaps, key=lambda g: g.duration)
    total = sum(g.n_samples for g in gaps)
    return (f"{performance.path}: tracking was lost in {total} of {performance.n_frames} "
            f"samples, {len(gaps)} run(s) ({sum(g.duration for g in gaps):.2f} s in all); the "
            f"longest {worst.duration:.2f} s, samples {worst.start}-{worst.stop - 1} (lines "
            f"{worst.start + 2}-{worst.stop + 1}, from {cells[worst.start]!s} at "
            f"{worst.start_time:.3f} s): left as gaps (NaN weights), filled only when asked")


def _numbers(path, cells, column: str, lost=None) -> np.ndarray:
    """Floats of one column's cells, NaN in the `lost` rows; FileFormatError naming the first
    bad cell's line."""
    import pandas as pd

    out = pd.to_numeric(pd.Series(cells), errors="coerce").to_numpy(dtype=np.float64, copy=True)
    if lost is not None:
        out[lost] = np.nan
    bad = np.flatnonzero(~np.isfinite(out) & (True if lost is None else ~lost))
    if len(bad):
        raise FileFormatError(path, f"column {column!r}: {cells[bad[0]]!r} is not a finite "
                                    "number", line=int(bad[0]) + 2)
    return out


def resample_performance(performance: Performance, rate: float, *, start: float = 0.0,
                         duration: float | None = None) -> Performance:
    """Weights on a uniform time grid, by linear interpolation.

    Parameters
    ----------
    performance : Performance
    rate : float, Hz
        The new sampling rate.
    start : float, default 0, s
        Time of the first grid sample, counted from the performance's first
        sample (``performance.times[0]``).
    duration : float, optional, s
        Length of the grid (default: up to the last sample). The grid is
        ``start + k / rate`` for every k with a time within the performance.

    Returns
    -------
    Performance
        ``times`` from 0 (``start`` maps to 0), ``rate`` the new rate. A grid
        point between a lost sample and its neighbour is lost (NaN): gaps
        are kept, never bridged.

    Raises
    ------
    InputError
        `start` outside the performance, a duration that is not positive,
        a grid on which every sample is lost.
    """
    if not isinstance(performance, Performance):
        raise InputError(f"performance must be a Performance, got {type(performance).__name__}")
    rate = as_positive_float(rate, "rate")
    start = float(as_float_array(start, "start", ndim=0, allow_nan=False))
    times = performance.times - performance.times[0]
    end = times[-1]
    if not 0 <= start <= end:
        raise InputError(f"start must be within the performance's 0-{end:.3f} s, got {start}")
    if duration is not None:
        end = min(end, start + as_positive_float(duration, "duration"))
    # a rounding allowance keeps a grid point that falls exactly on the last sample
    grid = start + np.arange(int(np.floor((end - start) * rate + 1e-9)) + 1) / rate
    grid = np.minimum(grid, end)
    right = np.clip(np.searchsorted(times, grid, side="right"), 1, max(len(times) - 1, 1))
    left = right - 1
    if len(times) == 1:
        weights = np.repeat(performance.weights, len(grid), axis=0)
    else:
        w = performance.weights
        frac = ((grid - times[left]) / (times[right] - times[left]))[:, None]
        # on a sample, its own value: a lost neighbour must not make it NaN (0 * NaN)
        weights = np.where(frac == 0, w[left], np.where(frac == 1, w[right],
                                                        (1 - frac) * w[left] + frac * w[right]))
    if np.isnan(weights).all():
        raise InputError(f"{performance.path or 'performance'}: tracking is lost over the "
                         f"whole of {start:.3f}-{end:.3f} s")
    return Performance(performance.names, grid - start, weights, rate,
                       ignored=performance.ignored, path=performance.path)


def _key(name: str) -> str:
    """Case-free name with a trailing side as ``_l``/``_r`` (``EyeBlinkLeft`` -> ``eyeblink_l``)."""
    name = str(name).strip()
    side = _SIDE.search(name)
    if side and side.start() > 0:
        return name[:side.start()].lower() + "_" + (side.group(1) or side.group(2))[0].lower()
    return name.lower()


def match_shape_names(columns, shapes) -> dict[str, int]:
    """Which performance column drives each basis shape.

    Parameters
    ----------
    columns : sequence of str
        Performance weight names (``JawOpen``, ``EyeBlinkLeft``, ``BrowInnerUp``).
    shapes : sequence of str
        Basis shape names (``jawOpen``, ``eyeBlink_L``, ``browInnerUp_L``).

    Returns
    -------
    dict of str to int
        Shape name to column index, for the shapes that a column drives.

    Notes
    -----
    Names match case-insensitively, with a trailing ``Left``/``Right``,
    ``_L``/``_R`` or ``L``/``R`` read as the side. A column without a side
    drives both sides of a shape that the basis splits (``BrowInnerUp`` ->
    ``browInnerUp_L`` and ``browInnerUp_R``) when no unsided shape exists.
    """
    by_key = {}
    for j, column in enumerate(columns):
        by_key.setdefault(_key(column), j)
    shape_keys = {_key(shape) for shape in shapes}
    out = {}
    for shape in shapes:
        key = _key(shape)
        if key in by_key:
            out[shape] = by_key[key]
        elif key[-2:] in ("_l", "_r") and key[:-2] in by_key and key[:-2] not in shape_keys:
            out[shape] = by_key[key[:-2]]
    return out


def performance_weights(performance: Performance, shapes) -> np.ndarray:
    """A performance's weights in the order of a basis' shapes.

    Parameters
    ----------
    performance : Performance
    shapes : sequence of str
        Basis shape names, n_basis of them.

    Returns
    -------
    ndarray of shape (T, n_basis)
        The driving column's weight for each shape (:func:`match_shape_names`),
        0 for a shape that no column drives; a row of NaN where tracking was lost.

    Raises
    ------
    InputError
        No column drives any shape (names the file).

    Warns
    -----
    UserWarning
        Weight columns that drive no shape, and shapes that no column drives (named).
    """
    if not isinstance(performance, Performance):
        raise InputError(f"performance must be a Performance, got {type(performance).__name__}")
    shapes = [str(s) for s in shapes]
    matched = match_shape_names(performance.names, shapes)
    where = performance.path or "performance"
    if not matched:
        raise InputError(f"{where}: none of its weight columns ({', '.join(performance.names)}) "
                         f"matches a shape of the basis ({', '.join(shapes)})")
    unused = sorted(set(performance.names) - {performance.names[j] for j in matched.values()})
    idle = [s for s in shapes if s not in matched]
    if unused:
        warnings.warn(f"{where}: {len(unused)} weight columns match no shape of the basis: "
                      f"{', '.join(unused)}", stacklevel=2)
    if idle:
        warnings.warn(f"{where}: {len(idle)} shapes of the basis have no weight column "
                      f"(held at 0): {', '.join(idle)}", stacklevel=2)
    weights = np.zeros((performance.n_frames, len(shapes)))
    cols = [shapes.index(s) for s in matched]
    weights[:, cols] = performance.weights[:, list(matched.values())]
    weights[performance.lost] = np.nan
    return weights
