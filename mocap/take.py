"""The Take: one capture's marker tracks, in millimetres, NaN where missing."""

from __future__ import annotations

import contextvars
import copy
import dataclasses
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from mocap.errors import InputError, MarkerError
from mocap.util.arrays import read_only
from mocap.util.validation import as_float_array, as_int, as_positive_float

__all__ = ["Take", "SourceInfo", "Analog", "FILL_METHODS", "fill_code", "as_take",
           "take_of_checked_samples"]

#: Gap-filling methods a sample can have been filled by. ``Take.filled`` holds
#: 0 for a sample that was captured (or is still missing) and ``i + 1`` for a
#: sample filled by ``FILL_METHODS[i]``.
FILL_METHODS = ("spline", "rigid", "pca")


def fill_code(method: str) -> int:
    """The code that ``Take.filled`` stores for a fill `method`."""
    if method not in FILL_METHODS:
        raise InputError(f"fill method must be one of {FILL_METHODS}, got {method!r}")
    return FILL_METHODS.index(method) + 1


@dataclass(frozen=True)
class SourceInfo:
    """Where a take came from and how it was encoded.

    Attributes
    ----------
    path : str or None
        The file read, or None for a take made in memory.
    format : str
        ``"c3d"``, ``"vicon-csv"``, ``"trc"``, ``"npz"`` or ``"memory"``.
    units : str
        Length unit as found in the file (positions are always converted to mm).
    producer : str
        The software or system that wrote the file, when the file says.
    byte_order : str
        ``"intel"``, ``"dec"`` or ``"mips"`` for C3D; empty otherwise.
    storage : str
        ``"float"`` or ``"integer"`` for C3D; ``"text"`` for text formats.
    extra : mapping
        Anything else worth keeping (e.g. C3D header fields, subjects).
    """

    path: str | None = None
    format: str = "memory"
    units: str = "mm"
    producer: str = ""
    byte_order: str = ""
    storage: str = ""
    extra: Mapping = field(default_factory=dict)


@dataclass(frozen=True)
class Analog:
    """Analog channels recorded beside the markers (force plates, EMG, audio).

    Attributes
    ----------
    values : ndarray of shape (n_samples, n_channels)
        Scaled values, in each channel's units.
    rate : float
        Sampling rate, Hz.
    labels : tuple of str
        Channel labels, one per column.
    units : tuple of str
        Channel units, one per column (may be empty strings).
    """

    values: np.ndarray
    rate: float
    labels: tuple
    units: tuple

    def __post_init__(self):
        values = as_float_array(self.values, "analog values", ndim=2)
        object.__setattr__(self, "values", read_only(values))
        object.__setattr__(self, "rate", as_positive_float(self.rate, "analog rate"))
        labels = tuple(str(s) for s in self.labels)
        units = tuple(str(s) for s in self.units)
        n = values.shape[1]
        if len(labels) != n or len(units) != n:
            raise InputError(f"analog data has {n} channels but {len(labels)} labels "
                             f"and {len(units)} units")
        object.__setattr__(self, "labels", labels)
        object.__setattr__(self, "units", units)

    def channel(self, label: str) -> np.ndarray:
        """Samples of one channel, shape (n_samples,)."""
        try:
            return self.values[:, self.labels.index(label)].copy()
        except ValueError:
            raise InputError(f"no analog channel {label!r}; channels are "
                             f"{list(self.labels)}") from None


@dataclass(frozen=True)
class Take:
    """Marker tracks of one capture.

    Attributes
    ----------
    labels : tuple of str
        Marker labels, unique, one per marker.
    positions : ndarray of shape (n_frames, n_markers, 3), mm
        Marker positions; NaN (all three coordinates) where a marker is missing.
        Read-only: derive new takes with :meth:`replace`. A float64 array that
        is read-only down to the memory it views is kept as it is (nobody can
        change it, and a large take is not copied); anything else is copied.
    rate : float
        Frame rate, Hz.
    first_frame : int
        Frame number of the first frame, as in the source file (C3D starts at 1).
    filled : ndarray of shape (n_frames, n_markers), uint8
        0 for a captured (or still missing) sample, ``i + 1`` for a sample
        filled by ``FILL_METHODS[i]``. Kept or copied as `positions` is.
    source : SourceInfo
        Where the take came from.
    analog : Analog or None
        Analog channels, if the source had any.

    Notes
    -----
    NaN policy: a missing sample is NaN in all three coordinates, never zero.
    A sample with some but not all coordinates NaN is rejected.

    Examples
    --------
    >>> import numpy as np
    >>> take = Take(("a", "b"), np.zeros((4, 2, 3)), rate=100.0)
    >>> take.n_frames, take.n_markers, take.duration
    (4, 2, 0.04)
    """

    labels: tuple
    positions: np.ndarray
    rate: float
    first_frame: int = 1
    filled: np.ndarray | None = None
    source: SourceInfo = field(default_factory=SourceInfo)
    analog: Analog | None = None

    def __post_init__(self):
        labels = tuple(str(s) for s in self.labels)
        positions = as_float_array(self.positions, "positions", shape=(None, None, 3),
                                   copy=not _immutable(self.positions), check_finite=False)
        if len(labels) != positions.shape[1]:
            raise InputError(f"take has {positions.shape[1]} markers but "
                             f"{len(labels)} labels")
        seen = set()
        for label in labels:
            if label in seen:
                raise MarkerError(label, "label appears more than once in the take")
            seen.add(label)
        if not _SAMPLES_CHECKED.get():
            _check_samples(positions, labels)
        if self.filled is None:
            filled = np.zeros(positions.shape[:2], dtype=np.uint8)
        else:
            filled = np.asarray(self.filled)
            if filled.dtype.kind not in "biu":
                raise InputError(f"filled must hold integer fill-method codes, got "
                                 f"{filled.dtype}")
            if filled.shape != positions.shape[:2]:
                raise InputError(f"filled must have shape {positions.shape[:2]}, "
                                 f"got {filled.shape}")
            if filled.size and (filled.min() < 0 or filled.max() > len(FILL_METHODS)):
                raise InputError("filled holds an unknown fill-method code")
            filled = filled.astype(np.uint8, copy=not _immutable(filled))
        object.__setattr__(self, "labels", labels)
        object.__setattr__(self, "positions", read_only(positions))
        object.__setattr__(self, "filled", read_only(filled))
        object.__setattr__(self, "rate", as_positive_float(self.rate, "rate"))
        object.__setattr__(self, "first_frame", as_int(self.first_frame, "first_frame"))
        if not isinstance(self.source, SourceInfo):
            raise InputError("source must be a SourceInfo")
        if self.analog is not None and not isinstance(self.analog, Analog):
            raise InputError("analog must be an Analog or None")

    # -- sizes and time ---------------------------------------------------
    @property
    def n_frames(self) -> int:
        """Number of frames T."""
        return self.positions.shape[0]

    @property
    def n_markers(self) -> int:
        """Number of markers M."""
        return self.positions.shape[1]

    @property
    def duration(self) -> float:
        """Length of the take in seconds, ``n_frames / rate``."""
        return self.n_frames / self.rate

    @property
    def frames(self) -> np.ndarray:
        """Frame numbers, shape (n_frames,), starting at `first_frame`."""
        return self.first_frame + np.arange(self.n_frames)

    def frame_index(self, frame, what: str = "frame"):
        """The 0-based index of the capture's frame number `frame` (strings pass through).

        Frame numbers are the capture's own (``first_frame`` ... ``first_frame +
        n_frames - 1``), the convention of everything a user sees; `what` names
        the option in the error.

        Raises
        ------
        InputError
            `frame` is not a frame of the take.

        Examples
        --------
        >>> take = Take(("a",), np.zeros((5, 1, 3)), rate=100.0, first_frame=11)
        >>> take.frame_index(12), take.frame_index("auto")
        (1, 'auto')
        """
        if isinstance(frame, str):
            return frame
        number = as_int(frame, what)
        last = self.first_frame + self.n_frames - 1
        if not self.first_frame <= number <= last:
            raise InputError(f"{what} {number} is not a frame of the take: its frames are "
                             f"numbered {self.first_frame}..{last} (the capture's own numbers)")
        return number - self.first_frame

    @property
    def times(self) -> np.ndarray:
        """Time of each frame from the start of the take, s, shape (n_frames,)."""
        return np.arange(self.n_frames) / self.rate

    @property
    def missing(self) -> np.ndarray:
        """Boolean mask of missing samples, shape (n_frames, n_markers)."""
        return np.isnan(self.positions[:, :, 0])

    # -- markers -----------------------------------------------------------
    def index(self, label: str) -> int:
        """Column of marker `label`; raises MarkerError naming the known labels."""
        try:
            return self.labels.index(label)
        except ValueError:
            raise MarkerError(label, f"not in the take (markers: "
                                     f"{', '.join(self.labels)})") from None

    def indices(self, labels, *, distinct: bool = False) -> np.ndarray:
        """Columns of several markers, shape (len(labels),); with `distinct`, a MarkerError
        for a label given twice."""
        idx = np.array([self.index(label) for label in labels], dtype=np.intp)
        if distinct and len(np.unique(idx)) != len(idx):
            dup = next(self.labels[i] for i in idx if np.count_nonzero(idx == i) > 1)
            raise MarkerError(dup, "label appears more than once in the take")
        return idx

    def marker(self, label: str) -> np.ndarray:
        """Trajectory of one marker, a new array of shape (n_frames, 3), mm."""
        return self.positions[:, self.index(label)].copy()

    def select(self, labels) -> "Take":
        """The take with only `labels`, in that order (itself when they are all its
        markers in its order: a take is immutable).

        The columns of a valid take are valid: they are gathered, not checked
        or copied again.
        """
        idx = self.indices(labels, distinct=True)
        labels = tuple(self.labels[i] for i in idx)
        if labels == self.labels:
            return self
        selected = copy.copy(self)
        # np.take, not positions[:, idx]: a gather of whole rows, several times faster
        for name, value in (("labels", labels),
                            ("positions", read_only(np.take(self.positions, idx, axis=1))),
                            ("filled", read_only(np.take(self.filled, idx, axis=1)))):
            object.__setattr__(selected, name, value)
        return selected

    def replace(self, **changes) -> "Take":
        """A new take with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


#: Set while :func:`take_of_checked_samples` makes a take whose samples its maker checked.
_SAMPLES_CHECKED = contextvars.ContextVar("samples_checked", default=False)


def take_of_checked_samples(labels, positions, rate, **fields) -> Take:
    """``Take(labels, positions, rate, **fields)`` of `positions` whose maker has made every
    sample either finite or NaN in all three coordinates (as the C3D decoder does while
    it widens each chunk): validated as any take, but its samples not read a second time.

    For readers that guarantee it by construction; anything else makes a :class:`Take`.
    """
    token = _SAMPLES_CHECKED.set(True)
    try:
        return Take(labels, positions, rate, **fields)
    finally:
        _SAMPLES_CHECKED.reset(token)


def _check_samples(positions: np.ndarray, labels: tuple) -> None:
    """InputError for an infinite coordinate of `positions` (T, M, 3), MarkerError for a
    sample with some coordinates NaN and others not."""
    suspect, samples = _not_finite_samples(positions)
    nan = np.isnan(samples)
    partial = nan.any(axis=1) & ~nan.all(axis=1)
    if partial.any():
        t, m = (int(index[np.argmax(partial)]) for index in suspect)
        raise MarkerError(labels[m], f"frame index {t} has some coordinates NaN and "
                                     "others not; a missing sample is NaN in x, y and z")


def _not_finite_samples(positions: np.ndarray) -> tuple:
    """The samples of `positions` (T, M, 3) with a coordinate that is not finite: their
    (frame, marker) indices in C order and their (k, 3) values; InputError if one is
    infinite.

    One (T, M) sum finds them: a sum is finite exactly when its three terms are, save
    finite terms that overflow it (taken too, and found finite when looked at again).
    """
    with np.errstate(all="ignore"):     # inf - inf, overflow
        total = positions @ np.ones(3)  # a BLAS product: twice as fast as two np.add
    # flat indices, then divided: np.nonzero of a 2-D mask is ten times slower
    suspect = np.divmod(np.flatnonzero(~np.isfinite(total)), positions.shape[1])
    samples = positions[suspect]
    if np.isinf(samples).any():
        raise InputError("positions contains infinite values")
    return suspect, samples


def _immutable(arr) -> bool:
    """True when nobody can change `arr`'s data: read-only all the way down to its owner."""
    while isinstance(arr, np.ndarray):
        if arr.flags.writeable:
            return False
        arr = arr.base
    return arr is None or isinstance(arr, bytes)


def as_take(value, name: str = "take") -> Take:
    """`value` itself, checked to be a :class:`Take` (validation at a public boundary)."""
    if not isinstance(value, Take):
        raise InputError(f"{name} must be a mocap.Take, got {type(value).__name__}")
    return value
