"""Hostile files and unwritable outputs: refused early, cheaply, by our errors, in one line.

Each case here once ended in a memory bomb, a bare traceback or a write in the
wrong place (the reliability issue's probe); the fuzz test (test_fuzz.py)
covers the same readers at random.
"""

from __future__ import annotations

import errno
import io
import json
import os
import subprocess
import sys
import tracemalloc
import warnings
import zipfile

import numpy as np
import pytest
from helpers import FACIAL_SING_MARKERSET_TOML

import mocap
from fit.cli.main import main
from fit.demo import make_demo_session
from fit.pipeline.stages import complete_span
from fit.report.views import plot_frame_views
from mocap import Take
from mocap.bind import load_binding
from mocap.clean.ingest import IngestOptions, ingest
from mocap.clean.resampling import resample
from mocap.errors import FileFormatError, InputError, MarkerError
from mocap.io.c3d import read_c3d, read_c3d_parameters, write_c3d
from mocap.io.trc import read_trc
from mocap.io.vicon_csv import read_vicon_csv
from mocap.markerset import load_markerset
from mocap.mesh.mesh import load_mesh
from mocap.util.budget import max_bytes
from mocap.util.npz import read_npz

NEXUS_HEAD = "Trajectories\n100\n,,a,,\nFrame,Sub Frame,X,Y,Z\n,,mm,mm,mm\n"
TRC_HEAD = ("PathFileType\t4\t(X/Y/Z)\ta.trc\nDataRate\tCameraRate\tNumFrames\tNumMarkers\t"
            "Units\n100\t100\t3\t1\tmm\nFrame#\tTime\ta\t\t\n\t\tX1\tY1\tZ1\n\n")
REGIONS = ("[regions]\nupper_lip=[]\nlower_lip=[]\nleft_brow=[]\nright_brow=[]\nleft_eye=[]\n"
           "right_eye=[]\nother=[\"d\"]\n")


def _peak_mb(fn) -> float:
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()


# --------------------------------------------------------------- memory bombs

def test_width_zero_char_parameter_claims_nothing(tmp_path):
    """POINT:LABELS of dimensions 0 x 255 x 255 x 255 (16.6 million empty strings)."""
    write_c3d(Take(("a", "b"), np.zeros((5, 2, 3)), 100.0), tmp_path / "a.c3d")
    buf = bytearray((tmp_path / "a.c3d").read_bytes())
    body = buf.find(b"LABELS") + len(b"LABELS") + 2
    buf[body + 1:body + 6] = bytes([4, 0, 255, 255, 255])
    (tmp_path / "b.c3d").write_bytes(buf)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        assert _peak_mb(lambda: read_c3d(tmp_path / "b.c3d")) < 5
        assert read_c3d(tmp_path / "b.c3d").labels == ("point1", "point2")
        assert read_c3d_parameters(tmp_path / "b.c3d")["POINT"]["LABELS"] == ()


@pytest.mark.parametrize("reader, name, head, row, line", [
    (read_vicon_csv, "a.csv", NEXUS_HEAD, "{},0,1,2,3\n", 8),
    (read_trc, "a.trc", TRC_HEAD, "{}\t0\t1\t2\t3\n", 9),
])
def test_a_jump_in_frame_numbers_is_not_allocated(tmp_path, reader, name, head, row, line):
    path = tmp_path / name
    path.write_text(head + row.format(1) + row.format(2) + row.format(2_000_000))
    with pytest.raises(FileFormatError, match=rf"at line {line}: positions of 2000000 frames "
                       r"\(frame numbers 1 to 2000000, 1999997 of them absent; the largest "
                       r"jump: 2 to 2000000\) x 1 markers would take 48 MB, more than the "
                       r"file's contents justify"):
        reader(path)


def test_a_few_dropped_frames_are_still_read_as_missing(tmp_path):
    path = tmp_path / "a.csv"
    path.write_text(NEXUS_HEAD + "".join(f"{i},0,1,2,3\n" for i in (1, 2, 5, 6)))
    with pytest.warns(UserWarning, match="2 frame"):
        take = read_vicon_csv(path)
    assert take.n_frames == 6 and np.isnan(take.positions[2:4]).all()


def test_a_row_of_a_million_commas_costs_its_bytes(tmp_path):
    path = tmp_path / "a.csv"
    rows = "".join(f"{i},0,1,2,3\n" for i in range(1, 300))
    path.write_text(NEXUS_HEAD + rows + "300,0,1,2,3" + "," * 1_000_000 + "\n")
    assert _peak_mb(lambda: read_vicon_csv(path)) < 20
    assert read_vicon_csv(path).positions.shape == (300, 1, 3)


def test_a_value_past_the_last_column_names_its_line(tmp_path):
    path = tmp_path / "a.csv"
    path.write_text(NEXUS_HEAD + "1,0,1,2,3\n2,0,1,2,3,,,7\n")
    with pytest.raises(FileFormatError, match=r"at line 7: the row has values after its last "
                                              r"column \(Z of a\); expected 5 columns"):
        read_vicon_csv(path)


def test_a_carriage_return_inside_a_row_names_its_line(tmp_path):
    path = tmp_path / "a.csv"
    path.write_text(NEXUS_HEAD + "1,0,1,2,3\r\n2,0,1,2\r,3\r\n", newline="")
    with pytest.raises(FileFormatError, match="at line 7: a carriage return inside a row"):
        read_vicon_csv(path)


@pytest.mark.parametrize("reader, name, text", [
    (read_vicon_csv, "a.csv", NEXUS_HEAD + '1,0,"1,2,3\n2,0,1,2,3\n'),
    (read_trc, "a.trc", TRC_HEAD + '1\t0\t"1\t2\t3\n'),
])
def test_a_quote_is_a_character_of_its_cell(tmp_path, reader, name, text):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(FileFormatError, match=r"cell '\"1' in column 3 \(X of a\) is not a "
                                              "finite number"):
        reader(path)


def _npz_with_header(path, shape, descr="<f8", data=b"\0" * 480):
    out = io.BytesIO()
    np.lib.format.write_array_header_1_0(out, {"descr": descr, "fortran_order": False,
                                               "shape": shape})
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("positions.npy", out.getvalue() + data)


def test_an_npz_header_claiming_a_billion_frames_is_refused_before_allocating(tmp_path):
    _npz_with_header(tmp_path / "a.npz", (1_000_000_000, 40, 3))
    with pytest.raises(FileFormatError, match=r"member 'positions.npy' claims shape "
                                              r"\(1000000000, 40, 3\) of float64 "
                                              r"\(960000000000 bytes\), more than it holds"):
        read_npz(tmp_path / "a.npz", "take archive")


def test_npz_members_that_are_not_plain_arrays(tmp_path):
    _npz_with_header(tmp_path / "o.npz", (3,), descr="|O")
    with pytest.raises(FileFormatError, match="holds Python objects, which are never unpickled"):
        read_npz(tmp_path / "o.npz", "take archive")
    with zipfile.ZipFile(tmp_path / "b.npz", "w") as archive:
        archive.writestr("notes.txt", "x" * 100)
    with pytest.raises(FileFormatError, match=r"member 'notes.txt' is not a NumPy array"):
        read_npz(tmp_path / "b.npz", "take archive")


@pytest.mark.parametrize("damage", [b"{", b"(", b"'"])
def test_an_npz_header_that_python_cannot_tokenize(tmp_path, damage):
    """numpy parses a 1.0 header as Python: an unclosed bracket or string ends in a TokenError
    or SyntaxError of the tokenizer, which must come out as our error (seen in the fuzz)."""
    out = io.BytesIO()
    np.lib.format.write_array(out, np.arange(3.0))
    raw = bytearray(out.getvalue())
    end = raw.index(b"}")
    raw[end:end + 1] = damage
    with zipfile.ZipFile(tmp_path / "t.npz", "w") as archive:
        archive.writestr("positions.npy", bytes(raw))
    with pytest.raises(FileFormatError, match=r"t\.npz: cannot read take archive"):
        read_npz(tmp_path / "t.npz", "take archive")


def test_the_global_limit_names_its_variable(tmp_path, monkeypatch):
    write_c3d(Take(("a",), np.zeros((50_000, 1, 3)), 100.0), tmp_path / "a.c3d")
    monkeypatch.setenv("MOCAP2MESH_MAX_BYTES", "1M")
    with pytest.raises(FileFormatError, match=r"the samples of 50000 frames x 1 points and 0 "
                                              r"analog channels would take 1.2 MB, more than "
                                              r"MOCAP2MESH_MAX_BYTES \(1.05 MB\)"):
        read_c3d(tmp_path / "a.c3d")
    monkeypatch.setenv("MOCAP2MESH_MAX_BYTES", "lots")
    with pytest.raises(InputError, match="MOCAP2MESH_MAX_BYTES must be a positive number"):
        max_bytes()


def test_resampling_far_above_the_take_rate_is_refused():
    take = Take(("a",), np.zeros((100, 1, 3)), 100.0)
    with pytest.raises(InputError, match=r"rate 1e\+07 Hz is more than 16 times the take's "
                                         "100 Hz"):
        resample(take, 1e7)
    assert resample(take, 1600.0).n_frames == 1585


# --------------------------------------------------------- bare tracebacks

@pytest.mark.parametrize("text, match", [
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9223372036854775808\n",
     "line 4: face indices are not integers of at most 64 bits"),
    ("v 0 0 0\nv 1 0 0\nv 0 1e200 0\nf 1 2 3\n", r"coordinates beyond ±1e\+15"),
])
def test_obj_numbers_out_of_range(tmp_path, text, match):
    (tmp_path / "a.obj").write_text(text)
    with pytest.raises(FileFormatError, match=match):
        load_mesh(tmp_path / "a.obj")


@pytest.mark.parametrize("edit, match", [
    (lambda doc: doc.update(face_ids=[1e30]), "bad or missing binding field"),
    (lambda doc: doc.update(labels="[" * 100_000), None),
])
def test_binding_fields_out_of_range(tmp_path, edit, match):
    doc = {"format": "mocap2mesh-binding-1", "labels": ["a"], "scale": 1.0,
           "rotation": np.eye(3).tolist(), "translation": [0, 0, 0], "face_ids": [0],
           "vertex_ids": [[0, 1, 2]], "barycentric": [[1, 0, 0]], "distances_mm": [0.0],
           "rms_mm": 0.0, "skin_offset_mm": 0.0, "n_landmarks": 3, "n_iterations": 1,
           "converged": True, "message": ""}
    edit(doc)
    text = json.dumps(doc) if match else "[" * 100_000 + "]" * 100_000
    (tmp_path / "b.json").write_text(text)
    with pytest.raises(FileFormatError, match=match or "not a binding file: JSON nested too "
                                                       "deeply"):
        load_binding(tmp_path / "b.json")


@pytest.mark.parametrize("text, match", [
    ('head=["a","b","c"]\nclusters=["x"]\n' + REGIONS, r"\[clusters\] must be a table, got "
                                                       r"\['x'\]"),
    ('head=["a","b","c"]\n' + REGIONS + '[landmarks]\nnose_tip=["d"]\n',
     r"landmark 'nose_tip' must name one marker \(a string\), got \['d'\]"),
    ('head=["a","b","c"]\nname=3\n' + REGIONS, "name must be a string, got 3"),
    ("x=" + "[" * 10_000 + "]" * 10_000 + "\n", "marker set nests arrays or tables too deeply"),
])
def test_marker_set_values_of_the_wrong_type(tmp_path, text, match):
    (tmp_path / "m.toml").write_text(text)
    with pytest.raises(FileFormatError, match=match):
        load_markerset(tmp_path / "m.toml")


def test_text_that_is_not_utf8_names_the_byte(tmp_path):
    (tmp_path / "m.toml").write_bytes(b'name = "Daphn\xe9e"\n')
    with pytest.raises(FileFormatError, match=r"m.toml at byte 13: marker set is not UTF-8 "
                                              r"text \(invalid continuation byte: byte 0xe9\)"):
        load_markerset(tmp_path / "m.toml")


def test_paths_no_file_system_takes(tmp_path):
    with pytest.raises(InputError, match="holds a NUL character"):
        mocap.read(str(tmp_path / "a\0b.c3d"))
    with pytest.raises(FileFormatError, match="cannot read marker set: path .* holds a NUL"):
        load_markerset(str(tmp_path / "a\0b.toml"))
    with pytest.raises(FileFormatError, match="cannot read C3D file: File name too long"):
        mocap.read(tmp_path / ("x" * 300 + ".c3d"))


def test_a_take_whose_filled_codes_are_not_integers():
    with pytest.raises(InputError, match="filled must hold integer fill-method codes, got "
                                         "float64"):
        Take(("a",), np.zeros((2, 1, 3)), 100.0, filled=np.full((2, 1), np.nan))


# ------------------------------------------------------------------ numerics

def test_an_empty_take_is_refused_before_stabilizing():
    markerset = load_markerset(FACIAL_SING_MARKERSET_TOML)
    take = Take(markerset.markers, np.zeros((0, len(markerset.markers), 3)), 100.0)
    with pytest.raises(InputError, match="the take: the take has no frames"):
        ingest(take, markerset=markerset, options=IngestOptions(stabilize=True))


def test_a_marker_missing_from_the_whole_take_is_named():
    positions = np.ones((4, 3, 3))
    positions[:, 1] = np.nan
    with pytest.raises(MarkerError, match="marker 'b': is missing in every frame of the take"):
        complete_span(Take(("a", "b", "c"), positions, 100.0), ("a", "b", "c"))


# ---------------------------------------------------------------------- plots

def test_labels_are_drawn_as_plain_text_and_absurd_values_refused(tmp_path):
    rng = np.random.default_rng(0)
    neutral = rng.normal(size=(4, 3)) * 30
    captured = neutral + rng.normal(size=(6, 4, 3))
    labels = ("$\\frac{a}{$", "b$", "$x$", "d")
    plot_frame_views(captured, captured + 0.5, [1, 2], tmp_path / "v.png", neutral=neutral,
                     labels=labels)
    assert (tmp_path / "v.png").stat().st_size > 1000
    captured[3, 2, 1] = 1e30
    with pytest.raises(InputError, match=r"captured positions: marker '\$x\$' at frame 3 is "
                                         r"1e\+30, beyond ±1e\+06: not plotted"):
        plot_frame_views(captured, captured, [1], tmp_path / "w.png", neutral=neutral,
                         labels=labels)


# ------------------------------------------------------------------- the CLI

@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = tmp_path_factory.mktemp("hostile")
    make_demo_session(root / "session", seconds=2.0)
    return root / "session"


def _one_line_error(capsys, command: str, match: str) -> None:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"mocap2mesh {command}: error: "), err
    assert match in err[0], err[0]


UNWRITABLE = "/sys/mocap2mesh-cannot-write-here"


def test_unwritable_output_folders_are_one_line(session, tmp_path, capsys):
    assert main(["ingest", str(session / "capture.c3d"), "-o", str(tmp_path / "t.npz"),
                 "--markerset", str(session / "markerset.toml"), "--stabilize",
                 "--qa", f"{UNWRITABLE}/qa"]) == 1
    _one_line_error(capsys, "ingest", UNWRITABLE)
    assert main(["demo", "-o", UNWRITABLE, "--seconds", "1"]) == 1
    _one_line_error(capsys, "demo", UNWRITABLE)


def test_a_read_only_file_system_or_a_full_disk_is_one_line(session, tmp_path, capsys,
                                                            monkeypatch):
    def refuse(src, dst):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(dst))

    monkeypatch.setattr(os, "replace", refuse)
    assert main(["ingest", str(session / "capture.c3d"), "-o", str(tmp_path / "t.npz")]) == 1
    _one_line_error(capsys, "ingest", "t.npz: cannot write: Read-only file system")


def test_nul_and_overlong_names_on_the_command_line(session, tmp_path, capsys):
    assert main(["info", str(tmp_path / "a\0b.c3d")]) == 1
    _one_line_error(capsys, "info", "holds a NUL character")
    assert main(["ingest", str(session / "capture.c3d"), "-o",
                 str(tmp_path / ("x" * 300 + ".npz"))]) == 1
    _one_line_error(capsys, "ingest", "File name too long")


def test_basis_never_writes_into_its_own_input_directory(session, capsys):
    before = sorted(p.name for p in (session / "shapes").iterdir())
    assert main(["basis", str(session / "capture.c3d"), "--neutral",
                 str(session / "neutral.obj"), "--shapes", str(session / "shapes"),
                 "-o", str(session / "shapes"), "--binding", str(session / "nope.json"),
                 "--markerset", str(session / "markerset.toml")]) == 1
    _one_line_error(capsys, "basis", "refusing to write inside the input directory")
    assert sorted(p.name for p in (session / "shapes").iterdir()) == before


def test_a_closed_pipe_ends_quietly(tmp_path):
    labels = tuple(f"marker-{i:04d}" for i in range(4000))   # more lines than a pipe holds
    write_c3d(Take(labels, np.zeros((2, len(labels), 3)), 100.0), tmp_path / "many.c3d")
    command = "from fit.cli.main import console; console()"
    pipe = subprocess.run(["bash", "-c", f"{sys.executable} -c '{command}' info "
                           f"{tmp_path / 'many.c3d'} | head -3; exit ${{PIPESTATUS[0]}}"],
                          capture_output=True, text=True, check=False)
    assert len(pipe.stdout.splitlines()) == 3 and pipe.stderr == ""
    assert pipe.returncode == 141


def test_the_console_imports_with_the_collector_off_and_runs_with_it_on():
    """The console entry point makes the command's imports with the collector off, then
    freezes them: the command runs with the collector on."""
    command = ("import atexit, gc, json, sys; import fit.cli.main; "
               "cli = sys.modules['fit.cli.main']; seen = []; "
               "real = cli.build_parser; "
               "cli.build_parser = lambda argv: seen.append(gc.isenabled()) or real(argv); "
               "atexit.register(lambda: print(json.dumps({'importing': seen, "
               "'after': gc.isenabled(), 'frozen': gc.get_freeze_count()}))); "
               "cli.console()")
    done = subprocess.run([sys.executable, "-c", command, "info", "--help"],
                          capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
    state = json.loads(done.stdout.strip().splitlines()[-1])
    # (main builds the parser again, the command already imported)
    assert state["importing"][0] is False and state["after"] and state["frozen"] > 10_000


def test_the_console_ends_with_all_it_printed_written(tmp_path):
    """The console entry point leaves the objects of its imports to the process's end:
    what it printed is still flushed whole, and its exit code is the command's."""
    labels = tuple(f"marker-{i:04d}" for i in range(4000))
    write_c3d(Take(labels, np.zeros((2, len(labels), 3)), 100.0), tmp_path / "many.c3d")
    command = "from fit.cli.main import console; console()"
    with open(tmp_path / "out.txt", "w") as out:
        done = subprocess.run([sys.executable, "-c", command, "info", str(tmp_path / "many.c3d")],
                              stdout=out, stderr=subprocess.PIPE, text=True, check=False)
    assert done.returncode == 0 and done.stderr == ""
    printed = (tmp_path / "out.txt").read_text()
    assert all(label in printed for label in labels[-3:]) and printed.endswith("\n")
    failed = subprocess.run([sys.executable, "-c", command, "info", str(tmp_path / "no.c3d")],
                            capture_output=True, text=True, check=False)
    assert failed.returncode == 1 and "mocap2mesh info: error:" in failed.stderr
