"""``mocap2mesh run`` killed (SIGKILL) at chosen moments: every finished take is skipped on the
re-run, nothing else is trusted, every output loads, and no worker outlives its run."""

from __future__ import annotations

import json

import pytest
from resume import (
    committed,
    finish,
    kill_when,
    make_session,
    record_keys,
    staged_files,
    start_run,
    verify_outputs,
    write_config,
)

from fit.pipeline.completion import RECORD_NAME

N_TAKES = 3
#: Longest a worker may outlive its killed run (s): well under a take's time, so that a worker
#: that goes on with its take (and writes into the folder) is caught.
ORPHAN_S = 3.0


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = tmp_path_factory.mktemp("resume")
    return make_session(root, N_TAKES), root / "results"


def _manifest(out):
    return json.loads((out / "manifest.json").read_text(encoding="utf-8"))


def _skipped(out) -> set:
    return {name for name, take in _manifest(out)["takes"].items() if take.get("skipped")}


def test_killed_runs_resume_and_leave_no_orphans(session):
    config, out = session
    takes = {f"t{k}" for k in range(1, N_TAKES + 1)}
    # killed as soon as one take is committed: the other worker was mid-take
    killed, workers, orphans, first = kill_when(start_run(config), out,
                                                lambda o: len(committed(o)) >= 1,
                                                orphan_timeout=ORPHAN_S)
    assert killed and len(workers) >= 2 and orphans == set()
    assert 1 <= len(first) < N_TAKES
    inodes = {name: (out / name / RECORD_NAME).stat().st_ino for name in first}
    # killed while a take is being written, before it is committed
    killed, workers, orphans, second = kill_when(
        start_run(config), out, lambda o: staged_files(o) >= 3 and committed(o) == first,
        orphan_timeout=ORPHAN_S)
    assert killed and orphans == set()
    assert second >= first
    # to the end: what was committed is skipped (untouched), the rest redone
    assert finish(start_run(config)) == 0
    assert _skipped(out) == second
    assert committed(out) == takes
    assert {name: (out / name / RECORD_NAME).stat().st_ino for name in first} == inodes
    manifest = _manifest(out)
    assert all(take["status"] == "ok" for take in manifest["takes"].values())
    checked = verify_outputs(out)
    assert checked["leftovers"] == checked["unlisted"] == [] and checked["outputs"] > 0


def test_a_killed_run_with_other_parameters_is_not_trusted(session):
    """Run A is done; run B (another low-pass) is killed after replacing a take: re-running A
    redoes exactly the takes B replaced and skips the others."""
    config, out = session
    if committed(out) != {f"t{k}" for k in range(1, N_TAKES + 1)}:
        assert finish(start_run(config)) == 0
    keys_a = record_keys(out)
    other = write_config(config.parent, lowpass=10.0, path="run-b.toml")
    killed, _, orphans, _ = kill_when(start_run(other), out,
                                      lambda o: record_keys(o) != keys_a,
                                      orphan_timeout=ORPHAN_S)
    assert killed and orphans == set()
    replaced = {name for name, key in record_keys(out).items() if key != keys_a.get(name)}
    assert replaced
    assert finish(start_run(config)) == 0
    manifest = _manifest(out)
    redone = {name for name, take in manifest["takes"].items() if not take["skipped"]}
    assert redone == replaced
    assert record_keys(out) == keys_a
    checked = verify_outputs(out)
    assert checked["leftovers"] == checked["unlisted"] == []


def test_no_worker_outlives_a_run_killed_as_its_first_take_is_written(session):
    """Workers forked by a fork server outlive their parent's parent unless told otherwise:
    none may go on with its take once the run is killed."""
    config, _ = session
    config = write_config(config.parent, lowpass=15.0, path="run-first.toml")
    config.write_text(config.read_text(encoding="utf-8").replace(
        'directory = "results"', 'directory = "results-first"'), encoding="utf-8")
    out = config.parent / "results-first"
    killed, workers, orphans, _ = kill_when(start_run(config), out,
                                            lambda o: staged_files(o) > 0,
                                            orphan_timeout=ORPHAN_S)
    assert killed and workers and orphans == set()
