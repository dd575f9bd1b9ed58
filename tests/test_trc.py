"""TRC: the real file against a plain csv-module parse and against ezc3d, TRC files
written here from ezc3d's reading of markers.c3d, every error message, and the writer."""

import csv
import functools

import numpy as np
import pytest
from helpers import write_utf8
from tolerances import EXACT_MM, TRC_BOX_VS_C3D_MM

import mocap.io
from mocap import FileFormatError, InputError, MarkerError, Take
from mocap.io.trc import read_trc, write_trc


def trc_text(labels, positions, *, rate=100.0, first_frame=1, units="mm", sep="\t",
             newline="\n", blank_line=True, num_frames=None):
    """A TRC file written cell by cell (the oracle of the reader)."""
    num_frames = len(positions) if num_frames is None else num_frames
    lines = [["PathFileType", "4", "(X/Y/Z)", "take.trc"],
             ["DataRate", "CameraRate", "NumFrames", "NumMarkers", "Units", "OrigDataRate",
              "OrigDataStartFrame", "OrigNumFrames"],
             [repr(rate), repr(rate), str(num_frames), str(len(labels)), units, repr(rate),
              str(first_frame), str(num_frames)],
             ["Frame#", "Time"] + [c for lab in labels for c in (lab, "", "")],
             ["", ""] + [f"{a}{k + 1}" for k in range(len(labels)) for a in "XYZ"]]
    if blank_line:
        lines.append([])
    for t, frame in enumerate(positions):
        cells = [str(first_frame + t), repr(t / rate)]
        for xyz in frame:
            cells += ["" if np.isnan(v) else repr(float(v)) for v in xyz]
        lines.append(cells)
    return "".join(sep.join(cells) + newline for cells in lines)


#: A TRC file of the given text in tmp_path (newlines kept as written).
write_bytes = functools.partial(write_utf8, name="take.trc")


@pytest.fixture(scope="module")
def c3d(vicon_nexus_ezc3d):
    """Labels, positions (n_frames, n_markers, 3) and first frame of markers.c3d via ezc3d."""
    c = vicon_nexus_ezc3d
    return (tuple(c["parameters"]["POINT"]["LABELS"]["value"]),
            c["data"]["points"][:3].transpose(2, 1, 0),
            int(c["parameters"]["TRIAL"]["ACTUAL_START_FIELD"]["value"][0]))


# -- the real file -----------------------------------------------------------
@pytest.fixture(scope="module")
def real_trc(vicon_nexus_dir):
    path = vicon_nexus_dir / "markers.trc"
    with pytest.warns(UserWarning, match="the header says NumFrames 652 but 93 data rows"):
        return path, read_trc(path)


def test_real_trc_agrees_with_a_plain_parse(real_trc):
    path, take = real_trc
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    labels = tuple(cell for cell in rows[3][2:] if cell)
    data = [row for row in rows[6:] if any(row)]
    expect = np.array([[float(c) if c else np.nan for c in row[2:2 + 3 * len(labels)]]
                       for row in data]).reshape(len(data), len(labels), 3)
    assert take.labels == labels and len(labels) == int(rows[2][3])
    assert take.rate == float(rows[2][0]) and take.first_frame == int(data[0][0])
    np.testing.assert_array_equal(take.positions, expect)
    assert (take.source.format, take.source.units, take.source.storage) == ("trc", "mm", "text")
    assert take.source.extra["header"]["OrigDataRate"] == "100"


def test_real_trc_box_matches_the_c3d_box(real_trc, c3d):
    """markers.trc is another trial of the session: the rigid box keeps its shape."""
    take = real_trc[1]
    labels, positions, _ = c3d
    box = [i for i, label in enumerate(labels) if label.startswith("boite:")]
    ours = take.select([labels[i].replace(":", "_") for i in box]).positions

    def distances(p):
        return np.nanmedian(np.linalg.norm(p[:, :, None] - p[:, None], axis=-1), axis=0)

    assert len(box) == 8
    assert np.abs(distances(ours) - distances(positions[:, box])).max() <= TRC_BOX_VS_C3D_MM


# -- TRC files written here from ezc3d's data ---------------------------------
@pytest.mark.parametrize("sep, newline, blank_line", [("\t", "\n", True), ("\t", "\r\n", False),
                                                      (",", "\r\n", True)])
def test_reads_the_c3d_trial_written_as_trc(tmp_path, c3d, sep, newline, blank_line):
    labels, positions, first_frame = c3d
    path = write_bytes(tmp_path, trc_text(labels, positions, first_frame=first_frame, sep=sep,
                                          newline=newline, blank_line=blank_line))
    take = read_trc(path)
    assert take.labels == labels and take.rate == 100 and take.first_frame == first_frame
    np.testing.assert_array_equal(take.positions, positions)
    assert take.missing.sum() == 305


@pytest.mark.parametrize("units, scale", [("mm", 1.0), ("m", 1000.0), ("cm", 10.0)])
def test_units_are_converted_to_mm(tmp_path, units, scale):
    pos = np.arange(12.0).reshape(2, 2, 3)
    take = read_trc(write_bytes(tmp_path, trc_text(("a", "b"), pos, units=units)))
    np.testing.assert_array_equal(take.positions, pos * scale)
    assert take.source.units == units


# -- errors -------------------------------------------------------------------
GOOD = trc_text(("a", "b"), np.arange(18.0).reshape(3, 2, 3)).split("\n")[:-1]
ERRORS = [  # (line index -> new text, or a whole text), message, 1-based line
    ("", "the file is empty", 1),
    ("Frame,X,Y,Z\n1,2,3,4\n", "not a TRC file: line 1 is 'Frame,X,Y,Z', expected 'PathFil", 1),
    ({1: "CameraRate\tNumFrames\tNumMarkers\tUnits", 2: "100\t3\t2\tmm"},
     "the header has no DataRate value; expected the keys DataRate, NumMarkers, Units", 2),
    ({2: "100\t100\t3\t2\t\t100\t1\t3"}, "the header has no Units value", 3),
    ({2: "fast\t100\t3\t2\tmm\t100\t1\t3"},
     "DataRate 'fast' and NumMarkers '2' must be a positive number and a positive integer", 3),
    ({2: "100\t100\t3\t2\tft\t100\t1\t3"}, "Units: unknown length unit 'ft'", 3),
    ({3: "Frame#\tTime\ta\t\t\t"},
     "the names row has 1 marker names and the next row 6 X/Y/Z columns, but NumMarkers is 2", 4),
    ({4: "\t\tX1\tY1\tZ1\tX2\tY2"}, "the names row has 2 marker names and the next row 5", 4),
    ("\n".join(GOOD[:6]) + "\n\n\n", "no data rows after the header", 6),
    ({7: "2\t0.01\t6\t7\tx8\t9\t10\t11"},
     r"cell 'x8' in column 5 \(Z of a\) is not a finite number", 8),
    ({8: "3\t0.02\t12\t13\t14"}, "the row has 5 cells but 8 were expected .* truncated", 9),
    ("\n".join(GOOD) + "\n\n\n4\t0.03\t1\t2\t3\t4\t5\t6\n",
     "text after the blank line that ends the data", 12),
]


@pytest.mark.parametrize("change, match, line", ERRORS)
def test_error_names_the_line(tmp_path, change, match, line):
    if isinstance(change, dict):
        change = "\n".join(change.get(i, text) for i, text in enumerate(GOOD))
    with pytest.raises(FileFormatError, match=match) as info:
        read_trc(write_bytes(tmp_path, change))
    assert info.value.line == line


def test_the_error_base_file_is_valid(tmp_path):
    take = read_trc(write_bytes(tmp_path, "\n".join(GOOD)))
    np.testing.assert_array_equal(take.positions, np.arange(18.0).reshape(3, 2, 3))


# -- the writer ---------------------------------------------------------------
@pytest.mark.parametrize("decimals", [2, 5])
def test_writer_round_trips_to_the_printed_precision(tmp_path, c3d, decimals):
    labels, positions, first_frame = c3d
    take = Take(labels, positions, rate=100, first_frame=first_frame)
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    first, second = tmp_path / "a" / "take.trc", tmp_path / "b" / "take.trc"
    write_trc(take, first, decimals=decimals)
    back = read_trc(first)
    assert (back.labels, back.rate, back.first_frame) == (labels, 100, first_frame)
    np.testing.assert_array_equal(back.missing, take.missing)
    assert np.nanmax(np.abs(back.positions - positions)) <= 0.5 * 10.0 ** -decimals + EXACT_MM
    write_trc(back, second, decimals=decimals)
    assert first.read_bytes() == second.read_bytes()


def test_writer_header_is_standard(tmp_path):
    take = Take(("a", "b"), np.ones((4, 2, 3)), rate=60, first_frame=10)
    path = tmp_path / "out.trc"
    write_trc(take, path)
    rows = [line.split("\t") for line in path.read_text().split("\n")]
    assert rows[0] == ["PathFileType", "4", "(X/Y/Z)", "out.trc"]
    header = dict(zip(rows[1], rows[2]))
    assert header == {"DataRate": "60", "CameraRate": "60", "NumFrames": "4",
                      "NumMarkers": "2", "Units": "mm", "OrigDataRate": "60",
                      "OrigDataStartFrame": "10", "OrigNumFrames": "4"}
    assert rows[3] == ["Frame#", "Time", "a", "", "", "b", "", ""]
    assert rows[4] == ["", "", "X1", "Y1", "Z1", "X2", "Y2", "Z2"]
    assert rows[5] == [""] and rows[6][:2] == ["10", "0.00000"]


def test_writer_errors(tmp_path):
    take = Take(("a\tb",), np.zeros((2, 1, 3)), rate=50)
    with pytest.raises(MarkerError, match="cannot be written to a TRC file"):
        write_trc(take, tmp_path / "x.trc")
    with pytest.raises(InputError, match="take must be a mocap.Take, got tuple"):
        write_trc((1, 2), tmp_path / "x.trc")
    assert not list(tmp_path.iterdir())


def test_io_read_dispatches_to_the_trc_reader(tmp_path):
    path = write_bytes(tmp_path, "\n".join(GOOD))
    np.testing.assert_array_equal(mocap.io.read(path).positions, read_trc(path).positions)
