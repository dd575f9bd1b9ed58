"""Benchmark: a session of simulated takes serial, in the local process pool and on Dask.

16 takes (``--takes``) are simulated with ``mocap2mesh synth``: the ICT face
(53 shapes) driven by the real ARKit performances ``alex_rom_3/4.csv`` in turn,
the 66-marker layout of ``tests/ict_marker_layout.toml``, 3,000 frames
(``--frames``) at 30 Hz, 0.2 mm noise, head motion and 20 gaps, each take with
a seed of its own. The same session then runs through the whole chain
(:func:`fit.pipeline.session.run_takes`, no video) three ways, in one run of
this script and one after the other:

- serial: ``executor="local", workers=1`` (every take in this process);
- local pool: ``executor="local", workers=2`` (a process per take);
- Dask: a ``distributed.LocalCluster`` of 2 single-threaded worker
  processes, started and stopped inside the timed call (as ``mocap2mesh run
  --executor dask`` does); its start-up is also timed on its own.

Printed: wall time of each, speed-up over serial, Dask's overhead per take
against the local pool (``(dask - pool) / takes``, and in % of the pool's
time; aim: under max(0.5 s, 5 %)), and, since the load of a shared machine
moves between the variants, each executor's idle worker time (worker slots ×
wall − the takes' own times) per take; the per-take time the workers reported,
and the peak resident memory per take: each local-pool take is a process of
its own, so its ``ru_maxrss`` is that take's peak; a Dask worker's is the peak
over the takes it ran. The BLAS's threads are left as a user has them: the serial run
has the machine's (and a figure helper per spare core), each local-pool worker its share
of them, each Dask worker one (Dask's nanny sets ``OPENBLAS_NUM_THREADS=1``).

Usage: ``python bench/bench_session.py [--takes 16] [--frames 3000]``
(writes into bench/out/session).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from _common import REPO, shared_data

from fit.cli.main import main as cli
from fit.pipeline.config import load_run_config
from fit.pipeline.executors import DaskExecutor
from fit.pipeline.session import run_takes

OUT = REPO / "bench" / "out" / "session"
RATE = 30.0


def simulate(root: Path, n_takes: int, frames: int) -> list:
    ict = root / "ict-face"
    captures = []
    for i in range(n_takes):
        performance = ("alex_rom_3.csv", "alex_rom_4.csv")[i % 2]
        path = OUT / "captures" / f"take{i:02d}.c3d"
        captures.append(path)
        if path.is_file():
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")             # TongueOut: no ICT shape
            code = cli(["synth", "--mesh", str(ict / "generic_neutral_mesh.obj"),
                        "--shapes", str(ict / "expressions"),
                        "--performance", str(root / "arkit-performances" / performance),
                        "--layout", str(REPO / "tests" / "ict_marker_layout.toml"),
                        "--markerset", str(REPO / "tests" / "ict_markerset.toml"),
                        "-o", str(path), "--rate", f"{RATE:g}",
                        "--duration", f"{frames / RATE:g}", "--noise", "0.2",
                        "--gaps", "20", "--seed", str(i)])
        if code:
            sys.exit(f"mocap2mesh synth failed with exit code {code}")
    return captures


def config(root: Path, captures: list, output: str) -> Path:
    ict = root / "ict-face"
    text = ("[inputs]\ncaptures = [" + ", ".join(f'"{c}"' for c in captures) + "]\n"
            f'markerset = "{REPO / "tests" / "ict_markerset.toml"}"\n'
            f'mesh = "{ict / "generic_neutral_mesh.obj"}"\nmesh_units = "cm"\n'
            f'landmarks = "{REPO / "tests" / "ict_landmarks.toml"}"\n'
            f'basis = "{ict / "expressions"}"\n\n'
            f'[output]\ndirectory = "{OUT / output}"\n\n'
            # the simulated gaps last up to ~1 s: filled, as the chain needs every frame
            '[ingest]\nmax_gap = 60\n\n'
            '[bind]\nskin_offset = 2.0\n\n[fit]\nspace = "marker"\n\n[report]\nvideo = false\n')
    path = OUT / f"{output}.toml"
    path.write_text(text, encoding="utf-8")
    shutil.rmtree(OUT / output, ignore_errors=True)
    return path


def timed(fn):
    tic = time.perf_counter()
    outcome = fn()
    seconds = time.perf_counter() - tic
    if outcome.n_failed:
        bad = {k: v["error"] for k, v in outcome.takes.items() if v["status"] != "ok"}
        sys.exit(f"takes failed: {bad}")
    return outcome, seconds


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--takes", type=int, default=16)
    parser.add_argument("--frames", type=int, default=3000)
    args = parser.parse_args()
    root = shared_data()
    (OUT / "captures").mkdir(parents=True, exist_ok=True)
    captures = simulate(root, args.takes, args.frames)
    print(f"{args.takes} takes of {args.frames} frames (ICT face, 60 face + 6 head markers, "
          f"{RATE:g} Hz), whole chain without video; "
          f"{os.cpu_count()} cores\n")
    rows = []
    serial, serial_s = timed(lambda: run_takes(load_run_config(config(root, captures, "serial")),
                                               executor="local", workers=1, progress=False))
    rows.append(("serial (1 process)", serial, serial_s))
    pool, pool_s = timed(lambda: run_takes(load_run_config(config(root, captures, "pool")),
                                           executor="local", workers=2, progress=False))
    rows.append(("local pool, 2 workers", pool, pool_s))

    start = {}

    def on_dask():
        tic = time.perf_counter()
        with DaskExecutor(workers=2) as dask:
            start["s"] = time.perf_counter() - tic
            return run_takes(load_run_config(config(root, captures, "dask")), executor=dask,
                             progress=False)

    dask, dask_s = timed(on_dask)
    rows.append(("Dask LocalCluster, 2 workers", dask, dask_s))
    print(f"{'executor':<30}{'wall s':>9}{'× serial':>9}{'take s (median)':>17}"
          f"{'peak RSS/take MB (max)':>24}")
    for label, outcome, seconds in rows:
        takes = outcome.takes.values()
        per_take = np.median([t["seconds"] for t in takes])
        peak = max(t["worker"]["peak_rss_mb"] for t in takes)
        print(f"{label:<30}{seconds:9.1f}{serial_s / seconds:9.2f}{per_take:17.2f}"
              f"{peak:24.0f}")
    overhead = (dask_s - pool_s) / args.takes
    aim = max(0.5, 0.05 * pool_s / args.takes)
    print(f"\nDask overhead against the local pool: {overhead:+.2f} s per take "
          f"({100 * (dask_s - pool_s) / pool_s:+.1f} % of the pool's wall time; aim under "
          f"{aim:.2f} s a take), of which cluster start-up {start['s']:.1f} s once")
    # On a shared machine the load moves between the variants; the time worker slots spent
    # not running a take (start-up, hand-out, manifest writes, the last take's tail) is
    # the executor's own cost whatever the load.
    for label, outcome, seconds in rows:
        slots = 1 if outcome is serial else 2
        idle = slots * seconds - sum(t["seconds"] for t in outcome.takes.values())
        print(f"{label:<30} idle worker time {idle:7.1f} s: {idle / args.takes:5.2f} s per "
              f"take, {100 * idle / (slots * seconds):4.1f} % of the worker time")
    same = all(_same(OUT / "pool", OUT / "dask", c.stem) for c in captures)
    print(f"outputs other than the QA report and the take record (its times) identical "
          f"in the local pool and on Dask (one BLAS thread a take in both): {same}")
    apart = max(_weights_apart(OUT / "pool", OUT / "serial", c.stem) for c in captures)
    print(f"serial (the machine's BLAS threads) against the local pool: weights within "
          f"{apart:.1e} (rounding: a threaded BLAS sums in another order)")


def _same(a: Path, b: Path, take: str) -> bool:
    files = [p.relative_to(a / take) for p in (a / take).rglob("*")
             if p.is_file() and "report" not in p.parts and p.name != "take-record.json"]
    return all((a / take / f).read_bytes() == (b / take / f).read_bytes() for f in files)


def _weights_apart(a: Path, b: Path, take: str) -> float:
    """Largest difference between the weights CSVs of a take in two runs."""
    return max(float(np.abs(np.loadtxt(a / take / f.name, delimiter=",", comments="#",
                                       skiprows=1)
                            - np.loadtxt(f, delimiter=",", comments="#", skiprows=1)).max())
               for f in (b / take).glob("weights-*.csv"))


if __name__ == "__main__":
    main()
