"""Helpers shared by the benchmark scripts: data location, timing, peak memory."""

from __future__ import annotations

import atexit
import io
import json
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
import tracemalloc
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
# A benchmark times the code of the checkout it lives in, not the installed package's: an
# editable install points at one checkout, and a copy of another commit beside it is how
# two versions are timed side by side. The processes it starts (``mocap2mesh run``) get
# the same path.
sys.path.insert(0, str(REPO))
os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO),
                                                         os.environ.get("PYTHONPATH")]))
#: The longest gap the benchmarks fill in facial-sing.c3d, frames: its longest face-marker
#: gap is 192 frames (1.92 s), far beyond the default maximum gap, and they fill it.
FACIAL_SING_MAX_GAP = 200


def memory_as_the_command() -> str:
    """Set this process's memory as the ``mocap2mesh`` command sets it
    (:func:`mocap.util.process_memory.configure_process_memory`), for the code timed and its
    floors alike; what was set, in words."""
    from mocap.util.process_memory import configure_process_memory

    changed = configure_process_memory()
    said = [what for key, what in (("kept_freed_memory", "freed memory kept"),
                                   ("hugepage_advice_off", "NumPy's huge-page advice off"))
            if changed[key]]
    return "memory as the command sets it: " + (", ".join(said) or "as the system has it")


def shared_data() -> Path:
    """``$MOCAP2MESH_SHARED_DATA`` or ``../shared/data``; exit with a message if absent."""
    env = os.environ.get("MOCAP2MESH_SHARED_DATA")
    path = Path(env) if env else REPO.parent / "shared" / "data"
    if not path.is_dir():
        sys.exit(f"benchmark needs the real data: {path} not found "
                 "(set MOCAP2MESH_SHARED_DATA)")
    return path


def scratch_directory(prefix: str) -> Path:
    """A new temporary directory for a benchmark's files, removed when the script ends
    (a run of ``bench_chain.py`` leaves about 0.5 GB); kept, and named on stderr, when
    ``BENCH_KEEP`` is set, to look at what the benchmark wrote."""
    path = Path(tempfile.mkdtemp(prefix=prefix))
    if os.environ.get("BENCH_KEEP"):
        atexit.register(lambda: print(f"kept the benchmark's files in {path}", file=sys.stderr))
    else:
        atexit.register(shutil.rmtree, path, ignore_errors=True)
    return path


def without_kept_geodesics() -> None:
    """Drop the geodesic fields this process kept (:data:`mocap.mesh.geodesic.FIELDS`): the
    retargeting timed next solves its own, as a take run alone does."""
    from mocap.mesh.geodesic import FIELDS
    FIELDS.clear()


def best_time(fn, *, repeat: int = 3) -> float:
    """Best wall-clock time of `repeat` calls of ``fn()``, seconds."""
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def report_floor(paths, out: Path) -> tuple[float, dict]:
    """The floor of writing a QA report: every PNG of `paths` encoded again from its pixels
    by the report's encoder (:func:`mocap.viz.figures.write_png`) and every HTML page's
    bytes written, into `out`; (seconds in all, seconds per PNG name)."""
    import cv2

    from mocap.viz.figures import write_png
    paths = [Path(p) for p in paths]
    pngs = {p.name: cv2.imread(str(p))[:, :, ::-1] for p in paths if p.suffix == ".png"}
    pages = {p.name: p.read_bytes() for p in paths if p.suffix == ".html"}
    out.mkdir(parents=True, exist_ok=True)
    per_png = {}
    for name, pixels in pngs.items():
        tic = time.perf_counter()
        write_png(pixels, out / name)
        per_png[name] = time.perf_counter() - tic
    tic = time.perf_counter()
    for name, page in pages.items():
        (out / name).write_bytes(page)
    return sum(per_png.values()) + time.perf_counter() - tic, per_png


def peak_memory_mb(fn) -> float:
    """Peak memory allocated through Python/NumPy during ``fn()``, MB (tracemalloc)."""
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()


def export_tree(ref: str, into: Path) -> Path:
    """The source tree of git `ref` extracted into `into` (a baseline to run side by side;
    nothing of the checkout is touched)."""
    blob = subprocess.run(["git", "-C", str(REPO), "archive", "--format=tar", ref],
                          check=True, capture_output=True).stdout
    with tarfile.open(fileobj=io.BytesIO(blob)) as tar:
        tar.extractall(into, filter="data")
    return into


def run_take(out: Path, capture: Path, *, mesh: Path, basis: Path, landmarks: Path,
             max_gap: int) -> tuple[float, dict]:
    """``mocap2mesh run`` of the ICT-markered take `capture` onto `mesh` (cm) and its shapes
    `basis`, in a fresh process as a user runs it (2 mm skin offset, every gap up to
    `max_gap` frames filled, no video), into `out` / "run": its wall seconds and the take's
    record in the manifest (``seconds``, ``stage_seconds``...)."""
    config = out / "run.toml"
    config.write_text(f"""[inputs]
captures = ["{capture}"]
markerset = "{REPO / 'tests' / 'ict_markerset.toml'}"
mesh = "{mesh}"
mesh_units = "cm"
landmarks = "{landmarks}"
basis = "{basis}"

[output]
directory = "{out / 'run'}"

[ingest]
max_gap = {max_gap}

[bind]
skin_offset = 2.0

[report]
video = false
""", encoding="utf-8")
    tic = time.perf_counter()
    subprocess.run([sys.executable, "-m", "fit.cli.main", "run", str(config)], check=True,
                   stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - tic
    manifest = json.loads((out / "run" / "manifest.json").read_text(encoding="utf-8"))
    return wall, next(iter(manifest["takes"].values()))
