"""Vicon Nexus CSV: the real export against ezc3d's reading of the same trial's C3D,
edge-case files written here by a plain loop, every error message, and the writer."""

import csv
import functools

import numpy as np
import pytest
from helpers import write_utf8
from tolerances import CSV_VS_C3D_MM, EXACT_MM, VICON_CSV_CELL_MM

import mocap.io
from mocap import FileFormatError, InputError, MarkerError, Take
from mocap.io.vicon_csv import read_vicon_csv, write_vicon_csv
from mocap.units import UNITS_TO_MM

DEVICES = ("Devices\n1000\n,,Force Plate 1 - Force,,\nFrame,Sub Frame,Fx,Fy,Fz\n"
           ",,N,N,N\n1,0,1.5,2.5,3.5\n1,1,1.6,2.6,3.6\n")
MODEL_OUTPUTS = ("Model Outputs\n100\n,,S:LAngle,,\nFrame,Sub Frame,X,Y,Z\n"
                 ",,deg,deg,deg\n1,0,10,20,30\n")


def nexus_text(labels, positions, *, rate=100, first_frame=1, unit="mm", newline="\r\n",
               pad=True, trailing="", before="", after="", leading_blank=0):
    """A Nexus-style CSV written cell by cell (the oracle of the reader)."""
    width = 2 + 3 * len(labels)

    def line(cells):
        cells = [str(c) for c in cells]
        if pad:
            cells += [""] * (width - len(cells))
        return ",".join(cells) + trailing

    lines = [line(["Trajectories"]), line([rate]),
             line(["", ""] + [c for lab in labels for c in (lab, "", "")]),
             line(["Frame", "Sub Frame"] + ["X", "Y", "Z"] * len(labels)),
             line(["", ""] + [unit] * (3 * len(labels)))]
    for t, frame in enumerate(positions):
        cells = [first_frame + t, 0]
        for xyz in frame:
            cells += ["" if np.isnan(v) else repr(float(v)) for v in xyz]
        lines.append(line(cells))
    blocks = [b.replace("\n", newline) for b in (before,) if b]
    blocks.append(newline.join(lines) + newline)
    blocks += [b.replace("\n", newline) for b in (after,) if b]
    return newline * leading_blank + newline.join(blocks)


def random_positions(n_frames, n_markers, seed=0):
    rng = np.random.default_rng(seed)
    pos = rng.normal(0, 300, (n_frames, n_markers, 3))
    pos[rng.random((n_frames, n_markers)) < 0.2] = np.nan
    return pos


#: A Vicon CSV file of the given text in tmp_path (newlines kept as written).
write_bytes = functools.partial(write_utf8, name="take.csv")


# -- the real export against ezc3d ------------------------------------------
@pytest.fixture(scope="module")
def nexus(vicon_nexus_dir, vicon_nexus_ezc3d):
    """markers.csv read by our reader, and the same trial's markers.c3d read by ezc3d."""
    return read_vicon_csv(vicon_nexus_dir / "markers.csv"), vicon_nexus_ezc3d


def test_real_csv_agrees_with_ezc3d(nexus):
    take, c3d = nexus
    params = c3d["parameters"]
    expect = c3d["data"]["points"][:3].transpose(2, 1, 0)
    assert take.labels == tuple(params["POINT"]["LABELS"]["value"])
    assert take.rate == params["POINT"]["RATE"]["value"][0]
    assert take.first_frame == params["TRIAL"]["ACTUAL_START_FIELD"]["value"][0]
    assert take.first_frame == c3d["header"]["points"]["first_frame"] + 1  # ezc3d is 0-based
    np.testing.assert_array_equal(take.missing, np.isnan(expect[:, :, 0]))
    assert take.missing.sum() == 305 and take.positions.shape == (580, 51, 3)
    assert np.nanmax(np.abs(take.positions - expect)) <= CSV_VS_C3D_MM


def test_real_csv_source_and_subjects(nexus):
    take, c3d = nexus
    assert take.source.extra["subjects"] == tuple(c3d["parameters"]["SUBJECTS"]["NAMES"]["value"])
    assert (take.source.format, take.source.units, take.source.producer,
            take.source.storage) == ("vicon-csv", "mm", "Vicon Nexus", "text")


def test_io_read_dispatches_to_the_csv_reader(vicon_nexus_dir, nexus):
    take = mocap.io.read(vicon_nexus_dir / "markers.csv")
    np.testing.assert_array_equal(take.positions, nexus[0].positions)


# -- edge-case files ----------------------------------------------------------
LAYOUTS = {
    "nexus": {},
    "lf": {"newline": "\n"},
    "leading_blank_lines": {"leading_blank": 3},
    "trailing_commas": {"trailing": ",,,"},
    "unpadded": {"pad": False},
    "devices_before": {"before": DEVICES},
    "devices_and_model_outputs_after": {"after": DEVICES + "\n" + MODEL_OUTPUTS},
    "devices_around": {"before": DEVICES, "after": DEVICES, "newline": "\n"},
}
SUBJECTS = {
    "one_subject": (("S:a", "S:b", "S:c"), ("S",)),
    "two_subjects": (("box:a", "Daphnee:b", "box:c", "Daphnee:d"), ("box", "Daphnee")),
    "no_prefix": (("a", "*12"), ()),
}


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("subjects", SUBJECTS)
def test_reads_edge_case_layouts(tmp_path, layout, subjects):
    labels, expect_subjects = SUBJECTS[subjects]
    pos = random_positions(9, len(labels))
    path = write_bytes(tmp_path, nexus_text(labels, pos, rate=120, first_frame=7,
                                            **LAYOUTS[layout]))
    take = read_vicon_csv(path)
    assert take.labels == labels and take.rate == 120 and take.first_frame == 7
    np.testing.assert_array_equal(take.positions, pos)
    assert take.source.extra["subjects"] == expect_subjects


@pytest.mark.parametrize("unit", ["mm", "cm", "m", "in", "Millimeters"])
def test_units_row_is_converted_to_mm(tmp_path, unit):
    pos = random_positions(5, 2)
    take = read_vicon_csv(write_bytes(tmp_path, nexus_text(("a", "b"), pos, unit=unit)))
    np.testing.assert_array_equal(take.positions, pos * UNITS_TO_MM[unit.lower()])
    assert take.source.units == unit


def test_dropped_rows_become_missing_frames(tmp_path):
    pos = random_positions(6, 2)
    lines = nexus_text(("a", "b"), pos, first_frame=1).split("\r\n")
    del lines[7:9]  # the rows of frames 3 and 4
    path = write_bytes(tmp_path, "\r\n".join(lines))
    with pytest.warns(UserWarning, match=r"2 frame\(s\) absent between frames 1 and 6 "
                                         r"\(first absent: 3\)"):
        take = read_vicon_csv(path)
    expect = pos.copy()
    expect[2:4] = np.nan
    np.testing.assert_array_equal(take.positions, expect)
    assert take.first_frame == 1


# -- errors -------------------------------------------------------------------
GOOD = ["Trajectories", "100", ",,S:a,,,S:b,,", "Frame,Sub Frame,X,Y,Z,X,Y,Z",
        ",,mm,mm,mm,mm,mm,mm", "1,0,1,2,3,4,5,6", "2,0,1.5,2.5,3.5,,,", "3,0,1,2,3,4,5,6"]
ERRORS = [  # (line index -> new text, or a whole text), message, 1-based line
    ("", "the file is empty", 1),
    ("\r\n,,,\r\n\r\n", "the file is empty", 1),
    (DEVICES, r"no 'Trajectories' block: expected a line 'Trajectories' then the frame "
              r"rate; found 'Devices' first", 1),
    ("\n\n" + MODEL_OUTPUTS, r"no 'Trajectories' block.*found 'Model Outputs' first", 3),
    ({1: "100 Hz"}, r"expected the frame rate \(one positive number\) after 'Trajectories'", 2),
    ({1: "-100"}, "expected the frame rate", 2),
    ({2: ",,S:a,,,"}, "the names row has 1 marker names but the header has 2 X,Y,Z", 3),
    ({2: ",,S:a,,S:b,,"}, "marker name 'S:b' in column 5 does not start an X,Y,Z column", 3),
    ({2: ",,S:a,,,S:a,,"}, "marker name 'S:a' appears more than once", 3),
    ({3: "Frame,Sub Frame,X,Y,Q,X,Y,Z"}, "header column 5 is 'Q', expected 'Z'", 4),
    ({3: "Frame,Sub Frame,X,Y,Z,X,Y"}, "header column 8 is '', expected 'Z'", 4),
    ({4: ",,mm,mm,mm,m,m,m"}, r"mixed units \['m', 'mm'\] in the units row", 5),
    ({4: ",,ft,ft,ft,ft,ft,ft"}, "units row: unknown length unit 'ft'", 5),
    ("\n".join(GOOD[:5]) + "\n\n" + DEVICES, "the Trajectories block has no data rows", 6),
    ({6: "2,0,1.5,abc,3.5,,,"}, r"cell 'abc' in column 4 \(Y of S:a\) is not a finite", 7),
    ({6: "2,0,1.5,2.5,3.5,inf,1,1"}, r"cell 'inf' in column 6 \(X of S:b\) is not a finite", 7),
    ({7: "3,0,1,2"}, r"the row has 4 cells but 8 were expected .* the row is truncated", 8),
    ({7: "3,0,1,2,3,4,5,6,7"}, r"values after its last column \(Z of S:b\)", 8),
    ({6: "2,0,1.5,,3.5,,,"}, "marker 'S:a' has some of X, Y, Z empty and others not", 7),
    ({6: "2.5,0,1,2,3,4,5,6"}, "frame number 2.5 is not an integer", 7),
    ({7: "2,0,1,2,3,4,5,6"}, "frame 2 follows frame 2: frame numbers must increase", 8),
]


@pytest.mark.parametrize("change, match, line", ERRORS)
def test_error_names_the_line(tmp_path, change, match, line):
    if isinstance(change, dict):
        change = "\n".join(change.get(i, text) for i, text in enumerate(GOOD))
    with pytest.raises(FileFormatError, match=match) as info:
        read_vicon_csv(write_bytes(tmp_path, change))
    assert info.value.line == line
    assert f"take.csv at line {line}: " in str(info.value)


def test_the_error_base_file_is_valid(tmp_path):
    take = read_vicon_csv(write_bytes(tmp_path, "\n".join(GOOD)))
    assert take.missing.tolist() == [[False, False], [False, True], [False, False]]


# -- the writer ---------------------------------------------------------------
@pytest.mark.parametrize("decimals", [0, 3, 5])
def test_writer_round_trips_to_the_printed_precision(tmp_path, nexus, decimals):
    take = nexus[0]
    first, second = tmp_path / "a.csv", tmp_path / "b.csv"
    write_vicon_csv(take, first, decimals=decimals)
    back = read_vicon_csv(first)
    assert (back.labels, back.rate, back.first_frame) == (take.labels, take.rate,
                                                          take.first_frame)
    np.testing.assert_array_equal(back.missing, take.missing)
    assert np.nanmax(np.abs(back.positions - take.positions)) <= 0.5 * 10.0 ** -decimals + EXACT_MM
    write_vicon_csv(back, second, decimals=decimals)
    assert first.read_bytes() == second.read_bytes()


def test_writer_layout_is_nexus(tmp_path):
    pos = random_positions(4, 2)
    take = Take(("S:a", "S:b"), pos, rate=119.88, first_frame=0)
    path = tmp_path / "out.csv"
    write_vicon_csv(take, path)
    raw = path.read_bytes()
    assert raw.count(b"\r\n") == raw.count(b"\n") == 9
    rows = list(csv.reader(raw.decode().splitlines()))
    assert {len(row) for row in rows} == {8}
    assert rows[0][0] == "Trajectories" and float(rows[1][0]) == 119.88
    assert rows[2] == ["", "", "S:a", "", "", "S:b", "", ""]
    assert rows[3] == ["Frame", "Sub Frame", "X", "Y", "Z", "X", "Y", "Z"]
    assert rows[4] == ["", ""] + ["mm"] * 6
    for t, row in enumerate(rows[5:]):
        assert row[:2] == [str(t), "0"]
        for m in range(2):
            cells = row[2 + 3 * m: 5 + 3 * m]
            if np.isnan(pos[t, m, 0]):
                assert cells == ["", "", ""]
            else:
                np.testing.assert_allclose([float(c) for c in cells], pos[t, m],
                                           atol=VICON_CSV_CELL_MM)
    assert read_vicon_csv(path).rate == 119.88


def test_io_write_dispatches_to_the_csv_writer(tmp_path):
    take = Take(("a",), random_positions(3, 1), rate=50)
    mocap.io.write(take, tmp_path / "t.csv")
    np.testing.assert_allclose(mocap.io.read(tmp_path / "t.csv").positions, take.positions,
                               atol=VICON_CSV_CELL_MM)


def test_writer_refuses_to_overwrite_an_input(tmp_path):
    take = Take(("a",), np.zeros((2, 1, 3)), rate=50)
    path = write_bytes(tmp_path, "\n".join(GOOD))
    with pytest.raises(InputError, match="refusing to overwrite an input file"):
        write_vicon_csv(take, path, inputs=[path])
    assert path.read_text() == "\n".join(GOOD)


@pytest.mark.parametrize("label", ["a,b", "", " a", "a\nb"])
def test_writer_rejects_labels_it_cannot_write(tmp_path, label):
    take = Take((label,), np.zeros((2, 1, 3)), rate=50)
    with pytest.raises(MarkerError, match="cannot be written to a Vicon CSV file"):
        write_vicon_csv(take, tmp_path / "x.csv")
    assert not list(tmp_path.iterdir())


def test_writer_rejects_bad_arguments(tmp_path):
    with pytest.raises(InputError, match="take must be a mocap.Take, got ndarray"):
        write_vicon_csv(np.zeros((2, 1, 3)), tmp_path / "x.csv")
    take = Take(("a",), np.zeros((2, 1, 3)), rate=50)
    with pytest.raises(InputError, match="decimals must be at least 0"):
        write_vicon_csv(take, tmp_path / "x.csv", decimals=-1)


@pytest.mark.parametrize("decimals", [0, 2, 5])
def test_writer_cells_match_python_formatting(tmp_path, decimals):
    rng = np.random.default_rng(3)
    scale = 10.0 ** rng.integers(-6, 6, (50, 4, 1))
    pos = rng.normal(0, 1, (50, 4, 3)) * scale
    pos[rng.random((50, 4)) < 0.2] = np.nan
    pos[0, 0] = [0.0, -0.0, -1e-9]
    path = tmp_path / "f.csv"
    write_vicon_csv(Take(("a", "b", "c", "d"), pos, rate=100, first_frame=-3), path,
                    decimals=decimals)
    rows = list(csv.reader(path.read_text().splitlines()))[5:]
    for t, row in enumerate(rows):
        assert row[:2] == [str(t - 3), "0"]
        for cell, value in zip(row[2:], pos[t].ravel()):
            text = "" if np.isnan(value) else f"{value:.{decimals}f}"
            if text.startswith("-") and not text.strip("-0."):
                text = text[1:]  # the writer never prints "-0"
            assert cell == text


def test_writer_rejects_values_too_large_for_the_decimals(tmp_path):
    take = Take(("a",), np.full((2, 1, 3), 3e13), rate=50)
    with pytest.raises(InputError, match="values up to 3e\\+13 cannot be written with 5 "
                                         "decimals"):
        write_vicon_csv(take, tmp_path / "x.csv")


@pytest.mark.parametrize("encoding", ["utf-8-sig", "latin-1"])
def test_reads_non_ascii_labels_and_a_bom(tmp_path, encoding):
    pos = random_positions(3, 1)
    path = tmp_path / "take.csv"
    path.write_bytes(nexus_text(("Daphnée:épaule",), pos).encode(encoding))
    take = read_vicon_csv(path)
    assert take.labels == ("Daphnée:épaule",)
    np.testing.assert_array_equal(take.positions, pos)


def test_unreadable_file_is_a_file_format_error(tmp_path):
    with pytest.raises(FileFormatError, match="cannot read Vicon CSV file: no such file"):
        read_vicon_csv(tmp_path / "absent.csv")
