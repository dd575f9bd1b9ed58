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

__all__ = ["Performance", "read_performance", "resample_performance", "match_shape_names",
           "performance_weights", "TIME_COLUMNS", "NON_WEIGHT_COLUMNS"]

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

_TIMECODE = re.compile(r"^(\d+):(\d{2}):(\d{2})[:;](\d+(?:\.\d*)?)$")
_SIDE = re.compile(r"(?:_([LlRr])|_?([Ll]eft|[Rr]ight))$")


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
        Weights as recorded (not clipped: ARKit weights may exceed 1).
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
        weights = as_float_array(self.weights, "weights", shape=(len(times), len(names)),
                                 allow_nan=False)
        if len(times) == 0:
            raise InputError("a performance needs at least one sample")
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
        Times from the first sample, s; weights as recorded.

    Raises
    ------
    FileFormatError
        Unreadable or empty file, no time column, a malformed timecode or
        time, times not strictly increasing (the line is named), no weight
        column, or an empty or non-numeric weight cell.

    Notes
    -----
    Dropped frames are kept where they are in time: a sample's time is read
    from its own timecode, so a missing row is a longer step, not a shift.
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
    names, ignored, values = [], [], []
    for j, name in enumerate(columns):
        if name == time_col:
            continue
        column = table.iloc[:, j].to_numpy()
        if name.lower() in NON_WEIGHT_COLUMNS or pd.to_numeric(
                pd.Series(column), errors="coerce").isna().all():
            ignored.append(name)
            continue
        names.append(name)
        values.append(_numbers(path, column, name))
    if not names:
        raise FileFormatError(path, f"no weight column besides the time column {time_col!r}")
    rate = 1.0 / float(np.median(steps)) if len(steps) else 1.0
    return Performance(tuple(names), times - times[0], np.stack(values, axis=1), rate,
                       ignored=tuple(ignored), path=str(path))


def _numbers(path, cells, column: str) -> np.ndarray:
    """Floats of one column's cells, FileFormatError naming the first bad cell's line."""
    import pandas as pd

    out = pd.to_numeric(pd.Series(cells), errors="coerce").to_numpy(dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(out))
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
        ``times`` from 0 (``start`` maps to 0), ``rate`` the new rate.

    Raises
    ------
    InputError
        `start` outside the performance, a duration that is not positive.
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
        frac = ((grid - times[left]) / (times[right] - times[left]))[:, None]
        weights = (1 - frac) * performance.weights[left] + frac * performance.weights[right]
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
        0 for a shape that no column drives.

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
    return weights
