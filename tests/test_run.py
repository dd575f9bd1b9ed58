"""``mocap2mesh run``: files, manifest, skip logic, failing takes, configuration errors."""

from __future__ import annotations

import base64
import dataclasses
import hashlib
import importlib.util
import json
import shutil
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from helpers import play_gltf, stub_take
from tolerances import FLOAT32_REL, GLB_PLAYED_MM

import mocap
from fit.cli.main import main
from fit.demo import demo_config_toml, make_demo_session
from fit.exports import read_mesh_sequence
from fit.pipeline import BASES
from fit.pipeline.completion import RECORD_NAME
from fit.pipeline.config import load_run_config
from fit.pipeline.session import run_takes
from mocap.bind import load_binding
from mocap.errors import FileFormatError, InputError

PER_BASIS = ("basis-{}.npz", "weights-{}.csv", "mesh-{}.npz", "face-{}.glb")
PER_TAKE = ("take.c3d", "head_motion.npz", "binding.json", "report/gaps.png",
            "report/head_residuals.png", "report/{take}.html", "report/{take}-alpha.png",
            "report/{take}-coverage.png", "report/{take}-held-out.png", "report/{take}-mesh-WD.png")
REPORT_PER_BASIS = ("heatmap", "markers", "views", "mesh")


#: Frames of the take per frame of the report's video, in these runs.
VIDEO_STEP = 12


def _config(root, captures, *, extra=""):
    text = demo_config_toml().replace('captures = ["session/capture.c3d"]',
                                      "captures = [" + ", ".join(f'"{c}"' for c in captures)
                                      + "]")
    text = text.replace("video_step = 4", f"video_step = {VIDEO_STEP}")
    path = root / "run.toml"
    path.write_text(text + extra, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def session_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("run")
    make_demo_session(root / "session", seconds=2.0, n_gaps=20)   # 10 gaps/s
    (root / "session" / "broken.c3d").write_bytes(b"\x02\x50" + bytes(range(256)) * 4)
    return root


@pytest.fixture(scope="module")
def first_run(session_root):
    path = _config(session_root, ["session/capture.c3d", "session/broken.c3d"])
    code = main(["run", str(path)])
    manifest = json.loads((session_root / "results" / "manifest.json").read_text())
    return code, manifest


def test_every_promised_file_is_written(session_root, first_run):
    _, manifest = first_run
    out = session_root / "results"
    for take in ("capture",):
        record = manifest["takes"][take]
        assert record["status"] == "ok"
        expected = [f.format(take=take) for f in PER_TAKE]
        expected += [f.format(b) for b in BASES for f in PER_BASIS]
        expected += [f"report/{take}-{kind}-{b}.png" for b in BASES for kind in REPORT_PER_BASIS]
        expected.append(f"report/{take}-video.webm")
        for name in expected:
            assert (out / take / name).is_file(), name
            assert f"{take}/{name}" in record["files"]
        assert set(record["metrics"]) == set(BASES)
        assert all(record["metrics"][b]["smoothness"] == 0.0 for b in BASES)  # none asked
        assert record["frames"]["neutral_window"] == 1         # bind.frame "auto": one frame
        first, count = record["frames"]["first"], record["frames"]["count"]
        for b in BASES:      # the capture's frame numbers, as the report's worst-frame table
            worst = record["metrics"][b]["worst_frame"]
            assert first <= worst < first + count
        html = (out / take / "report" / f"{take}.html").read_text()
        for picture in ("gaps.png", "head_residuals.png"):       # ingestion QA embedded
            encoded = base64.b64encode((out / take / "report" / picture).read_bytes())
            assert encoded.decode() in html
        # the video, drawn in parts by the figure helpers and this process and joined, has
        # every frame it draws, and no part is left
        report = out / take / "report"
        assert not [p.name for p in report.iterdir() if p.name.startswith(".")]
        import av
        with av.open(str(report / f"{take}-video.webm")) as video:
            shown = sum(1 for _ in video.decode(video=0))
        assert shown == len(range(0, count, VIDEO_STEP))


def test_outputs_read_back(session_root, first_run):
    out = session_root / "results" / "capture"
    take = mocap.read(out / "take.c3d")
    weights = np.loadtxt(out / "weights-H.csv", delimiter=",", skiprows=1)
    assert len(weights) == take.n_frames
    assert np.all((weights[:, 2:] >= 0) & (weights[:, 2:] <= 1))
    with np.load(out / "mesh-PCA.npz") as z:
        assert z["weights"].shape[0] == take.n_frames
        np.testing.assert_array_equal(z["weights"][:, 0], 1.0)


@pytest.mark.parametrize("basis", BASES)
def test_glb_plays_the_mesh_where_the_head_was(session_root, first_run, basis):
    """face-B.glb played as a viewer does (weights clamped to [0, 1]) is the mesh sequence
    we computed, moved as the stabilization says the head moved: each vertex taken to the
    capture's head frame, moved by R(t), t(t) of head_motion.npz, taken back to the mesh;
    keys on the capture's frame numbers."""
    out = session_root / "results" / "capture"
    played = play_gltf(out / f"face-{basis}.glb")
    sequence = read_mesh_sequence(out / f"mesh-{basis}.npz")
    binding = load_binding(out / "binding.json")
    head = np.load(out / "head_motion.npz")
    start = sequence.first_frame - mocap.read(session_root / "session" / "capture.c3d").first_frame
    rotation = head["rotation"][start:start + sequence.n_frames]
    translation = head["translation"][start:start + sequence.n_frames]
    ours = sequence.vertices()                                      # mm, head frame
    in_head = binding.to_capture(ours.reshape(-1, 3)).reshape(ours.shape)
    moved = np.einsum("tij,tvj->tvi", rotation, in_head) + translation[:, None]
    want = binding.to_mesh(moved.reshape(-1, 3)).reshape(moved.shape)
    np.testing.assert_allclose(played["vertices"] * 1000.0, want, rtol=0, atol=GLB_PLAYED_MM)
    np.testing.assert_allclose(sequence.placed_vertices(), want, rtol=0, atol=GLB_PLAYED_MM)
    assert np.abs(want - ours).max() > 5.0                           # the head does move
    np.testing.assert_allclose(played["times"] * sequence.rate,
                               sequence.first_frame + np.arange(sequence.n_frames),
                               rtol=FLOAT32_REL)
    # make blender-check's reference (numpy only, beside Blender) is this mesh too
    spec = importlib.util.spec_from_file_location(
        "blender_check", Path(__file__).resolve().parents[1] / "bench" / "blender_check.py")
    blender_check = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(blender_check)
    glb = out / f"face-{basis}.glb"
    assert blender_check.reference_for(glb) == out / f"mesh-{basis}.npz"
    reference = blender_check.reference_mesh(out / f"mesh-{basis}.npz")
    assert reference["first_frame"] == sequence.first_frame and reference["moving"]
    np.testing.assert_allclose(reference["frames"], want, rtol=0, atol=GLB_PLAYED_MM)


def test_broken_take_is_reported_and_others_finish(first_run, capsys):
    code, manifest = first_run
    assert code == 1
    broken = manifest["takes"]["broken"]
    assert broken["status"] == "failed" and "broken.c3d" in broken["error"]
    assert manifest["takes"]["capture"]["status"] == "ok"


def test_manifest_hashes(session_root, first_run):
    _, manifest = first_run
    for take in ("capture", "broken"):
        entry = manifest["takes"][take]["capture"]
        with open(entry["path"], "rb") as fh:
            assert entry["sha256"] == hashlib.sha256(fh.read()).hexdigest()
    for role in ("markerset", "mesh", "landmarks"):
        entry = manifest["inputs"][role]
        with open(entry["path"], "rb") as fh:
            assert entry["sha256"] == hashlib.sha256(fh.read()).hexdigest()
    assert manifest["versions"]["numpy"] == np.__version__
    # the report's provenance shows the digests of the run's record, each file read once
    page = (session_root / "results" / "capture" / "report" / "capture.html").read_text()
    files = [manifest["takes"]["capture"]["capture"],
             *(entry for entry in manifest["inputs"].values() if "path" in entry)]
    assert len(files) == 5                      # the capture, its 4 shared inputs
    for entry in files:
        assert f"<td>{entry['path']}</td><td>{entry['sha256']}</td>" in page


def test_package_versions_are_the_installed_ones_in_a_new_dict_each_call():
    from importlib import metadata

    from fit.pipeline.manifest import package_versions

    first = package_versions()
    first["numpy"] = "changed by a caller"
    again = package_versions()
    assert again is not first
    assert again["numpy"] == metadata.version("numpy") == np.__version__
    assert again["scipy"] == metadata.version("scipy")


def test_rerun_of_the_same_config_skips_the_done_take(session_root, first_run):
    path = _config(session_root, ["session/capture.c3d", "session/broken.c3d"])
    outcome = run_takes(load_run_config(path), progress=False)
    assert outcome.takes["capture"]["skipped"] and outcome.takes["capture"]["status"] == "ok"
    assert not outcome.takes["broken"]["skipped"] and outcome.n_failed == 1


def _two_takes(session_root, folder) -> Path:
    """A run configuration of two copies of the demo capture, a.c3d and b.c3d, in `folder`."""
    for name in ("a.c3d", "b.c3d"):
        shutil.copy(session_root / "session" / "capture.c3d", folder / name)
    for name in ("markerset.toml", "neutral.obj", "landmarks.toml"):
        shutil.copy(session_root / "session" / name, folder / name)
    shutil.copytree(session_root / "session" / "shapes", folder / "shapes")
    path = folder / "run.toml"
    path.write_text(demo_config_toml(".", "out").replace("./capture.c3d", "a.c3d\", \"b.c3d")
                    .replace("pca_coverage = 0.995", 'pca_coverage = 0.995\nscope = "take"'))
    return path


def test_takes_side_by_side_leave_the_cores_to_each_other(session_root, monkeypatch,
                                                           tmp_path):
    """One take at a time draws its report with helper processes; takes run side by side
    (here two threads of a pool) draw their figures themselves."""
    calls, helpers = [], []
    monkeypatch.setattr("fit.pipeline.session._guarded", stub_take(calls, helpers=helpers))
    config = load_run_config(_two_takes(session_root, tmp_path))
    run_takes(config, workers=1, progress=False)
    assert helpers == [None, None]              # FigureQueue's default: the spare cores
    with ThreadPoolExecutor(2) as pool:
        run_takes(config, executor=pool, force=True, progress=False)
    assert helpers[2:] == [0, 0] and sorted(calls) == ["a.c3d", "a.c3d", "b.c3d", "b.c3d"]


def test_takes_run_here_load_numba_before_the_inputs(session_root, monkeypatch, tmp_path):
    """The takes' fits load numba where they run: a run whose takes run in this process
    loads it before it reads the inputs (so that the basis's shapes parse compiled); a run
    on a pool leaves it to the pool's workers."""
    from fit.pipeline.reconstruction import Reconstruction

    events = []
    monkeypatch.setattr("fit.pipeline.session._guarded", stub_take([]))
    monkeypatch.setattr("fit.pipeline.session.load_numba", lambda: events.append("numba"))
    original = Reconstruction.from_config.__func__
    monkeypatch.setattr(Reconstruction, "from_config", classmethod(
        lambda cls, config: events.append("inputs") or original(cls, config)))
    config = load_run_config(_two_takes(session_root, tmp_path))
    run_takes(config, workers=1, progress=False)
    assert events == ["numba", "inputs"]
    events.clear()
    with ThreadPoolExecutor(2) as pool:
        run_takes(config, executor=pool, force=True, progress=False)
    assert events == ["inputs"]


def test_the_pretouched_heap_is_kept_for_takes_run_here_and_given_back_otherwise(
        session_root, monkeypatch, tmp_path):
    """The block the console's imports wrote (mocap.util.pretouch) is freed before the
    takes run: its pages kept when they run in this process, given back when they run
    on a pool."""
    kept = []
    monkeypatch.setattr("fit.pipeline.session._guarded", stub_take([]))
    monkeypatch.setattr("fit.pipeline.session.release_pretouch",
                        lambda keep=True: kept.append(keep))
    config = load_run_config(_two_takes(session_root, tmp_path))
    run_takes(config, workers=1, progress=False)
    with ThreadPoolExecutor(2) as pool:
        run_takes(config, executor=pool, force=True, progress=False)
    assert kept == [True, False]


def test_rerun_redoes_only_changed_takes(session_root, monkeypatch, tmp_path):
    """Skip logic alone: the chain is replaced by a stub that records its calls."""
    calls = []
    monkeypatch.setattr("fit.pipeline.session._guarded", stub_take(calls))
    path = _two_takes(session_root, tmp_path)
    config = load_run_config(path)
    assert config.captures[1].name == "b.c3d"
    run_takes(config, workers=1, progress=False)
    assert sorted(calls) == ["a.c3d", "b.c3d"]
    outcome = run_takes(config, workers=1, progress=False)
    assert sorted(calls) == ["a.c3d", "b.c3d"] and outcome.n_skipped == 2
    assert outcome.reasons["a"] == "done by an earlier run; 1 output verified"
    (tmp_path / "b.c3d").write_bytes((tmp_path / "b.c3d").read_bytes() + b"\0")
    outcome = run_takes(config, workers=1, progress=False)
    assert calls[2:] == ["b.c3d"] and outcome.reasons["b"] == "the capture changed"
    assert outcome.takes["a"]["skipped"] and not outcome.takes["b"]["skipped"]
    assert outcome.takes["b"]["capture"]["sha256"] == \
        hashlib.sha256((tmp_path / "b.c3d").read_bytes()).hexdigest()
    (tmp_path / "out" / "a" / "out.txt").unlink()          # a missing output: redo
    outcome = run_takes(config, workers=1, progress=False)
    assert calls[3:] == ["a.c3d"] and outcome.reasons["a"] == "output out.txt is missing"
    text = (tmp_path / "out" / "b" / "out.txt").read_text()   # same size, other bytes
    (tmp_path / "out" / "b" / "out.txt").write_text(text.swapcase())
    outcome = run_takes(config, workers=1, progress=False)
    assert calls[4:] == ["b.c3d"]
    assert outcome.reasons["b"] == "output out.txt changed (SHA-256 differs)"
    path.write_text(path.read_text().replace("video_step = 4", "video_step = 3"))
    outcome = run_takes(load_run_config(path), workers=1, progress=False)   # a parameter
    assert sorted(calls[5:]) == ["a.c3d", "b.c3d"]
    assert outcome.reasons["a"] == "parameter report.video_step changed (4 -> 3)"
    (tmp_path / "out" / "a" / RECORD_NAME).unlink()       # a folder without its record
    outcome = run_takes(load_run_config(path), workers=1, progress=False, check=True)
    assert outcome.checked and outcome.takes["b"]["skipped"]
    assert outcome.takes["a"] == {"skipped": False, "reason": "no completion record (the run "
                                                              "that wrote it did not finish it)"}
    assert len(calls) == 7                                 # a check runs nothing


@pytest.mark.parametrize("edit, match", [
    (lambda t: t.replace('space = "marker"', 'spcae = "marker"'), r"fit\.spcae: unknown key"),
    (lambda t: t.replace('space = "marker"', 'space = "vertex"'), r"fit\.space: space must be"),
    (lambda t: t.replace('space = "marker"', 'space = "marker"\nsmoothness = "auto"'),
     r"fit\.smoothness: smoothness must be a number >= 0 or one of 'gcv', got 'auto'"),
    (lambda t: t.replace('mesh = "session/neutral.obj"\n', ""), r"inputs\.mesh: missing"),
    (lambda t: t.replace("landmarks.toml", "nope.toml"), r"inputs\.landmarks: .* does not exist"),
    (lambda t: t.replace("video_step = 12", "video_step = 0"),
     r"report\.video_step: video_step must be at least 1"),
    (lambda t: t.replace("video_step = 12", 'video_step = "fast"'),
     r"report\.video_step: video_step must be 'auto' or an integer >= 1, got 'fast'"),
    (lambda t: t.replace('frame = "auto"', "frame = -2"), r"bind\.frame: frame must be at least"),
    (lambda t: t.replace("lowpass_hz = 15.0", 'lowpass_hz = "x"'), r"ingest\.lowpass_hz"),
    (lambda t: t.replace('directory = "results"', 'directory = "results"\nworkers = 0'),
     r"output\.workers: workers must be at least 1"),
    (lambda t: t + '\n[run]\nworkers = 0\n', r"run\.workers: workers must be at least 1"),
    (lambda t: t + '\n[run]\nexecutor = "slurm"\n',
     r"run\.executor: executor must be one of \['dask', 'local'\], got 'slurm'"),
    (lambda t: t + '\n[run]\nscheduler = "tcp://h:8786"\n',
     r'run\.scheduler: a scheduler address needs executor = "dask"'),
    (lambda t: t + '\n[run]\nexecutor = "dask"\nscheduler = 8786\n',
     r"run\.scheduler: scheduler must be an address such as 'tcp://host:8786', got 8786"),
    (lambda t: t + '\n[run]\ntimeout = -5\n', r"run\.timeout: timeout must be positive"),
    (lambda t: t + '\n[run]\nthreads = 2\n', r"run\.threads: unknown key"),
    (lambda t: t.replace('directory = "results"', 'directory = "results"\nworkers = 2')
     + '\n[run]\nworkers = 2\n', r"output\.workers: workers is given in \[run\] and in "
                                   r"\[output\]; keep run\.workers"),
    (lambda t: t.replace("[inputs]", "[inputs]\nsession = \"session\""),
     r"inputs\.captures: give either"),
    (lambda t: t + "\n[extra]\n", r"extra: unknown key"),
])
def test_config_errors_name_the_key(session_root, edit, match):
    path = session_root / "bad.toml"
    good = _config(session_root, ["session/capture.c3d"]).read_text()
    path.write_text(edit(good), encoding="utf-8")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)      # output.workers: the old key
        with pytest.raises(InputError, match=match):
            load_run_config(path)


def test_run_table_and_the_old_output_workers(session_root):
    path = session_root / "run-table.toml"
    good = _config(session_root, ["session/capture.c3d"]).read_text()
    path.write_text(good + '\n[run]\nexecutor = "dask"\nscheduler = " tcp://h:8786 "\n'
                           'workers = 3\ntimeout = 90\n', encoding="utf-8")
    config = load_run_config(path)
    assert (config.executor, config.scheduler, config.workers, config.timeout) == \
        ("dask", "tcp://h:8786", 3, 90.0)
    assert "run" not in config.parameters()          # where takes run changes no output
    path.write_text(good.replace('directory = "results"', 'directory = "results"\nworkers = 1'),
                    encoding="utf-8")
    with pytest.warns(FutureWarning, match=r"output\.workers is now run\.workers"):
        assert load_run_config(path).workers == 1


def test_a_take_past_its_timeout_is_failed_with_the_reason(session_root, tmp_path):
    path = _config(session_root, ["session/capture.c3d"])
    config = load_run_config(path)
    config = dataclasses.replace(config, output=tmp_path / "out")
    outcome = run_takes(config, timeout=0.01, progress=False)
    record = outcome.takes["capture"]
    assert outcome.n_failed == 1 and record["status"] == "failed"
    assert record["error"] == "timed out after 0.01 s (the per-take timeout)"
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert manifest["takes"]["capture"]["error"] == record["error"]


def test_config_not_toml(session_root):
    path = session_root / "bad.toml"
    path.write_text("[inputs\n", encoding="utf-8")
    with pytest.raises(FileFormatError, match="not valid TOML"):
        load_run_config(path)


def test_session_directory_and_relative_paths(session_root):
    path = session_root / "session.toml"
    path.write_text(demo_config_toml().replace('captures = ["session/capture.c3d"]',
                                               'session = "session"'), encoding="utf-8")
    config = load_run_config(path)
    assert [c.name for c in config.captures] == ["broken.c3d", "capture.c3d"]
    assert config.mesh == (session_root / "session" / "neutral.obj").resolve()
    assert config.workers == 2


def test_a_take_records_its_warnings_not_the_garbage_collectors():
    """A finalizer that the garbage collector runs inside a take's block (an unclosed file
    of earlier work) warns ResourceWarning there: it says nothing of the take, so neither
    capture records it; the take's own warnings are recorded, each once."""
    from fit.pipeline.take_warnings import capture_warnings, recorded_warnings

    def take():
        warnings.warn("marker far from the skin", UserWarning)
        warnings.warn("unclosed file <_io.BufferedReader name=60>", ResourceWarning)
        warnings.warn("marker far from the skin", UserWarning)
    with capture_warnings(reemit=False) as caught:
        take()
    with recorded_warnings() as pairs:
        take()
    assert caught == ["marker far from the skin"]
    assert pairs == [("marker far from the skin", UserWarning)] * 2
