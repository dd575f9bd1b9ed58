"""Text tables of marker positions: decoding, one vectorized numeric block,
frame numbers, and fixed-point row formatting.

Shared by the Vicon Nexus CSV (:mod:`mocap.io.vicon_csv`) and TRC
(:mod:`mocap.io.trc`) readers and writers. Line numbers in errors are 1-based.
"""

from __future__ import annotations

import codecs
import io
import re
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from mocap.errors import FileFormatError, InputError, MarkerError
from mocap.util.atomic import atomic_path

BLANK_LINES = re.compile(rb"(?:[ \t,]*\r?\n)*")
NOT_BLANK = re.compile(rb"[^ \t\r\n,]")
BLANK_LINE_AFTER = re.compile(rb"\n[ \t,]*\r?(?=\n|\Z)")
_CHUNK_FRAMES = 2048


def read_bytes(path) -> bytes:
    """The file's bytes without a UTF-8 BOM; FileFormatError if empty or unreadable."""
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise FileFormatError(path, f"cannot read the file: {exc.strerror}") from None
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
        The cell separator.

    Returns
    -------
    ndarray of shape (n_rows, len(columns)), float64
        NaN for empty cells.
    """
    n_cols = len(columns)
    if not data.endswith(b"\n"):
        data += b"\n"
    raw = np.frombuffer(data, dtype=np.uint8)
    ends = np.flatnonzero(raw == 10)
    fields = np.diff(np.searchsorted(np.flatnonzero(raw == ord(sep)), ends), prepend=0) + 1
    short = np.flatnonzero(fields < n_cols)
    if short.size:
        row = int(short[0])
        raise FileFormatError(path, f"the row has {fields[row]} cells but {n_cols} were "
                                    f"expected ({columns[0]}, {columns[1]} and X, Y, Z "
                                    "per marker): the row is truncated",
                              line=first_line + row)
    table = pd.read_csv(io.BytesIO(data), sep=sep, header=None, index_col=False,
                        names=list(range(int(fields.max()))), skipinitialspace=True,
                        skip_blank_lines=False, encoding="latin-1", engine="c")
    extra = table.iloc[:, n_cols:].notna().to_numpy().any(axis=1)
    if extra.any():
        row = int(np.argmax(extra))
        raise FileFormatError(path, f"the row has values after its last column "
                                    f"({columns[-1]}); expected {n_cols} columns",
                              line=first_line + row)
    table = table.iloc[:, :n_cols]
    bad_rows = np.full(n_cols, len(table))
    for col in range(n_cols):
        if pd.api.types.is_bool_dtype(table[col]):  # a column of True/False only
            bad_rows[col] = 0
        elif not pd.api.types.is_numeric_dtype(table[col]):
            numbers = pd.to_numeric(table[col], errors="coerce")
            bad = (numbers.isna() & table[col].notna()).to_numpy()
            bad_rows[col] = np.argmax(bad) if bad.any() else len(table)
            table[col] = numbers
    values = table.to_numpy(dtype=np.float64)
    infinite = np.isinf(values)
    bad_rows = np.minimum(bad_rows, np.where(infinite.any(axis=0),
                                             np.argmax(infinite, axis=0), len(table)))
    if (bad_rows < len(table)).any():
        row = int(bad_rows.min())
        col = int(np.flatnonzero(bad_rows == row)[0])
        line = data[ends[row - 1] + 1 if row else 0:ends[row]].decode("latin-1")
        cell = line.split(sep)[col].strip()
        raise FileFormatError(path, f"cell {cell!r} in column {col + 1} ({columns[col]}) "
                                    "is not a finite number", line=first_line + row)
    return values


def frames_and_positions(path, values: np.ndarray, *, first_line: int,
                          labels: tuple, scale: float) -> tuple:
    """First frame and (n_frames, n_markers, 3) mm positions from parsed rows.

    Column 0 holds frame numbers, columns 2: the X, Y, Z of each marker.
    Frame numbers absent between the first and the last row become missing
    frames (NaN), with a warning; decreasing or repeated numbers are an error.
    """
    frames = values[:, 0]
    broken = np.isnan(frames) | (frames != np.round(frames))
    if broken.any():
        row = int(np.argmax(broken))
        raise FileFormatError(path, f"frame number {frames[row]} is not an integer",
                              line=first_line + row)
    back = np.diff(frames) <= 0
    if back.any():
        row = int(np.argmax(back)) + 1
        raise FileFormatError(path, f"frame {frames[row]:.0f} follows frame "
                                    f"{frames[row - 1]:.0f}: frame numbers must increase",
                              line=first_line + row)
    xyz = values[:, 2:].reshape(len(values), len(labels), 3) * scale
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
        return first, xyz
    positions = np.full((n_frames, len(labels), 3), np.nan)
    positions[frames - first] = xyz
    absent = np.setdiff1d(np.arange(first, first + n_frames), frames)
    warnings.warn(f"{path}: {absent.size} frame(s) absent between frames {first} and "
                  f"{frames[-1]} (first absent: {absent[0]}); they are read as missing",
                  stacklevel=3)
    return first, positions


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
