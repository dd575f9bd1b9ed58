"""``mocap2mesh run`` on a real Dask LocalCluster (2 worker processes): the same files as the
local pool, a worker killed mid-take, a driver killed mid-session and run again."""

from __future__ import annotations

import gc
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import distributed  # the test extra installs Dask and psutil (.[test])
import numpy as np
import psutil
import pytest

import mocap
from fit.demo import demo_config_toml, make_demo_session
from fit.pipeline.completion import RECORD_NAME
from fit.pipeline.config import load_run_config
from fit.pipeline.session import run_takes

TAKES = ("a", "b")
KILL_WAIT = 120         # s: longest we wait for a take to be running or done


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """Two small takes (1 s of the demo capture each, no video) and their configuration."""
    root = tmp_path_factory.mktemp("dask-run")
    make_demo_session(root / "session", seconds=1.0, n_gaps=2)
    for name in TAKES:
        shutil.copy(root / "session" / "capture.c3d", root / "session" / f"{name}.c3d")
    text = demo_config_toml().replace(
        'captures = ["session/capture.c3d"]',
        "captures = [" + ", ".join(f'"session/{n}.c3d"' for n in TAKES) + "]")
    (root / "run.toml").write_text(text.replace("video = true", "video = false"))
    return root



@pytest.fixture(scope="module")
def client():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as c:
        yield c


def _config(session, out: str, takes=TAKES):
    text = (session / "run.toml").read_text().replace('directory = "results"',
                                                     f'directory = "{out}"')
    text = text.replace(", ".join(f'"session/{n}.c3d"' for n in TAKES),
                        ", ".join(f'"session/{n}.c3d"' for n in takes))
    path = session / f"{out}.toml"
    path.write_text(text)
    return load_run_config(path)


def _numeric_files(out: Path, take: str) -> dict:
    """Every output of a take but the QA report (pictures and HTML) and the completion record
    (when and how long), as bytes."""
    return {p.relative_to(out / take).as_posix(): p.read_bytes()
            for p in sorted((out / take).rglob("*"))
            if p.is_file() and "report" not in p.parts and p.name != RECORD_NAME}


def _metrics(record):
    """A manifest record without what depends on where and when it ran (times, worker)."""
    if isinstance(record, dict):
        return {k: _metrics(v) for k, v in record.items()
                if k not in ("seconds", "stage_seconds", "worker", "skipped")}
    return record


@pytest.fixture(scope="module")
def local(session):
    """Takes a and b through the local pool (2 worker processes): the reference."""
    return run_takes(_config(session, "local", TAKES), executor="local", workers=2,
                     progress=False)


def test_dask_writes_the_same_bits_as_the_local_pool(session, client, local):
    dask = run_takes(_config(session, "dask", TAKES), executor=client, progress=False)
    assert local.n_failed == dask.n_failed == 0
    for take in TAKES:
        ours, theirs = _numeric_files(session / "local", take), \
            _numeric_files(session / "dask", take)
        assert len(ours) > 10 and ours.keys() == theirs.keys()
        for name in ours:
            assert ours[name] == theirs[name], name
        assert _metrics(local.takes[take]) == _metrics(dask.takes[take])
        ran_on = dask.takes[take]["worker"]["pid"]
        assert ran_on in client.run(os.getpid).values()     # on a worker, not here
    # the workers' objects, frozen out of the collector's passes while a take ran, are not
    # left frozen after it
    assert set(client.run(gc.get_freeze_count).values()) == {0}


def test_a_worker_killed_mid_take_is_rescheduled(session, client, local):
    """Dask runs the take again on the other worker; the outputs are the same."""
    pids = client.run(os.getpid)
    killed = []

    def kill_the_first_busy_worker():
        deadline = time.monotonic() + KILL_WAIT
        while time.monotonic() < deadline:
            busy = [w for w, keys in client.processing().items()
                    if any(str(k).startswith("take-") for k in keys)]
            if busy and busy[0] in pids:
                time.sleep(1.0)                          # well into the take
                os.kill(pids[busy[0]], signal.SIGKILL)
                killed.append(busy[0])
                return
            time.sleep(0.05)

    killer = threading.Thread(target=kill_the_first_busy_worker)
    killer.start()
    outcome = run_takes(_config(session, "killed", TAKES), executor=client, progress=False)
    killer.join()
    assert killed, "no take was seen running"
    assert outcome.n_failed == 0 and local.n_failed == 0
    for take in TAKES:
        assert outcome.takes[take]["status"] == "ok"
        assert outcome.takes[take]["worker"]["pid"] != pids[killed[0]]
        assert _numeric_files(session / "killed", take) == _numeric_files(session / "local", take)


def test_a_killed_driver_leaves_a_valid_manifest_and_no_worker_and_a_rerun_finishes(session):
    config = _config(session, "resumed", TAKES)
    manifest = config.output / "manifest.json"
    driver = subprocess.Popen([sys.executable, "-m", "fit.cli.main", "run", str(config.path),
                               "--executor", "dask", "--workers", "1"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + KILL_WAIT
    done = []
    while not done:
        assert time.monotonic() < deadline and driver.poll() is None, "no take finished"
        time.sleep(0.1)
        try:
            takes = json.loads(manifest.read_text())["takes"]
        except (OSError, ValueError):    # not written yet: written atomically, never partial
            continue
        done = [t for t, r in takes.items() if r["status"] == "ok"]
    workers = psutil.Process(driver.pid).children(recursive=True)
    assert workers, "the LocalCluster's processes"
    driver.send_signal(signal.SIGKILL)
    driver.wait()
    gone, alive = psutil.wait_procs(workers, timeout=60)
    assert not alive, f"orphan workers: {[p.pid for p in alive]}"
    takes = json.loads(manifest.read_text())["takes"]              # valid JSON
    assert len(done) < len(TAKES)
    unfinished = [t for t, r in takes.items() if r["status"] != "ok"]
    assert unfinished and all(takes[t]["status"] == "pending" for t in unfinished)
    rerun = run_takes(load_run_config(config.path), executor="dask", workers=2,
                      progress=False)
    assert rerun.n_failed == 0
    assert sorted(t for t, r in rerun.takes.items() if r["skipped"]) == sorted(done)
    assert sorted(t for t, r in rerun.takes.items() if not r["skipped"]) == sorted(unfinished)
    for take in TAKES:                                # every output loads
        record = rerun.takes[take]
        for name in record["files"]:
            path = config.output / name
            if path.suffix == ".npz":
                with np.load(path) as z:
                    assert all(np.isfinite(z[k]).all() for k in z.files
                               if np.issubdtype(z[k].dtype, np.floating))
            elif path.suffix == ".c3d":
                assert mocap.read(path).n_frames > 0
            else:
                assert path.stat().st_size > 0
