"""Killing ``mocap2mesh run`` at chosen moments, and checking what the next run trusts.

Used by ``tests/test_resume.py`` and ``bench/bench_resume.py``. A run is started
as a subprocess in a session of its own; :func:`kill_when` polls the output
directory and SIGKILLs the run (only the parent: its workers must die by
themselves) when a condition holds, returning what was committed then and the
worker processes alive at that moment.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from fit.demo import demo_config_toml, make_demo_session
from fit.pipeline.completion import RECORD_NAME, read_record
from fit.pipeline.outdir import STAGING_NAME
from mocap.util.atomic import is_temp_name

POLL_S = 0.02
RUN = "from fit.cli.main import console; console()"


def make_session(root: Path, n_takes: int, *, seconds: float = 2.0) -> Path:
    """A demo session whose capture is copied into `n_takes` takes t1, t2..., with run.toml."""
    make_demo_session(root / "session", seconds=seconds, n_gaps=int(10 * seconds))  # 10 gaps/s
    names = []
    for k in range(1, n_takes + 1):
        shutil.copy(root / "session" / "capture.c3d", root / "session" / f"t{k}.c3d")
        names.append(f'"session/t{k}.c3d"')
    write_config(root, lowpass=15.0, names=names)
    return root / "run.toml"


def write_config(root: Path, *, lowpass: float, names=None, path: str = "run.toml") -> Path:
    """The session's run configuration with another low-pass cut-off (a parameter)."""
    if names is None:
        names = [f'"session/{p.name}"' for p in sorted((root / "session").glob("t*.c3d"))]
    text = (demo_config_toml()
            .replace('captures = ["session/capture.c3d"]', f"captures = [{', '.join(names)}]")
            .replace("lowpass_hz = 15.0", f"lowpass_hz = {lowpass}")
            .replace("video_step = 4", "video_step = 12")
            .replace("video = true", "video = false"))
    (root / path).write_text(text, encoding="utf-8")
    return root / path


def start_run(config: Path, *, workers: int = 2, force: bool = False,
              tree: Path | None = None) -> subprocess.Popen:
    """``mocap2mesh run CONFIG -j N`` in a new session (one BLAS thread per worker).

    With `tree`, the package of that source tree runs instead of this one.
    """
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONDONTWRITEBYTECODE="1")
    if tree is not None:
        env["PYTHONPATH"] = str(tree)
    argv = [sys.executable, "-c", RUN, "run", str(config), "-j", str(workers)]
    return subprocess.Popen(argv + (["--force"] if force else []), env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True, cwd=config.parent)


def descendants(pid: int) -> set:
    """Every live descendant of process `pid` (from /proc/PID/task/*/children)."""
    found, todo = set(), [pid]
    while todo:
        parent = todo.pop()
        for task in Path(f"/proc/{parent}/task").glob("*"):
            try:
                children = (task / "children").read_text().split()
            except OSError:
                continue
            for child in map(int, children):
                if child not in found:
                    found.add(child)
                    todo.append(child)
    return found


def alive(pid: int) -> bool:
    """True while process `pid` exists and is not a zombie."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state not in ("Z", "X")


def wait_gone(pids, timeout: float) -> set:
    """Wait until no process of `pids` is alive; returns those still alive at `timeout`."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        left = {p for p in pids if alive(p)}
        if not left:
            return set()
        time.sleep(POLL_S)
    return {p for p in pids if alive(p)}


def reported(out: Path) -> set:
    """Names of the take folders of `out` whose HTML report is there (the last file of a take)."""
    if not out.is_dir():
        return set()
    return {p.name for p in out.iterdir() if (p / "report" / f"{p.name}.html").is_file()}


def committed(out: Path) -> set:
    """Names of the take folders of `out` that hold a completion record."""
    if not out.is_dir():
        return set()
    return {p.name for p in out.iterdir() if p.is_dir() and not p.name.startswith(".")
            and read_record(p) is not None}


def staged_files(out: Path) -> int:
    """Files in the staging folder (takes being written)."""
    staging = out / STAGING_NAME
    return sum(1 for p in staging.rglob("*") if p.is_file()) if staging.is_dir() else 0


def kill_when(proc: subprocess.Popen, out: Path, condition, *, timeout: float = 600.0,
              orphan_timeout: float = 10.0):
    """SIGKILL the run `proc` (its parent process only) as soon as ``condition(out)`` holds.

    Returns
    -------
    killed : bool
        False when the run ended before the condition held.
    workers : set of int
        Its descendant processes alive just before the kill.
    orphans : set of int
        Those still alive `orphan_timeout` s after the kill.
    committed : set of str
        The takes committed once the run and its workers are gone.
    """
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            return False, set(), set(), committed(out)
        if condition(out):
            workers = descendants(proc.pid)
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()
            orphans = wait_gone(workers, orphan_timeout)
            return True, workers, orphans, committed(out)
        time.sleep(POLL_S)
    proc.kill()
    raise TimeoutError(f"the kill condition never held within {timeout:g} s")


def finish(proc: subprocess.Popen, timeout: float = 900.0) -> int:
    """Wait for a run to end; its exit code."""
    proc.wait(timeout=timeout)
    return proc.returncode


def load_output(path: Path) -> None:
    """Open an output the way its users would; raises if it is not whole."""
    import cv2
    import pandas as pd
    import pygltflib

    import mocap
    from mocap.mesh.mesh import load_mesh

    suffix = path.suffix.lower()
    if suffix == ".npz":
        with np.load(path, allow_pickle=False) as archive:
            for name in archive.files:
                archive[name]
    elif suffix in (".c3d", ".trc"):
        mocap.read(path)
    elif suffix == ".csv":
        pd.read_csv(path)
    elif suffix == ".json":
        json.loads(path.read_text(encoding="utf-8"))
    elif suffix == ".glb":
        if pygltflib.GLTF2().load(str(path)) is None:
            raise ValueError(f"{path}: not a glTF")
    elif suffix == ".png":
        if cv2.imread(str(path)) is None:
            raise ValueError(f"{path}: not a PNG")
    elif suffix == ".html":
        if not path.read_text(encoding="utf-8").rstrip().endswith("</html>"):
            raise ValueError(f"{path}: the page is cut short")
    elif suffix in (".mp4", ".webm"):
        video = cv2.VideoCapture(str(path))
        ok, _ = video.read()
        video.release()
        if not ok:
            raise ValueError(f"{path}: no frame")
    elif suffix == ".obj":
        load_mesh(path)
    else:
        raise ValueError(f"{path}: no loader for {suffix}")


def verify_outputs(out: Path) -> dict:
    """Every output the manifest lists loads; no staging folder or temporary file is left.

    Returns
    -------
    dict
        ``{"outputs": n_loaded, "unlisted": [files of a take folder the manifest does
        not list], "leftovers": [temporary files, staging]}``.
    """
    manifest = json.loads((out / "manifest.json").read_text(encoding="utf-8"))
    listed = set()
    for name, take in manifest["takes"].items():
        for rel in take.get("files", ()):
            load_output(out / rel)
            listed.add(rel)
    on_disk = {p.relative_to(out).as_posix() for name in manifest["takes"]
               for p in (out / name).rglob("*") if p.is_file() and p.name != RECORD_NAME}
    leftovers = [str(p) for p in out.rglob("*") if is_temp_name(p.name)]
    if (out / STAGING_NAME).exists() and any((out / STAGING_NAME).iterdir()):
        leftovers.append(str(out / STAGING_NAME))
    return {"outputs": len(listed), "unlisted": sorted(on_disk - listed),
            "leftovers": leftovers}


def record_keys(out: Path) -> dict:
    """Each committed take's provenance key (from its record)."""
    return {name: json.loads((out / name / RECORD_NAME).read_text())["key"]
            for name in committed(out)}
