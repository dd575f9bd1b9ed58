"""C3D files: our own vectorized reader and a float/Intel writer.

The reader handles Intel, DEC (VAX floats) and MIPS/SGI byte orders, integer
and float storage, and the ways files in the wild bend the standard (see
:func:`read_c3d`). The writer emits the plainest form every reader accepts.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from mocap.errors import FileFormatError, InputError
from mocap.io._c3d_data import decode_frames, plan_layout, scan_missing
from mocap.io._c3d_header import BLOCK, locate_parameters, parse_header
from mocap.io._c3d_params import Parameters, parse_parameters
from mocap.io._c3d_write import encode_c3d
from mocap.take import Analog, SourceInfo, Take, as_take, take_of_checked_samples
from mocap.units import mm_per_unit
from mocap.util.arrays import read_only
from mocap.util.atomic import atomic_path, preallocate
from mocap.util.budget import check_allocation
from mocap.util.files import as_path, mapped_input

__all__ = ["read_c3d", "read_c3d_parameters", "summarize_c3d", "C3DSummary", "write_c3d"]

_HEADER_RATE_OFFSET = 20


def _warn_all(path, notes) -> None:
    for note in notes:
        warnings.warn(f"{path}: {note}", stacklevel=3)


def _parse(buf: bytes, path, notes: list):
    start, order = locate_parameters(buf, path)
    header = parse_header(buf, order)
    data_offset = (header.data_block - 1) * BLOCK
    end = data_offset if start < data_offset <= len(buf) else len(buf)
    params = parse_parameters(buf, start, order, end=end)
    if params.truncated and end < len(buf):
        # the section runs past the header's data pointer: the pointer may be wrong
        params = parse_parameters(buf, start, order, end=len(buf))
    notes.extend(params.notes)
    return start, order, header, params


def _unique_labels(raw, n: int, fallback: str, what: str, notes: list) -> tuple:
    """`n` labels from `raw`: blanks get ``{fallback}{i}``, duplicates a ``_2``... suffix."""
    labels = [str(raw[i]).strip() if i < len(raw) else "" for i in range(n)]
    labels = [label or f"{fallback}{i + 1}" for i, label in enumerate(labels)]
    seen, next_suffix, renamed = set(labels), {}, []
    out = []
    used = set()
    for label in labels:
        if label in used:
            k = next_suffix.get(label, 2)
            while f"{label}_{k}" in seen or f"{label}_{k}" in used:
                k += 1
            next_suffix[label] = k + 1
            renamed.append(f"{label}->{label}_{k}")
            label = f"{label}_{k}"
        used.add(label)
        out.append(label)
    if renamed:
        shown = ", ".join(renamed[:10]) + (" ..." if len(renamed) > 10 else "")
        notes.append(f"{len(renamed)} duplicate {what} labels made unique: {shown}")
    return tuple(out)


def _positive(value) -> bool:
    return value is not None and np.isfinite(value) and value > 0


def _per_channel(values, n: int, default: float, name: str, notes: list) -> np.ndarray:
    out = np.full(n, default)
    if values is None:
        return out
    if values.size < n:
        notes.append(f"ANALOG:{name} has {values.size} values for {n} channels; "
                     f"the others use {default}")
    k = min(n, values.size)
    out[:k] = np.where(np.isfinite(values[:k]), values[:k], default)
    return out


def _analog_meta(params: Parameters, layout, point_rate: float, notes: list):
    """(rate, labels, units) of the analog channels."""
    n = layout.n_channels
    rate = params.number("ANALOG", "RATE")
    if not _positive(rate):
        rate = point_rate * layout.analog_per_frame
    labels = _unique_labels(params.string_series("ANALOG", "LABELS"), n, "analog", "analog",
                            notes)
    units = params.string_series("ANALOG", "UNITS")
    return rate, labels, tuple(units[i] if i < len(units) else "" for i in range(n))


def _analog(raw: np.ndarray, params: Parameters, layout, point_rate: float,
            notes: list) -> Analog | None:
    """Scaled analog channels: ``(raw - OFFSET) * SCALE * GEN_SCALE``."""
    n = layout.n_channels
    if n == 0:
        return None
    unsigned = params.text("ANALOG", "FORMAT").upper() == "UNSIGNED"
    if unsigned and layout.storage == "integer":
        raw = np.where(raw < 0, raw + 65536, raw)
    offsets = _per_channel(params.numbers("ANALOG", "OFFSET", unsigned16=unsigned), n, 0.0,
                           "OFFSET", notes)
    scales = _per_channel(params.numbers("ANALOG", "SCALE"), n, 1.0, "SCALE", notes)
    gen = params.number("ANALOG", "GEN_SCALE")
    gen = gen if gen is not None and np.isfinite(gen) else 1.0
    with np.errstate(all="ignore"):
        values = (raw - offsets) * (scales * gen)
    bad = ~np.isfinite(values)
    if bad.any():
        notes.append(f"{int(bad.sum())} analog samples are not finite; set to NaN")
        values[bad] = np.nan
    return Analog(values, *_analog_meta(params, layout, point_rate, notes))


def _producer(params: Parameters) -> str:
    company = params.text("MANUFACTURER", "COMPANY")
    software = params.text("MANUFACTURER", "SOFTWARE")
    if company and software.lower().startswith(company.lower()):
        company = ""
    return " ".join(s for s in (company, software, params.text("MANUFACTURER", "VERSION_LABEL"))
                    if s)


def _units(params: Parameters, path, notes: list) -> tuple[str, float]:
    units = params.text("POINT", "UNITS")
    if not units:
        notes.append("no POINT:UNITS; assuming mm")
        return "mm", 1.0
    try:
        return units, mm_per_unit(units, where="POINT:UNITS")
    except InputError:
        raise FileFormatError(path, f"POINT:UNITS is {units!r}, not a length unit; expected "
                                    "mm, cm or m", offset=params.get("POINT", "UNITS").offset
                              ) from None


def _check_budget(layout, path) -> None:
    """Refuse, before decoding, frames whose float64 copy exceeds the allocation budget."""
    samples = layout.n_frames * (3 * layout.n_points
                                 + layout.n_channels * layout.analog_per_frame)
    stored = layout.n_frames * layout.frame_bytes
    check_allocation(path, f"the samples of {layout.n_frames} frames x {layout.n_points} "
                           f"points and {layout.n_channels} analog channels", 8 * samples,
                     justified=stored * 8 // layout.word_size, offset=layout.offset)


@dataclass(frozen=True)
class C3DSummary:
    """What a C3D file holds, found without keeping its positions (``mocap2mesh info``).

    Attributes
    ----------
    labels : tuple of str
        Marker labels, as :func:`read_c3d` gives them.
    n_frames, first_frame : int
    rate : float, Hz
    source : SourceInfo
        As :attr:`Take.source` of :func:`read_c3d`.
    missing : ndarray of shape (n_markers,), int
        Frames in which each marker is missing.
    longest_gap : ndarray of shape (n_markers,), int
        Each marker's longest run of missing frames.
    analog_labels : tuple of str
    analog_rate : float or None, Hz
    """

    labels: tuple
    n_frames: int
    first_frame: int
    rate: float
    source: SourceInfo
    missing: np.ndarray
    longest_gap: np.ndarray
    analog_labels: tuple
    analog_rate: float | None


def _frame(buf, path, notes: list):
    """Header, parameters and layout: everything about the file but its frames."""
    start, order, header, params = _parse(buf, path, notes)
    layout = plan_layout(len(buf), header, params, start, path, notes)
    rate = params.number("POINT", "RATE")
    if not _positive(rate):
        if not _positive(header.rate):
            raise FileFormatError(path, f"no frame rate: POINT:RATE is {rate} and the header "
                                        f"rate {header.rate}", offset=_HEADER_RATE_OFFSET)
        rate = header.rate
    units, factor = _units(params, path, notes)
    labels = _unique_labels(params.string_series("POINT", "LABELS"), layout.n_points,
                            "point", "point", notes)
    extra = dict(header.as_extra(), data_offset=layout.offset,
                 analog_per_frame=layout.analog_per_frame, groups=tuple(params.groups))
    source = SourceInfo(path=str(path), format="c3d", units=units, producer=_producer(params),
                        byte_order=order, storage=layout.storage, extra=extra)
    return order, params, layout, rate, factor, labels, source


def _decode(buf, path, notes: list) -> Take:
    order, params, layout, rate, factor, labels, source = _frame(buf, path, notes)
    _check_budget(layout, path)
    # float64: even the largest float32 or scaled int16 stays finite in mm
    xyz, raw_analog = decode_frames(buf, layout, order, factor=factor)
    # read-only: the take keeps this array as it is, no second copy of the positions; its
    # samples were made finite or NaN as each chunk was widened, not read again
    return take_of_checked_samples(labels, read_only(xyz), rate, first_frame=layout.first_frame,
                                   source=source,
                                   analog=_analog(raw_analog, params, layout, rate, notes))


def summarize_c3d(path) -> C3DSummary:
    """Labels, frames, rate, encoding and gaps of a C3D file, without loading its data.

    The data section is streamed through a memory map a chunk at a time;
    memory stays at a few chunks whatever the file's size (a 3 GB file's
    positions would be 4.5 GB in float64).

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    C3DSummary

    Raises
    ------
    FileFormatError
        As :func:`read_c3d`.

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> from mocap.take import Take
    >>> xyz = np.ones((5, 2, 3)); xyz[1:3, 1] = np.nan
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "t.c3d"
    >>> write_c3d(Take(("a", "b"), xyz, 100.0), path)
    >>> s = summarize_c3d(path)
    >>> s.n_frames, s.missing.tolist(), s.longest_gap.tolist()
    (5, [0, 2], [0, 2])
    """
    path = as_path(path)
    notes: list[str] = []
    with mapped_input(path, "C3D file") as buf:
        order, params, layout, rate, _, labels, source = _frame(buf, path, notes)
        missing, longest = scan_missing(buf, layout, order)
    analog_rate, analog_labels, _ = _analog_meta(params, layout, rate, notes)
    _warn_all(path, notes)
    return C3DSummary(labels, layout.n_frames, layout.first_frame, rate, source,
                      read_only(missing), read_only(longest), analog_labels,
                      analog_rate if layout.n_channels else None)


def read_c3d(path) -> Take:
    """Read a C3D file into a Take.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    Take
        ``positions`` of shape (n_frames, n_points, 3) in mm (POINT:UNITS mm, cm
        or m converted; mm assumed when absent), NaN where the residual word is
        negative (never a zero position); ``analog`` holds the analog channels
        scaled as ``(raw - OFFSET) * SCALE * GEN_SCALE``; ``source`` records the
        units as found, producer (MANUFACTURER), byte order, storage and the
        header fields (``extra``).

    Raises
    ------
    FileFormatError
        Empty, truncated or corrupt file, naming the byte offset: no C3D key,
        a parameter or data pointer outside the file, a data section without a
        complete frame, no frame rate, an unknown length unit.

    Warns
    -----
    UserWarning
        For what the reader worked around: duplicate labels (made unique with
        ``_2``, ``_3``...), a truncated data section, header and parameters
        that disagree, unreadable parameters.

    Notes
    -----
    Point data is located from the header, checked against the parameters and
    the file size before anything is allocated:

    - data start: the header's block unless it lies outside the file or inside
      the parameter section, then POINT:DATA_START (read unsigned);
    - frame count: TRIAL:ACTUAL_START_FIELD/END_FIELD (32-bit) when present,
      else the larger of the header's and POINT:FRAMES (unsigned 16-bit or
      float); a 16-bit count that wrapped is corrected from the file size;
    - a **truncated data section** yields the complete frames it holds and a
      warning; an error only when not one frame is complete;
    - a missing ANALOG group means no analog data; unknown parameter types and
      a parameter section without a proper end are skipped; groups that share
      a name are merged (first definition of a parameter wins).
    """
    path = as_path(path)
    notes: list[str] = []
    with mapped_input(path, "C3D file") as buf:
        take = _decode(buf, path, notes)
    _warn_all(path, notes)
    return take


def read_c3d_parameters(path) -> dict:
    """All parameters of a C3D file as ``{group: {name: value}}``.

    Char parameters are a str (one string) or a tuple of str; numeric ones an
    ndarray shaped as declared (C order, i.e. dims reversed). Group and
    parameter names are upper case.

    Raises
    ------
    FileFormatError
        As :func:`read_c3d`, for the header and parameter section.
    """
    path = as_path(path)
    notes: list[str] = []
    with mapped_input(path, "C3D file") as buf:
        params = _parse(buf, path, notes)[3]
    _warn_all(path, notes)
    return params.as_dict()


def write_c3d(take: Take, path, *, inputs=()) -> None:
    """Write `take` as a C3D file, atomically.

    The file has Intel byte order, float storage (POINT:SCALE -1), units mm,
    residual -1 with xyz 0 for missing samples (0 otherwise), labels in
    POINT:LABELS, LABELS2... (255 per parameter), the rate and first frame
    (header and TRIAL:ACTUAL_START_FIELD/END_FIELD) and the analog channels if
    the take has any (SCALE 1, OFFSET 0, so values are stored as they are).

    Parameters
    ----------
    take : Take
    path : str or os.PathLike
    inputs : iterable of paths, optional
        Files that must never be overwritten.

    Raises
    ------
    InputError
        A take C3D cannot hold: no frames, a negative first frame, labels longer
        than 255 bytes, analog sampled at a rate that is not a whole multiple of
        the frame rate, more than 255 analog channels, or values beyond float32's
        range (no file is left then).
    """
    take = as_take(take)
    parts = encode_c3d(take)        # a take C3D cannot hold fails before any file exists
    # here: the worker threads' module loads SciPy's BLAS, which reading a C3D never needs
    from mocap.util.blas import worker_threads
    from mocap.util.parallel_writes import positional_writer, write_parts
    with atomic_path(as_path(path), inputs=inputs) as tmp, open(tmp, "wb") as fh:
        preallocate(fh, sum(size for size, _ in parts))
        # the frames encoded and written a part at a time by the worker threads: no copy
        # of the whole take
        write_parts(positional_writer(fh, 0), parts, workers=worker_threads(),
                    part_bytes=max(size for size, _ in parts[1:]))
