"""A take committed as a unit (fit.pipeline.completion) and the run's output directory
(fit.pipeline.outdir): what is trusted, what is refused, what is cleaned."""

from __future__ import annotations

import hashlib
import json
import os
import shutil

import pytest

from fit.demo import demo_config_toml, make_demo_session
from fit.pipeline.completion import (
    RECORD_NAME,
    Provenance,
    begin_take,
    commit_take,
    discard_stage,
    input_entries,
    plan_takes,
    read_record,
    verify_take,
)
from fit.pipeline.config import load_run_config
from fit.pipeline.outdir import (
    STAGING_NAME,
    check_take_dir,
    clean_stale,
    output_lock,
    safe_stem,
    take_names,
)
from fit.pipeline.session import run_takes
from mocap.errors import InputError


@pytest.fixture
def provenance(tmp_path):
    (tmp_path / "take.c3d").write_bytes(b"capture bytes")
    (tmp_path / "mesh.obj").write_bytes(b"v 0 0 0\n")
    return Provenance.of(tmp_path / "take.c3d", input_entries({"mesh": tmp_path / "mesh.obj"}),
                         {"fit": {"space": "marker"}, "ingest": {"lowpass_hz": 15.0}})


def _commit(out, name, provenance, files=None):
    stage = begin_take(out, name)
    for rel, text in (files or {"a.txt": "alpha", "report/b.txt": "beta"}).items():
        (stage / rel).parent.mkdir(parents=True, exist_ok=True)
        (stage / rel).write_text(text)
    return commit_take(stage, out, name, provenance, summary={"status": "ok", "n": 1})


def test_a_committed_take_records_its_outputs_and_verifies(tmp_path, provenance):
    out = tmp_path / "out"
    out.mkdir()
    record = _commit(out, "t1", provenance)
    assert sorted(record.files) == ["a.txt", "report/b.txt"]
    assert record.files["a.txt"] == {"bytes": 5, "sha256": hashlib.sha256(b"alpha").hexdigest()}
    assert record.files["report/b.txt"] == {"bytes": 4,
                                            "sha256": hashlib.sha256(b"beta").hexdigest()}
    doc = json.loads((out / "t1" / RECORD_NAME).read_text())
    assert doc["capture"]["sha256"] == hashlib.sha256(b"capture bytes").hexdigest()
    assert doc["key"] == provenance.key and doc["summary"] == {"status": "ok", "n": 1}
    assert read_record(out / "t1").key == provenance.key
    verdict = verify_take(out, "t1", provenance)
    assert verdict.reusable and verdict.reason == "done by an earlier run; 2 outputs verified"
    assert not (out / STAGING_NAME).exists() or not any((out / STAGING_NAME).iterdir())


def test_every_output_gets_its_own_digest(tmp_path, provenance):
    """The files are hashed side by side: each digest still goes with its file."""
    out = tmp_path / "out"
    out.mkdir()
    texts = {f"{folder}/{i}.txt": f"file {i} " * i for i in range(12) for folder in "ab"}
    record = _commit(out, "t1", provenance, texts)
    assert record.files == {rel: {"bytes": len(text), "sha256": hashlib.sha256(
        text.encode()).hexdigest()} for rel, text in texts.items()}


def test_a_new_commit_replaces_the_whole_folder(tmp_path, provenance):
    out = tmp_path / "out"
    out.mkdir()
    _commit(out, "t1", provenance, {"old.txt": "from an earlier run", "a.txt": "x"})
    _commit(out, "t1", provenance, {"a.txt": "y"})
    assert sorted(p.name for p in (out / "t1").iterdir()) == ["a.txt", RECORD_NAME]


@pytest.mark.parametrize("change, reason", [
    (lambda out, p: p, None),
    (lambda out, p: Provenance({**p.capture, "sha256": "0" * 64}, p.inputs, p.parameters),
     "the capture changed"),
    (lambda out, p: Provenance(p.capture, {"mesh": {"path": "m", "sha256": "1"}},
                               p.parameters), "input mesh changed"),
    (lambda out, p: Provenance(p.capture, p.inputs, {"fit": {"space": "vertex"},
                                                     "ingest": {"lowpass_hz": 15.0}}),
     "parameter fit.space changed ('marker' -> 'vertex')"),
    (lambda out, p: (out / "t1" / "a.txt").unlink() or p, "output a.txt is missing"),
    (lambda out, p: ((out / "t1" / "a.txt").write_text("alphas"), p)[1],
     "output a.txt changed size (5 -> 6 bytes)"),
    (lambda out, p: ((out / "t1" / "a.txt").write_text("ALPHA"), p)[1],
     "output a.txt changed (SHA-256 differs)"),
    (lambda out, p: (out / "t1" / RECORD_NAME).unlink() or p,
     "no completion record (the run that wrote it did not finish it)"),
    (lambda out, p: shutil.rmtree(out / "t1") or p, "not done yet"),
])
def test_a_take_is_trusted_only_when_everything_matches(tmp_path, provenance, change, reason):
    out = tmp_path / "out"
    out.mkdir()
    _commit(out, "t1", provenance)
    verdict = verify_take(out, "t1", change(out, provenance))
    assert verdict.reusable == (reason is None)
    if reason is not None:
        assert verdict.reason == reason


def test_a_tampered_record_never_points_outside_the_folder(tmp_path, provenance):
    out = tmp_path / "out"
    out.mkdir()
    _commit(out, "t1", provenance)
    (tmp_path / "secret").write_text("alpha")
    doc = json.loads((out / "t1" / RECORD_NAME).read_text())
    doc["files"] = {"../../secret": doc["files"]["a.txt"]}
    (out / "t1" / RECORD_NAME).write_text(json.dumps(doc))
    verdict = verify_take(out, "t1", provenance)
    assert not verdict.reusable and "outside the take folder" in verdict.reason


def test_outputs_outside_the_stage_are_refused(tmp_path, provenance):
    out = tmp_path / "out"
    out.mkdir()
    stage = begin_take(out, "t1")
    (tmp_path / "elsewhere.txt").write_text("x")
    os.symlink(tmp_path / "elsewhere.txt", stage / "link.txt")
    with pytest.raises(InputError, match="an output of the take lies outside its folder"):
        commit_take(stage, out, "t1", provenance, summary={})
    discard_stage(stage)
    assert not stage.exists()


def test_force_trusts_nothing(tmp_path, provenance):
    out = tmp_path / "out"
    out.mkdir()
    _commit(out, "t1", provenance)
    assert plan_takes(out, {"t1": provenance})["t1"].reusable
    assert plan_takes(out, {"t1": provenance}, force=True)["t1"].reason == \
        "redone on request (--force)"


def test_take_names_are_safe_and_unique():
    names, renamed = take_names(["s/...c3d", "s/a_b.c3d", "s/A_b.csv", "s/\x1b[2J.trc",
                                 "s/" + "x" * 300 + ".c3d", "s/take 01.c3d"])
    assert list(names.values()) == ["take", "a_b", "A_b-2", "__2J", "x" * 100, "take 01"]
    assert renamed[1] == "s/A_b.csv: take named 'A_b-2' (another take is named 'A_b')"
    assert all(safe_stem(n) == n for n in names.values())


def test_take_folders_stay_inside_and_hold_no_input(tmp_path):
    with pytest.raises(InputError, match="would not lie inside"):
        check_take_dir(tmp_path, "..")
    (tmp_path / "t1").mkdir()
    (tmp_path / "t1" / "capture.c3d").write_bytes(b"")
    with pytest.raises(InputError, match="holds the input"):
        check_take_dir(tmp_path, "t1", inputs=[tmp_path / "t1" / "capture.c3d"])


def test_one_run_at_a_time_per_output_directory(tmp_path):
    with output_lock(tmp_path / "out"):
        with pytest.raises(InputError, match=rf"another mocap2mesh run \(pid {os.getpid()}\) "
                                             "is writing into this directory"):
            with output_lock(tmp_path / "out"):
                pass
    with output_lock(tmp_path / "out"):     # released
        pass


def test_what_killed_runs_left_is_cleaned(tmp_path):
    out = tmp_path / "out"
    (out / STAGING_NAME / "t1.123.ab").mkdir(parents=True)
    (out / "t2" / "report").mkdir(parents=True)
    (out / "t2" / "report" / ".t2.html.4242.tmp").write_text("half a page")
    (out / "t2" / "report" / "t2.html").write_text("<html></html>")
    removed = clean_stale(out)
    assert sorted(p.name for p in removed) == [".staging", ".t2.html.4242.tmp"]
    assert (out / "t2" / "report" / "t2.html").exists()


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = tmp_path_factory.mktemp("outdir")
    make_demo_session(root / "session", seconds=0.5)
    return root


def test_the_output_directory_is_never_inside_an_input_directory(session):
    path = session / "inside.toml"
    path.write_text(demo_config_toml().replace('captures = ["session/capture.c3d"]',
                                               'session = "session"')
                    .replace('directory = "results"', 'directory = "session/out"'))
    with pytest.raises(InputError, match="refusing to write inside the input directory"):
        run_takes(load_run_config(path), progress=False, check=True)
    path.write_text(demo_config_toml().replace('directory = "results"',
                                               'directory = "session/shapes/out"'))
    with pytest.raises(InputError, match="refusing to write inside the input directory"):
        run_takes(load_run_config(path), progress=False, check=True)


def test_a_capture_named_dots_writes_inside_the_output(session, monkeypatch):
    shutil.copy(session / "session" / "capture.c3d", session / "session" / "...c3d")
    path = session / "dots.toml"
    path.write_text(demo_config_toml().replace("session/capture.c3d", "session/...c3d")
                    .replace('directory = "results"', 'directory = "dots"'))
    calls = []

    def fake(capture, config, name, provenance, session_basis=None, figure_helpers=None,
             kept=None, built=None):
        calls.append(name)
        stage = begin_take(config.output, name)
        (stage / "x.txt").write_text("x")
        record = commit_take(stage, config.output, name, provenance, summary={
            "status": "ok", "skipped": False, "error": None})
        return {**record.summary, "files": [f"{name}/x.txt"]}

    monkeypatch.setattr("fit.pipeline.session._guarded", fake)
    with pytest.warns(UserWarning, match=r"\.\.\.c3d: take named 'take' \(its file stem is "
                                         "not a safe folder name"):
        outcome = run_takes(load_run_config(path), progress=False)
    assert calls == ["take"] and list(outcome.takes) == ["take"]
    assert sorted(p.name for p in (session / "dots").iterdir()) == \
        [".mocap2mesh.lock", "manifest.json", "take"]
    assert sorted(p.name for p in session.iterdir() if p.suffix != ".toml") == \
        ["dots", "session"]
