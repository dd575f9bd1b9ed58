"""Text tables of marker positions: decoding, one vectorized numeric block,
frame numbers, and fixed-point row formatting.

Shared by the Vicon Nexus CSV (:mod:`mocap.io.vicon_csv`) and TRC
(:mod:`mocap.io.trc`) readers and writers. Line numbers in errors are 1-based.
"""

from __future__ import annotations

import codecs
import csv
import io
import re
import warnings

import numpy as np
import pandas as pd

from mocap.errors import FileFormatError, InputError, MarkerError
from mocap.util.arrays import read_only
from mocap.util.atomic import atomic_path
from mocap.util.budget import check_allocation
from mocap.util.files import read_input_bytes

BLANK_LINES = re.compile(rb"(?:[ \t,]*\r?\n)*")
NOT_BLANK = re.compile(rb"[^ \t\r\n,]")
BLANK_LINE_AFTER = re.compile(rb"\n[ \t,]*\r?(?=\n|\Z)")
_CHUNK_FRAMES = 2048
#: Largest frame number in a text table (integers are exact in float64 below 2**53).
_MAX_FRAME = 1e15
#: Bytes of rows whose separators are located at once when counting cells.
_COUNT_BYTES = 1 << 18
_LONE_CR = re.compile(rb"\r(?!\n)")
#: Cells per chunk when looking for the cell that is not a number.
_LOCATE_CELLS = 1 << 18


def read_bytes(path, what: str) -> bytes:
    """The file's bytes without a UTF-8 BOM; FileFormatError if empty or unreadable."""
    raw = read_input_bytes(path, what)
    if raw.startswith(codecs.BOM_UTF8):
        raw = raw[len(codecs.BOM_UTF8):]
    if NOT_BLANK.search(raw) is None:
        raise FileFormatError(path, "the file is empty", line=1)
    return raw


def line_number(raw: bytes, offset: int) -> int:
    """1-based line number of byte `offset`."""
    return raw.count(b"\n", 0, offset) + 1


def text_lines(raw: bytes, start: int, count: int) -> tuple:
    """`count` lines from byte `start` as text (missing lines are ""), and the offset after."""
    lines = []
    for _ in range(count):
        stop = raw.find(b"\n", start)
        stop = len(raw) if stop < 0 else stop
        line = raw[start:stop].rstrip(b"\r")
        try:
            lines.append(line.decode("utf-8"))
        except UnicodeDecodeError:
            lines.append(line.decode("latin-1"))
        start = min(stop + 1, len(raw))
    return lines, start


def cells(line: str, sep: str) -> list:
    """Stripped cells of one line, without the trailing empty ones."""
    cells = [c.strip() for c in line.split(sep)]
    while cells and not cells[-1]:
        cells.pop()
    return cells


def data_end(raw: bytes, start: int) -> int:
    """Offset of the blank line (or end of file) that ends the rows starting at `start`."""
    if BLANK_LINES.match(raw, start).end() > start:
        return start
    end = BLANK_LINE_AFTER.search(raw, start)
    return len(raw) if end is None else end.start() + 1


def _row_fields(data: bytes, raw: np.ndarray, ends: np.ndarray, sep: str) -> np.ndarray:
    """Cells of each row (separators + 1), counted a window of rows at a time.

    The separator positions of one window (:data:`_COUNT_BYTES`) are held at a
    time; a row longer than the window is counted in place (``bytes.count``).
    """
    sep_byte = sep.encode("latin-1")
    fields = np.empty(len(ends), dtype=np.int64)
    row = 0
    while row < len(ends):
        lo = int(ends[row - 1]) + 1 if row else 0
        stop = int(np.searchsorted(ends, lo + _COUNT_BYTES, side="right"))
        if stop <= row:                             # one row longer than the window
            fields[row] = data.count(sep_byte, lo, int(ends[row])) + 1
            row += 1
            continue
        seps = np.flatnonzero(raw[lo:int(ends[stop - 1])] == ord(sep))
        fields[row:stop] = np.diff(np.searchsorted(seps, ends[row:stop] - lo), prepend=0) + 1
        row = stop
    return fields


def _trim_wide_rows(path, data: bytes, starts, ends, fields, n_cols: int, sep: str,
                    first_line: int, columns: list) -> bytes:
    """The rows cut after their `n_cols`-th cell; an error if a cut cell is not blank.

    Exporters pad rows with empty cells (trailing separators); those are
    dropped here so that the table is never wider than its header says. One
    ``bytes.split`` per padded row (at most `n_cols` splits, done in C) keeps
    the memory to the row's own size, however many separators it holds.
    """
    sep_byte = sep.encode("latin-1")
    parts, pos = [], 0
    for row in np.flatnonzero(fields > n_cols).tolist():
        start, end = int(starts[row]), int(ends[row])
        cells = data[start:end].split(sep_byte, n_cols)
        if cells[-1].strip(b" \t\r" + sep_byte):
            raise FileFormatError(path, f"the row has values after its last column "
                                        f"({columns[-1]}); expected {n_cols} columns",
                                  line=first_line + row)
        parts += [data[pos:start], sep_byte.join(cells[:n_cols])]
        pos = end
    parts.append(data[pos:])
    return b"".join(parts)


def _read_table(data: bytes, sep: str, n_cols: int, **options) -> pd.DataFrame:
    """The rows as a table of exactly `n_cols` columns (pandas' C parser, no quoting)."""
    return pd.read_csv(io.BytesIO(data), sep=sep, header=None, index_col=False,
                       names=list(range(n_cols)), skipinitialspace=True,
                       skip_blank_lines=False, encoding="latin-1", engine="c",
                       quoting=csv.QUOTE_NONE, **options)


def _first_bad_cell(path, data: bytes, sep: str, columns: list, first_line: int):
    """Raise FileFormatError naming the first cell that is not a finite number.

    Reads the rows in chunks (as text) so that locating the cell stays within
    a small multiple of the chunk, whatever the file's size.
    """
    n_cols = len(columns)
    offset = 0
    for chunk in _read_table(data, sep, n_cols, dtype=object,
                             chunksize=max(1, _LOCATE_CELLS // n_cols)):
        cells = chunk.to_numpy(dtype=object)
        numbers = np.column_stack([pd.to_numeric(chunk[col], errors="coerce")
                                   .to_numpy(dtype=np.float64) for col in range(n_cols)])
        bad = (pd.notna(cells) & np.isnan(numbers)) | np.isinf(numbers)
        if bad.any():
            row, col = np.argwhere(bad)[0]
            raise FileFormatError(path, f"cell {str(cells[row, col]).strip()!r} in column "
                                        f"{col + 1} ({columns[col]}) is not a finite number",
                                  line=first_line + offset + int(row))
        offset += len(chunk)
    raise AssertionError("no bad cell found after the fast parse failed")  # pragma: no cover


def numeric_block(path, data: bytes, *, first_line: int, columns: list,
                   sep: str) -> np.ndarray:
    """Parse the data rows of a table, vectorized, checking every cell.

    Parameters
    ----------
    path : path
        The file, for error messages.
    data : bytes
        The data rows (LF or CRLF line ends); no blank line.
    first_line : int
        1-based line number of the first row in the file.
    columns : list of str
        A description of each expected column, for error messages.
    sep : str
        The cell separator. Quotes are ordinary characters (no cell of a
        marker table is quoted), so a quote makes its cell non-numeric.

    Returns
    -------
    ndarray of shape (n_rows, len(columns)), float64
        NaN for empty cells.

    Raises
    ------
    FileFormatError
        A row with fewer cells than columns, a value after the last column (empty
        trailing cells are allowed), a cell that is not a finite number, or
        more cells than ``MOCAP2MESH_MAX_BYTES`` allows.
    """
    n_cols = len(columns)
    if not data.endswith(b"\n"):
        data += b"\n"
    raw = np.frombuffer(data, dtype=np.uint8)
    ends = np.flatnonzero(raw == 10)
    starts = np.concatenate([[0], ends[:-1] + 1])
    fields = _row_fields(data, raw, ends, sep)
    short = np.flatnonzero(fields < n_cols)
    if short.size:
        row = int(short[0])
        raise FileFormatError(path, f"the row has {fields[row]} cells but {n_cols} were "
                                    f"expected ({columns[0]}, {columns[1]} and X, Y, Z "
                                    "per marker): the row is truncated",
                              line=first_line + row)
    check_allocation(path, f"a table of {len(ends)} rows x {n_cols} columns",
                     8.0 * len(ends) * n_cols, justified=8 * len(data), line=first_line)
    if fields.max() > n_cols:
        data = _trim_wide_rows(path, data, starts, ends, fields, n_cols, sep, first_line,
                               columns)
    n_rows = len(ends)
    del raw, ends, starts, fields
    lone = _LONE_CR.search(data)
    if lone is not None:
        raise FileFormatError(path, "a carriage return inside a row; rows end with LF or CRLF",
                              line=first_line + data.count(b"\n", 0, lone.start()))
    try:
        values = _read_table(data, sep, n_cols, dtype=np.float64).to_numpy(dtype=np.float64)
    except ValueError:
        values = None
    if values is None or np.isinf(values).any():
        _first_bad_cell(path, data, sep, columns, first_line)
    assert len(values) == n_rows, "pandas and the row count disagree"
    return values


def frames_and_positions(path, values: np.ndarray, *, first_line: int,
                          labels: tuple, scale: float) -> tuple:
    """First frame and (n_frames, n_markers, 3) mm positions from parsed rows (read-only:
    a take keeps them without a copy).

    Column 0 holds frame numbers, columns 2: the X, Y, Z of each marker.
    Frame numbers absent between the first and the last row become missing
    frames (NaN), with a warning, as long as they take no more memory than
    twice the rows the file holds (beyond, a FileFormatError names the jump);
    decreasing or repeated numbers are an error.
    """
    frames = values[:, 0]
    broken = np.isnan(frames) | (frames != np.round(frames)) | (np.abs(frames) > _MAX_FRAME)
    if broken.any():
        row = int(np.argmax(broken))
        raise FileFormatError(path, f"frame number {frames[row]} is not an integer of at most "
                                    f"{_MAX_FRAME:.0e} in magnitude", line=first_line + row)
    back = np.diff(frames) <= 0
    if back.any():
        row = int(np.argmax(back)) + 1
        raise FileFormatError(path, f"frame {frames[row]:.0f} follows frame "
                                    f"{frames[row - 1]:.0f}: frame numbers must increase",
                              line=first_line + row)
    with np.errstate(over="ignore"):
        xyz = values[:, 2:].reshape(len(values), len(labels), 3) * scale
    huge = np.isinf(xyz)
    if huge.any():
        row, marker, axis = np.argwhere(huge)[0]
        raise FileFormatError(path, f"{'XYZ'[axis]} of marker {labels[marker]!r} is "
                                    f"{values[row, 2 + 3 * marker + axis]:.6g} file units, "
                                    "beyond the float range in mm", line=first_line + int(row))
    nan = np.isnan(xyz)
    partial = nan.any(axis=2) & ~nan.all(axis=2)
    if partial.any():
        row, marker = np.argwhere(partial)[0]
        raise FileFormatError(path, f"marker {labels[marker]!r} has some of X, Y, Z empty "
                                    "and others not; a gap leaves all three empty",
                              line=first_line + int(row))
    frames = frames.astype(np.int64)
    first, n_frames = int(frames[0]), int(frames[-1] - frames[0]) + 1
    if n_frames == len(frames):
        return first, read_only(xyz)
    jump = int(np.argmax(np.diff(frames))) + 1
    check_allocation(path, f"positions of {n_frames} frames (frame numbers {first} to "
                           f"{frames[-1]}, {n_frames - len(frames)} of them absent; the "
                           f"largest jump: {frames[jump - 1]} to {frames[jump]}) x "
                           f"{len(labels)} markers", 24.0 * n_frames * len(labels),
                     justified=2 * xyz.nbytes, line=first_line + jump)
    positions = np.full((n_frames, len(labels), 3), np.nan)
    positions[frames - first] = xyz
    absent = np.setdiff1d(np.arange(first, first + n_frames), frames)
    warnings.warn(f"{path}: {absent.size} frame(s) absent between frames {first} and "
                  f"{frames[-1]} (first absent: {absent[0]}); they are read as missing",
                  stacklevel=3)
    return first, read_only(positions)


def check_labels(labels, sep: str, what: str) -> None:
    """MarkerError if a label cannot be written as one cell of a `what` file."""
    for label in labels:
        if not label or label != label.strip() or sep in label or "\n" in label \
                or "\r" in label:
            raise MarkerError(label, f"cannot be written to a {what} file: labels must be "
                                     "non-empty, without separators, line breaks or "
                                     "surrounding blanks")


def format_number(value: float) -> str:
    """An integer-valued float without decimals, else its shortest exact repr."""
    return str(int(value)) if float(value).is_integer() else repr(float(value))


def _fixed_point(values: np.ndarray, decimals: int) -> np.ndarray:
    """Cells of `values` (n, k) printed with `decimals` decimals, vectorized.

    Returns uint8 of shape (n, k, width): the ASCII characters of each cell,
    right-aligned, 0 bytes as padding; a NaN cell is all padding (empty).
    The value printed is ``round(|x| * 10**decimals)``, with a minus sign
    unless it is zero (never ``-0``).
    """
    missing = np.isnan(values)
    scaled = np.rint(np.abs(np.where(missing, 0.0, values)) * 10.0 ** decimals)
    if scaled.max(initial=0.0) >= 1e18:
        raise InputError(f"values up to {np.nanmax(np.abs(values)):.3g} cannot be written "
                         f"with {decimals} decimals (at most 18 digits)")
    rest = scaled.astype(np.int64)
    negative = (values < 0) & (rest > 0)
    places = max(decimals + 1, len(str(int(rest.max(initial=0)))))
    point = int(decimals > 0)
    width = places + point + 1
    cells = np.zeros(values.shape + (width,), dtype=np.uint8)
    n_digits = np.zeros(values.shape, dtype=np.int8)
    for place in range(places):  # one pass per digit place, over all cells at once
        shown = (rest > 0) | (place <= decimals)
        quotient = rest // 10  # (np.divmod has no fast path for a scalar divisor)
        digit = (rest - quotient * 10).astype(np.uint8)
        digit += ord("0")
        digit *= shown
        cells[..., width - 1 - place - (point if place >= decimals else 0)] = digit
        n_digits += shown
        rest = quotient
    if point:
        cells[..., width - 1 - decimals] = ord(".")
    row, col = np.nonzero(negative)
    cells[row, col, width - 1 - point - n_digits[row, col]] = ord("-")
    cells[missing] = 0
    return cells


def format_rows(lead: list, positions: np.ndarray, *, decimals: int, sep: str,
                 newline: str) -> bytes:
    """Data rows: the `lead` columns, then X, Y, Z per marker, empty for NaN.

    `lead` holds ``(values of shape (n_frames,), decimals)`` pairs. Rows are
    formatted in chunks of frames, each chunk with array operations only.
    """
    n_frames = positions.shape[0]
    flat = positions.reshape(n_frames, -1)
    tail = np.frombuffer(newline.encode(), dtype=np.uint8)
    parts = []
    for start in range(0, n_frames, _CHUNK_FRAMES):
        stop = min(start + _CHUNK_FRAMES, n_frames)
        groups = [_fixed_point(np.asarray(column, float)[start:stop, None], places)
                  for column, places in lead]
        groups.append(_fixed_point(flat[start:stop], decimals))
        width = max(group.shape[2] for group in groups)
        cells = np.concatenate([np.pad(group, ((0, 0), (0, 0), (width - group.shape[2], 0)))
                                for group in groups], axis=1)
        seps = np.full(cells.shape[:2] + (1,), ord(sep), dtype=np.uint8)
        rows = np.concatenate([cells, seps], axis=2).reshape(stop - start, -1)[:, :-1]
        rows = np.concatenate([rows, np.tile(tail, (stop - start, 1))], axis=1).ravel()
        parts.append(rows[rows != 0].tobytes())
    return b"".join(parts)


def write_text(head: str, rows: bytes, path, inputs) -> None:
    """Write `head` (UTF-8) then the formatted `rows` to `path`, atomically."""
    with atomic_path(path, inputs=inputs) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(head.encode("utf-8"))
            fh.write(rows)


# -- Vicon Nexus CSV ---------------------------------------------------------
