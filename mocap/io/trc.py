"""TRC marker files (Motion Analysis / OpenSim track row column format).

A TRC file is::

    PathFileType  4  (X/Y/Z)  name.trc
    DataRate  CameraRate  NumFrames  NumMarkers  Units  OrigDataRate  ...
    100       100         580        51          mm     100           ...
    Frame#  Time  ASISl        ASISr ...       <- each name spans X, Y, Z
                  X1  Y1  Z1   X2  Y2  Z2 ...
                                               <- optional blank line
    1       0     733.7 80.98 191.87 ...       <- empty cells: marker missing

Cells are separated by tabs (the standard) or by commas (some exporters);
the separator of the first line is used throughout.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from mocap.errors import FileFormatError, InputError
from mocap.io._text_table import (
    BLANK_LINES,
    NOT_BLANK,
    cells,
    check_labels,
    data_end,
    format_number,
    format_rows,
    frames_and_positions,
    line_number,
    numeric_block,
    read_bytes,
    text_lines,
    write_text,
)
from mocap.take import SourceInfo, Take, as_take
from mocap.units import mm_per_unit
from mocap.util.validation import as_int

__all__ = ["read_trc", "write_trc"]

#: Header keys (line 2) that :func:`read_trc` needs.
TRC_REQUIRED_KEYS = ("DataRate", "NumMarkers", "Units")


def _settings(path, lines: list, sep: str) -> dict:
    """The key-value header of lines 2-3, checked."""
    keys, values = cells(lines[1], sep), cells(lines[2], sep)
    settings = dict(zip(keys, values + [""] * (len(keys) - len(values))))
    for key in TRC_REQUIRED_KEYS:
        if not settings.get(key):
            raise FileFormatError(path, f"the header has no {key} value; expected the keys "
                                        f"{', '.join(TRC_REQUIRED_KEYS)} on line 2 and their "
                                        "values on line 3", line=3 if key in keys else 2)
    try:
        rate = float(settings["DataRate"])
        n_markers = int(settings["NumMarkers"])
    except ValueError:
        rate, n_markers = float("nan"), -1
    if not np.isfinite(rate) or rate <= 0 or n_markers < 1:
        raise FileFormatError(path, f"DataRate {settings['DataRate']!r} and NumMarkers "
                                    f"{settings['NumMarkers']!r} must be a positive number "
                                    "and a positive integer", line=3)
    return settings


def read_trc(path) -> Take:
    """Read a TRC marker file.

    Parameters
    ----------
    path : str or os.PathLike
        A TRC file, tab- or comma-separated, CRLF or LF line ends.

    Returns
    -------
    Take
        ``positions`` of shape (n_frames, n_markers, 3) in mm (converted from
        the ``Units`` header value), NaN where the cells are empty; rate from
        ``DataRate``; ``first_frame`` from the ``Frame#`` column; labels as
        found on line 4; ``source.extra["header"]`` the key-value header.

    Raises
    ------
    FileFormatError
        With the 1-based line at fault: empty file, no ``PathFileType`` line,
        a missing or bad ``DataRate``/``NumMarkers``/``Units``, a names row
        that does not match ``NumMarkers`` or the X/Y/Z row, a non-numeric
        cell, a truncated row, text after the data.

    Warns
    -----
    UserWarning
        When ``NumFrames`` differs from the number of data rows, and when frame
        numbers skip (the absent frames are read as missing).
    """
    raw = read_bytes(path, "TRC file")
    lines, start = text_lines(raw, 0, 5)
    if not lines[0].lstrip().startswith("PathFileType"):
        raise FileFormatError(path, f"not a TRC file: line 1 is {lines[0][:40]!r}, expected "
                                    "'PathFileType'", line=1)
    sep = "\t" if "\t" in lines[0] else ","
    settings = _settings(path, lines, sep)
    n_markers = int(settings["NumMarkers"])
    labels = tuple(name for name in cells(lines[3], sep)[2:] if name)
    axes = [cell for cell in cells(lines[4], sep) if cell]
    if len(labels) != n_markers or len(axes) != 3 * n_markers:
        raise FileFormatError(path, f"the names row has {len(labels)} marker names and the "
                                    f"next row {len(axes)} X/Y/Z columns, but NumMarkers is "
                                    f"{n_markers} (3 columns per marker)", line=4)
    try:
        scale = mm_per_unit(settings["Units"], where="Units")
    except InputError as exc:
        raise FileFormatError(path, str(exc), line=3) from None
    start = BLANK_LINES.match(raw, start).end()
    stop = data_end(raw, start)
    if stop == start:
        raise FileFormatError(path, "no data rows after the header", line=6)
    first_line = line_number(raw, start)
    after = NOT_BLANK.search(raw, stop)
    if after is not None:
        raise FileFormatError(path, "text after the blank line that ends the data; a TRC "
                                    "file holds one table",
                              line=line_number(raw, after.start()))
    columns = ["Frame#", "Time"] + [f"{axis} of {label}" for label in labels
                                    for axis in "XYZ"]
    values = numeric_block(path, raw[start:stop], first_line=first_line, columns=columns,
                            sep=sep)
    stated = settings.get("NumFrames", "")
    if stated.isdigit() and int(stated) != len(values):
        warnings.warn(f"{path}: the header says NumFrames {stated} but {len(values)} data "
                      "rows follow; reading the rows", stacklevel=2)
    first_frame, positions = frames_and_positions(path, values, first_line=first_line,
                                                   labels=labels, scale=scale)
    source = SourceInfo(path=str(path), format="trc", units=settings["Units"],
                        storage="text", extra={"header": settings})
    return Take(labels, positions, float(settings["DataRate"]), first_frame=first_frame,
                source=source)


def write_trc(take: Take, path, *, inputs=(), decimals: int = 5) -> None:
    """Write the markers of `take` as a tab-separated TRC file, in mm.

    Parameters
    ----------
    take : Take
        Positions (n_frames, n_markers, 3) in mm; NaN samples become empty cells.
    path : str or os.PathLike
        The output file, written atomically.
    inputs : iterable of paths, optional
        Files that must never be overwritten.
    decimals : int, optional
        Digits after the decimal point for positions (mm) and times (s).

    Raises
    ------
    InputError
        `take` is not a Take, `decimals` is negative, or `path` is an input.
    MarkerError
        A label is empty or holds a tab, a line break or surrounding blanks.
    """
    take = as_take(take)
    decimals = as_int(decimals, "decimals", minimum=0)
    check_labels(take.labels, "\t", "TRC")
    rate, n, m = format_number(take.rate), take.n_frames, take.n_markers
    head = [["PathFileType", "4", "(X/Y/Z)", Path(path).name],
            ["DataRate", "CameraRate", "NumFrames", "NumMarkers", "Units", "OrigDataRate",
             "OrigDataStartFrame", "OrigNumFrames"],
            [rate, rate, str(n), str(m), "mm", rate, str(take.first_frame), str(n)],
            ["Frame#", "Time"] + [cell for label in take.labels for cell in (label, "", "")],
            ["", ""] + [f"{axis}{k}" for k in range(1, m + 1) for axis in "XYZ"],
            []]
    rows = format_rows([(take.frames, 0), (take.times, decimals)], take.positions,
                        decimals=decimals, sep="\t", newline="\n")
    write_text("".join("\t".join(cells) + "\n" for cells in head), rows, path, inputs)
