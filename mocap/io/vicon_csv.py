"""Vicon Nexus CSV export: the ``Trajectories`` block, read and written.

A Nexus CSV export is a sequence of blocks separated by a blank line
(``Devices``, ``Joints``, ``Model Outputs``, ``Trajectories``...). The
``Trajectories`` block is::

    Trajectories
    100                                   <- frame rate, Hz
    ,,Subject:Marker,,,Subject:Other,,,   <- each name spans its X, Y, Z columns
    Frame,Sub Frame,X,Y,Z,X,Y,Z
    ,,mm,mm,mm,mm,mm,mm                   <- length unit of each column
    1,0,44.16,-276.86,675.70,,,           <- empty cells: marker missing
    ...

Nexus pads every line with commas to the full width and ends lines with
CRLF. This module reads that block (and ignores every other block) and
writes it back in the same layout.
"""

from __future__ import annotations

import re

import numpy as np

from mocap.errors import FileFormatError, InputError
from mocap.io._text_table import (
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

__all__ = ["read_vicon_csv", "write_vicon_csv"]

_TRAJECTORIES = re.compile(rb"Trajectories[ \t,]*\r?(?=\n|\Z)")
_NEWLINE = "\r\n"


def _header(path, lines: list, line0: int) -> tuple:
    """Rate, labels, unit and column descriptions from the four header lines."""
    rate_cells = cells(lines[0], ",")
    try:
        rate = float(rate_cells[0])
    except (IndexError, ValueError):
        rate = float("nan")
    if not np.isfinite(rate) or rate <= 0 or len(rate_cells) != 1:
        raise FileFormatError(path, f"expected the frame rate (one positive number) after "
                                    f"'Trajectories', got {lines[0]!r}", line=line0 + 1)
    header = cells(lines[2], ",")
    n_markers = max(len(header), 3) // 3  # ceil((n_cells - 2) / 3): a partial triple counts
    want = ["Frame", "Sub Frame"] + ["X", "Y", "Z"] * n_markers
    header += [""] * (len(want) - len(header))
    wrong = [j for j in range(2, len(want)) if header[j] != want[j]]
    if wrong:
        raise FileFormatError(path, f"header column {wrong[0] + 1} is {header[wrong[0]]!r}, "
                                    f"expected {want[wrong[0]]!r}: the header row is "
                                    "'Frame,Sub Frame' then 'X,Y,Z' per marker",
                              line=line0 + 3)
    names = cells(lines[1], ",")
    where = [j for j, name in enumerate(names) if name]
    labels = tuple(names[j] for j in where)
    if len(labels) != n_markers:
        raise FileFormatError(path, f"the names row has {len(labels)} marker names but the "
                                    f"header has {n_markers} X,Y,Z column triples",
                              line=line0 + 2)
    for k, j in enumerate(where):
        if j != 2 + 3 * k:
            raise FileFormatError(path, f"marker name {names[j]!r} in column {j + 1} does "
                                        "not start an X,Y,Z column triple", line=line0 + 2)
        if labels.index(labels[k]) != k:
            raise FileFormatError(path, f"marker name {labels[k]!r} appears more than once",
                                  line=line0 + 2)
    units = cells(lines[3], ",")[2:2 + 3 * n_markers]
    units += [""] * (3 * n_markers - len(units))
    if len(set(units)) != 1:
        raise FileFormatError(path, f"mixed units {sorted(set(units))} in the units row; "
                                    "expected one length unit for every X, Y, Z column",
                              line=line0 + 4)
    try:
        scale = mm_per_unit(units[0], where="units row")
    except InputError as exc:
        raise FileFormatError(path, str(exc), line=line0 + 4) from None
    columns = ["Frame", "Sub Frame"] + [f"{axis} of {label}" for label in labels
                                        for axis in "XYZ"]
    return rate, labels, units[0], scale, columns


def read_vicon_csv(path) -> Take:
    """Read the ``Trajectories`` block of a Vicon Nexus CSV export.

    Parameters
    ----------
    path : str or os.PathLike
        A Nexus CSV export (CRLF or LF line ends, lines padded with commas or
        not). Other blocks (``Devices``, ``Model Outputs``...) are ignored.

    Returns
    -------
    Take
        ``positions`` of shape (n_frames, n_markers, 3) in mm (converted from
        the units row), NaN where the cells are empty; ``first_frame`` from the
        Frame column; ``source.extra["subjects"]`` the subject names in order
        of appearance.

    Raises
    ------
    FileFormatError
        With the 1-based line at fault: empty file, no ``Trajectories`` block,
        bad rate, header or names row, unknown or mixed units, a non-numeric
        cell, a truncated row, a marker with only some of X, Y, Z, frame
        numbers that are not increasing integers.

    Warns
    -----
    UserWarning
        When frame numbers skip (rows dropped): the absent frames are read
        as missing (NaN) so that frame numbers stay ``first_frame + index``.

    Notes
    -----
    Labels are kept as found, ``Subject:Marker``: Nexus writes the same
    prefixed labels in the C3D of the trial (``SUBJECTS:USES_PREFIXES = 1``),
    so the CSV and the C3D of one trial give identical labels. A label
    without ``:`` belongs to no subject (e.g. unlabelled ``*12``).
    """
    raw = read_bytes(path, "Vicon CSV file")
    found = next((m for m in _TRAJECTORIES.finditer(raw)
                  if not raw[raw.rfind(b"\n", 0, m.start()) + 1:m.start()].strip()), None)
    if found is None:
        start = NOT_BLANK.search(raw).start()
        first = text_lines(raw, raw.rfind(b"\n", 0, start) + 1, 1)[0][0].strip(" \t,")
        raise FileFormatError(path, "no 'Trajectories' block: expected a line "
                                    f"'Trajectories' then the frame rate; found {first!r} "
                                    "first", line=line_number(raw, start))
    line0 = line_number(raw, found.start())
    lines, start = text_lines(raw, found.end() + 1, 4)
    rate, labels, unit, scale, columns = _header(path, lines, line0)
    stop = data_end(raw, start)
    if stop == start:
        raise FileFormatError(path, "the Trajectories block has no data rows",
                              line=line0 + 5)
    values = numeric_block(path, raw[start:stop], first_line=line0 + 5, columns=columns,
                            sep=",")
    first_frame, positions = frames_and_positions(path, values, first_line=line0 + 5,
                                                   labels=labels, scale=scale)
    subjects = tuple(dict.fromkeys(label.split(":", 1)[0] for label in labels
                                   if ":" in label))
    source = SourceInfo(path=str(path), format="vicon-csv", units=unit,
                        producer="Vicon Nexus", storage="text",
                        extra={"subjects": subjects})
    return Take(labels, positions, rate, first_frame=first_frame, source=source)


def write_vicon_csv(take: Take, path, *, inputs=(), decimals: int = 5) -> None:
    """Write the markers of `take` as a Vicon Nexus CSV ``Trajectories`` block.

    The layout is Nexus's: block name, rate, names row (each label spanning
    its X, Y, Z columns), ``Frame,Sub Frame,X,Y,Z`` header, units row (mm),
    one row per frame with empty cells where a marker is missing, every line
    padded with commas to the full width, CRLF line ends.

    Parameters
    ----------
    take : Take
        Positions (n_frames, n_markers, 3) in mm; NaN samples become empty
        cells. Labels are written as they are (``Subject:Marker`` or not).
    path : str or os.PathLike
        The output file, written atomically.
    inputs : iterable of paths, optional
        Files that must never be overwritten.
    decimals : int, optional
        Digits after the decimal point (mm); :func:`read_vicon_csv` gives the
        positions back rounded to this many decimals.

    Raises
    ------
    InputError
        `take` is not a Take, `decimals` is negative, or `path` is an input.
    MarkerError
        A label is empty or holds a comma, a line break or surrounding blanks.
    """
    take = as_take(take)
    decimals = as_int(decimals, "decimals", minimum=0)
    check_labels(take.labels, ",", "Vicon CSV")
    width = 2 + 3 * take.n_markers

    def line(cells):
        return ",".join(cells + [""] * (width - len(cells))) + _NEWLINE

    names = ["", ""] + [cell for label in take.labels for cell in (label, "", "")]
    head = (line(["Trajectories"]) + line([format_number(take.rate)]) + line(names)
            + line(["Frame", "Sub Frame"] + ["X", "Y", "Z"] * take.n_markers)
            + line(["", ""] + ["mm"] * (3 * take.n_markers)))
    rows = format_rows([(take.frames, 0), (np.zeros(take.n_frames), 0)], take.positions,
                        decimals=decimals, sep=",", newline=_NEWLINE)
    write_text(head, rows, path, inputs)
