"""`mocap2mesh init`: the files it writes, that the chain runs on them, and every error path of
stabilization and open questions in the marker set, the landmarks and the run configuration."""

import dataclasses
import json

import numpy as np
import pytest
from foreign_captures import PREFIX, facial_sing, ict_capture
from helpers import ICT_LANDMARKS_TOML

import mocap
from fit.cli.main import main
from fit.pipeline import Reconstruction
from fit.pipeline.config import STAGE_TABLES, load_run_config, stage_options
from fit.pipeline.initialize import initialize
from fit.pipeline.template import field_docs, run_config_text, toml_value
from mocap import FileFormatError, InputError, MarkerError
from mocap.markerset import REQUIRED_REGIONS, load_markerset
from mocap.mesh.landmarks import load_mesh_landmarks
from mocap.util.toml import read_toml

#: The required regions of a marker set (TOML): two lip markers and three others.
_MEMBERS = {"upper_lip": ["u1"], "lower_lip": ["l1"], "other": ["o1", "o2", "o3"]}
REGIONS = "\n[regions]\n" + "".join(f"{region} = {json.dumps(_MEMBERS.get(region, []))}\n"
                                    for region in REQUIRED_REGIONS)


def one_line_error(capsys, argv, match):
    """Run the CLI: exit code 1 and one line on stderr matching `match`."""
    assert main(argv) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and match in err[0], err
    return err[0]


@pytest.fixture(scope="module")
def sing_capture(tmp_path_factory, facial_sing_take, facial_sing_markerset):
    """facial-sing.c3d renamed, prefixed and without its head markers, as a C3D file."""
    foreign = facial_sing(facial_sing_take, facial_sing_markerset, keep_head=False)
    path = tmp_path_factory.mktemp("capture") / "stranger.c3d"
    mocap.write(foreign.take, path)
    return path


@pytest.fixture(scope="module")
def sing_init(tmp_path_factory, sing_capture, ict_neutral_path, ict_expressions_dir):
    out = tmp_path_factory.mktemp("init")
    return initialize(sing_capture, ict_neutral_path, out, shapes=ict_expressions_dir), out


# ---------------------------------------------------------------- what init writes

def test_init_writes_a_marker_set_landmarks_and_a_complete_run_config(sing_init):
    done, out = sing_init
    assert set(done.files) == {"markerset.toml", "landmarks.toml", "run.toml", "init.png",
                               "mesh_landmarks.png"}
    assert not done.questions
    markerset = load_markerset(out / "markerset.toml")
    assert markerset.prefix == PREFIX and markerset.head == ()
    assert len(markerset.stabilization) >= 3 and "Mouth_Lend" in markerset.face_markers
    assert markerset.landmarks["mouth_corner_left"] == "Mouth_Lend"
    config = load_run_config(out / "run.toml")
    assert config.ingest.stabilize == "auto" and config.mesh_units == "cm"
    for table in STAGE_TABLES:
        if table != "ingest":
            assert config.options(table) == STAGE_TABLES[table](), table
    text = (out / "run.toml").read_text()
    for table, cls in STAGE_TABLES.items():
        for f in dataclasses.fields(cls):
            assert f"\n{f.name} = " in text or f"\n# {f.name} = " in text, (table, f.name)
    landmarks = load_mesh_landmarks(out / "landmarks.toml")
    assert {"mouth_corner_left", "eye_outer_right", "upper_lip_top"} <= set(landmarks)
    assert any("stabilize = 'auto'" in line for line in done.lines)


def test_the_chain_runs_on_what_init_wrote(tmp_path, ict_basis, arkit_performance, ict_layout,
                                          ict_markerset, ict_neutral_path,
                                          ict_expressions_dir):
    foreign = ict_capture(ict_basis, arkit_performance, ict_layout, ict_markerset,
                          keep_head=False, duration=6.0)
    capture = tmp_path / "take.c3d"
    mocap.write(foreign.take, capture)
    done = initialize(capture, ict_neutral_path, tmp_path / "init", shapes=ict_expressions_dir)
    assert not done.questions
    result = Reconstruction.from_config(tmp_path / "init" / "run.toml").process(capture)
    assert result.ingested.head_frame.method == "auto"
    assert result.errors["H"].summary()["alpha"] < 5.0
    assert list(result.weights["H"].index[:2]) == [1, 2]


def test_every_option_of_every_table_is_documented():
    """run.toml's comments come from the option classes' docstrings: a key without one
    would be written '(undocumented)'."""
    for table, cls in STAGE_TABLES.items():
        docs = field_docs(cls)
        missing = [f.name for f in dataclasses.fields(cls) if f.name not in docs]
        assert not missing, (table, missing)


def test_a_run_config_of_defaults_reads_back_as_the_defaults(tmp_path):
    text = run_config_text({})
    doc = read_toml(_write(tmp_path, "run.toml", text), "run configuration")
    for table, cls in STAGE_TABLES.items():
        assert stage_options(table, doc.get(table, {})) == (
            dataclasses.replace(cls(), stabilize="head") if table == "ingest" else cls())


def test_template_refuses_what_toml_cannot_say():
    with pytest.raises(InputError, match="has no TOML literal"):
        toml_value(float("nan"))
    with pytest.raises(InputError, match=r"\[fit\] has no key 'spaces'"):
        run_config_text({}, options={"fit": {"spaces": "mesh"}})


# ---------------------------------------------------------------- open questions

def test_run_refuses_a_config_with_an_open_question(tmp_path, capsys, sing_capture,
                                                    ict_neutral_path):
    done = initialize(sing_capture, ict_neutral_path, tmp_path)        # no --shapes
    assert [q.key for q in done.questions] == ["basis"]
    one_line_error(capsys, ["run", str(tmp_path / "run.toml")],
                   "open question 'basis' of this run configuration is not answered")


def test_open_questions_in_a_marker_set_and_in_mesh_landmarks_are_refused(tmp_path):
    ms = _write(tmp_path, "ms.toml", 'head = []\n[open_questions]\nup = "which way?"\n' + REGIONS)
    with pytest.raises(FileFormatError, match="open question 'up' of this marker set is not "
                                              "answered: which way"):
        load_markerset(ms)
    lm = _write(tmp_path, "lm.toml", '[landmarks]\nnose_tip = 3\n[open_questions]\n'
                                     'chin = "where?"\n')
    with pytest.raises(FileFormatError, match="open question 'chin' of this mesh-landmark file"):
        load_mesh_landmarks(lm)
    bad = _write(tmp_path, "bad.toml", 'head = []\nopen_questions = "no"\n' + REGIONS)
    with pytest.raises(FileFormatError, match=r"\[open_questions\] must be a table"):
        load_markerset(bad)


def test_init_does_not_overwrite_an_earlier_init(sing_init, capsys, sing_capture,
                                                 ict_neutral_path):
    _, out = sing_init
    one_line_error(capsys, ["init", str(sing_capture), "--mesh", str(ict_neutral_path),
                            "-o", str(out)], "exists (an earlier init?)")


def test_init_prints_what_it_inferred(tmp_path, capsys, sing_capture, ict_neutral_path,
                                     ict_expressions_dir):
    assert main(["init", str(sing_capture), "--mesh", str(ict_neutral_path), "--shapes",
                 str(ict_expressions_dir), "-o", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "subject prefix 'Subject:' stripped" in out
    assert "not kept: Subject:Unlabeled1: an unlabeled marker" in out
    assert "head markers: none found; stabilize = 'auto'" in out
    assert "mouth_corner_left    Subject:Mouth_Lend" in out


# ---------------------------------------------------------------- marker sets without a head

def _write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_a_marker_set_without_head_markers_is_valid(tmp_path):
    ms = load_markerset(_write(tmp_path, "ms.toml", 'head = []\nprefix = "S:"\n'
                                                    'stabilization = ["o1", "o2", "o3"]\n'
                                                    + REGIONS))
    assert ms.head == () and "head" not in ms.clusters and ms.stabilization == ("o1", "o2", "o3")
    take = mocap.Take(("S:u1", "S:l1", "S:o1", "S:o2", "S:o3"), np.zeros((2, 5, 3)), 100.0)
    assert ms.own_labels(take).labels == ("u1", "l1", "o1", "o2", "o3")


@pytest.mark.parametrize(("text", "match"), [
    ('head = []\nstabilization = ["o1", "o2"]\n', "stabilization must name 3 or more face "
                                                  "markers"),
    ('head = ["h1", "h2", "h3"]\nstabilization = ["h1", "o1", "o2"]\n',
     r"not face markers: \['h1'\]"),
    ('head = ["h1", "h2"]\n', r"head names 2 markers; a rigid head fit needs at least 3 "
                              r"\(or list none"),
    ('head = []\nprefix = 3\n', "prefix must be a string"),
])
def test_marker_set_errors(tmp_path, text, match):
    with pytest.raises(FileFormatError, match=match):
        load_markerset(_write(tmp_path, "ms.toml", text + REGIONS))


def test_a_stripped_label_that_clashes_is_refused(tmp_path):
    ms = load_markerset(_write(tmp_path, "ms.toml", 'head = []\nprefix = "S:"\n' + REGIONS))
    take = mocap.Take(("S:u1", "u1"), np.zeros((2, 2, 3)), 100.0)
    with pytest.raises(MarkerError, match="is 'u1' without the prefix 'S:', and the take has "
                                          "that label too"):
        ms.own_labels(take)


# ---------------------------------------------------------------- stabilization in run.toml

def test_run_config_takes_the_stabilization():
    assert stage_options("ingest", {"stabilize": "none"}).stabilize == "none"
    assert stage_options("ingest", {"robust_stabilization": False}).robust_stabilization is False
    with pytest.raises(InputError, match="ingest.stabilize: the chain always stabilizes"):
        stage_options("ingest", {"stabilize": False})
    with pytest.raises(InputError, match="ingest.robust_guard_deg"):
        stage_options("ingest", {"robust_guard_deg": -1})


def test_reconstruction_refuses_head_stabilization_without_head_markers(sing_init,
                                                                         ict_neutral_path):
    _, out = sing_init
    with pytest.raises(InputError, match="names no head markers: set ingest.stabilize = "
                                         "'auto'"):
        Reconstruction(markerset=out / "markerset.toml", mesh=ict_neutral_path,
                       mesh_units="cm", landmarks=out / "landmarks.toml",
                       basis=out.parent, ingest={"stabilize": "head"})


# ---------------------------------------------------------------- the CLI's --stabilize

def test_cli_stabilize_auto_and_none(tmp_path, capsys, sing_init, sing_capture):
    _, out = sing_init
    ms = str(out / "markerset.toml")
    with pytest.warns(UserWarning, match="robust and the plain rigid fits"):   # it sings
        assert main(["ingest", str(sing_capture), "-o", str(tmp_path / "auto.npz"),
                     "--markerset", ms, "--stabilize", "auto", "-v"]) == 0
    printed = capsys.readouterr().out
    assert "stabilization markers (auto)" in printed and "residual median" in printed
    head = np.load(tmp_path / "auto.head.npz")
    assert str(head["method"]) == "auto" and len(head["head_markers"]) >= 3
    with pytest.warns(UserWarning, match="stabilize = 'none' takes"):
        assert main(["ingest", str(sing_capture), "-o", str(tmp_path / "none.npz"),
                     "--markerset", ms, "--stabilize", "none"]) == 0
    one_line_error(capsys, ["ingest", str(sing_capture), "-o", str(tmp_path / "h.npz"),
                            "--markerset", ms, "--stabilize"],
                   "stabilize = 'head' needs a marker set naming the head markers")
    assert main(["ingest", str(sing_capture), "-o", str(tmp_path / "x.npz"),
                 "--stabilize", "sideways"]) == 2


def test_bind_and_retarget_take_the_stabilization(tmp_path, sing_init, sing_capture,
                                                  ict_neutral_path):
    _, out = sing_init
    common = ["--markerset", str(out / "markerset.toml"), "--mesh", str(ict_neutral_path)]
    binding = tmp_path / "binding.json"
    with pytest.warns(UserWarning):        # markers off the ICT face, and the singing face
        assert main(["bind", str(sing_capture), *common, "--landmarks",
                     str(out / "landmarks.toml"), "-o", str(binding), "--stabilize", "auto",
                     "--head-frame"]) == 0
        assert main(["retarget", str(sing_capture), *common, "--binding", str(binding),
                     "-o", str(tmp_path / "mesh.npz"), "--stabilize", "auto",
                     "--no-robust-stabilization", "--max-gap", "192"]) == 0   # the longest gap
    assert np.load(tmp_path / "mesh.npz")["vertices"].shape[1:] == (9409, 3)


def test_init_with_the_meshs_own_landmarks(tmp_path, sing_capture, ict_neutral_path,
                                           ict_expressions_dir):
    done = initialize(sing_capture, ict_neutral_path, tmp_path, shapes=ict_expressions_dir,
                      landmarks=ICT_LANDMARKS_TOML)
    assert "landmarks.toml" not in done.files and not done.inference.mesh_landmarks.found
    config = load_run_config(tmp_path / "run.toml")
    assert config.landmarks == ICT_LANDMARKS_TOML.resolve()
    points = {p.point for p in done.inference.landmarks}
    assert {"brow_inner_left", "nose_tip", "mouth_corner_left"} <= points

