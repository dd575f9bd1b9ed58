"""Benchmark: reading very large C3D files, ours against ezc3d: time and peak resident memory.

Two files are written by our writer (float storage, Intel, no analog):
1,300 markers × 17,000 frames (the 300 MB file of ezc3d#369) and 100 markers
× 1,000,000 frames (past the 16-bit header count: POINT:FRAMES and the header
say 65,535, TRIAL holds the range). Positions are a random walk, 2 % of the
samples missing.

Each read runs in a fresh Python process that prints its own peak resident
set size (``VmHWM``, Linux), the file already in the page cache
(just written; one untimed read first). Printed per file: our read time (best
of ``--repeat``) and ezc3d's (one read: ``ezc3d.c3d(path)``, which also
builds its ``data["points"]`` array), their ratio, and each peak RSS, also
less the RSS of a process that only imports the reader (the interpreter,
numpy...), over the float64 positions' size (aim: ours ≤ 1.5×; ours ≥ 5×
faster). ezc3d is skipped on a file when the memory it would need (scaled
from its peak on the first file) exceeds half the memory available, and the
row says so. ``info`` (:func:`mocap.io.c3d.summarize_c3d`) is timed too.

Usage: ``python bench/bench_read_large.py [--repeat 3] [--keep]`` (files in
bench/out/large-c3d, deleted afterwards unless ``--keep``).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys

import numpy as np
from _common import REPO

from mocap.io.c3d import write_c3d
from mocap.take import Take

OUT = REPO / "bench" / "out" / "large-c3d"
FILES = ((1300, 17_000), (100, 1_000_000))
_BLOCK = 20_000         # frames simulated at a time

# Each script prints its read time and its process's peak resident set (VmHWM: of this
# process's own memory only; ru_maxrss would include the forking parent's).
PEAK = "print(next(l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM')))"
OURS = """
import sys, time
from mocap.io.c3d import read_c3d
tic = time.perf_counter(); take = read_c3d(sys.argv[1]); print(time.perf_counter() - tic)
assert take.n_frames == int(sys.argv[2])
""" + PEAK
INFO = """
import sys, time
from mocap.io.c3d import summarize_c3d
tic = time.perf_counter(); s = summarize_c3d(sys.argv[1]); print(time.perf_counter() - tic)
assert s.n_frames == int(sys.argv[2])
""" + PEAK
EZC3D = """
import sys, time
import ezc3d
tic = time.perf_counter(); c = ezc3d.c3d(sys.argv[1]); print(time.perf_counter() - tic)
assert c["data"]["points"].shape[2] == int(sys.argv[2])
""" + PEAK
IMPORT_OURS = "import mocap.io.c3d; print(0.0)\n" + PEAK
IMPORT_EZC3D = "import ezc3d, numpy; print(0.0)\n" + PEAK


def simulate(n_markers: int, n_frames: int, seed: int = 0) -> Take:
    """A random walk of every marker (mm), 2 % of the samples missing."""
    rng = np.random.default_rng(seed)
    positions = np.empty((n_frames, n_markers, 3))
    here = rng.uniform(-500, 500, size=(n_markers, 3))
    for start in range(0, n_frames, _BLOCK):
        stop = min(n_frames, start + _BLOCK)
        steps = rng.normal(scale=0.5, size=(stop - start, n_markers, 3))
        positions[start:stop] = here + np.cumsum(steps, axis=0)
        here = positions[stop - 1]
        gone = rng.random((stop - start, n_markers)) < 0.02
        positions[start:stop][gone] = np.nan
    positions.flags.writeable = False
    return Take([f"Subject:M{i:04d}" for i in range(n_markers)], positions, 120.0)


def run(script: str, *args) -> tuple[float, float]:
    """(seconds, peak RSS in MB) that `script` prints, run in a fresh Python process."""
    done = subprocess.run([sys.executable, "-c", script, *map(str, args)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"reader failed ({done.returncode}): {done.stderr.strip()[-500:]}")
    seconds, peak_kb = done.stdout.split()[:2]
    return float(seconds), float(peak_kb) / 1e3


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--keep", action="store_true")
    args = parser.parse_args()
    import psutil
    OUT.mkdir(parents=True, exist_ok=True)
    base_ours = run(IMPORT_OURS)[1]
    base_ez = run(IMPORT_EZC3D)[1]
    print(f"peak RSS of a process that only imports: ours {base_ours:.0f} MB, ezc3d "
          f"{base_ez:.0f} MB; ours best of {args.repeat}, ezc3d one read; "
          f"{os.cpu_count()} cores\n")
    print(f"{'file':<22}{'MB':>7}{'f64 MB':>8}{'ours s':>8}{'ezc3d s':>9}{'× faster':>9}"
          f"{'ours RSS':>9}{'-base':>7}{'/f64':>6}{'ez RSS':>8}{'-base':>7}{'/f64':>6}"
          f"{'info s':>7}{'info RSS':>9}")
    ez_per_sample = None
    for n_markers, n_frames in FILES:
        path = OUT / f"{n_markers}x{n_frames}.c3d"
        take = simulate(n_markers, n_frames)
        write_c3d(take, path)
        del take
        f64 = n_markers * n_frames * 3 * 8 / 1e6
        run(OURS, path, n_frames)                                    # page cache warm
        ours = [run(OURS, path, n_frames) for _ in range(args.repeat)]
        ours_s, ours_rss = min(t for t, _ in ours), max(r for _, r in ours)
        info_s, info_rss = run(INFO, path, n_frames)
        needed = None if ez_per_sample is None else ez_per_sample * n_markers * n_frames
        available = psutil.virtual_memory().available / 1e6
        if needed is not None and needed > available / 2:
            ez = f"{'skipped':>9}{'-':>9}{'-':>9}{'-':>7}{'-':>6}"
            note = (f"  ezc3d skipped: it would need ~{needed / 1e3:.1f} GB (scaled from the "
                    f"first file), {available / 1e3:.1f} GB available")
        else:
            ez_s, ez_rss = run(EZC3D, path, n_frames)
            ez_per_sample = (ez_rss - base_ez) / (n_markers * n_frames)
            ez = (f"{ez_s:9.2f}{ez_s / ours_s:9.1f}{ez_rss:8.0f}{ez_rss - base_ez:7.0f}"
                  f"{(ez_rss - base_ez) / f64:6.2f}")
            note = ""
        ez_time = ez[:18]
        ez_mem = ez[18:]
        print(f"{path.name:<22}{path.stat().st_size / 1e6:7.0f}{f64:8.0f}{ours_s:8.2f}{ez_time}"
              f"{ours_rss:9.0f}{ours_rss - base_ours:7.0f}{(ours_rss - base_ours) / f64:6.2f}"
              f"{ez_mem}{info_s:7.2f}{info_rss:9.0f}{note}")
        if not args.keep:
            path.unlink()
    if not args.keep:
        shutil.rmtree(OUT, ignore_errors=True)


if __name__ == "__main__":
    main()
