"""Exact batched weight solver vs scipy's lsq_linear(method="bvls") frame by frame.

Basis: 66 vertices (seeded sample) of the 53 ICT expression shapes, as
displacements from the neutral in mm (a marker-space basis, K = 198).
Frames: known weights from the two real ARKit performances (mapped to the
ICT shape names, clipped to [0, 1]), concatenated and linearly resampled to
35,000 frames (~ the quasi-eigen paper's take), imaged by the basis, plus
0.2 mm Gaussian noise. A second row uses i.i.d. uniform weights (no temporal
coherence: the warm start cannot help). Bounds [0, 1].

Both solvers are warmed up, untimed, before the timed runs: lsq_linear by one
call (its code), ours by passes over the slices until a pass makes no new page
faults, at most ``MAX_WARM_UPS`` (a process's heap grows to what its solves need
over their first calls, and glibc keeps it from then on: ~21,000 page faults in
the first pass, ~500 in the second, none in the third). Timed is the steady
state; the first, cold call's time is printed beside it, and the page faults of
the timed slices (a few thousand: lsq_linear's calls between them move the heap).
The machine may be shared, so the two are
timed interleaved: the frames are cut into ``N_SLICES`` consecutive slices and
each slice's solve by ours is followed by lsq_linear on the slice's share of an
evenly spaced subset (``N_BVLS`` frames in all). Ours is the sum over the
slices, i.e. all frames (the "ours s(T)" column), each slice passed as a view
of the data (a copy, 11 MB of fresh pages, would be timed as the solver's
work); lsq_linear's per-frame time is extrapolated to all frames ("bvls s(T)").
The ratio is of the totals; "ratio range" gives the slices' lowest and highest
ratio. Environment: BENCH_T and BENCH_BVLS override the two sizes for a quick
run.

Both solvers run on one BLAS thread (``OPENBLAS_NUM_THREADS=1`` unless set):
per-frame work is products of 53-wide matrices, and on a shared 2-core
machine a threaded BLAS made lsq_linear up to 25x slower (105 ms a frame
instead of 4 ms), which inflated the ratio to 1200x.

The last lines count the distinct active sets (which weights end at which
bound) over the frames: frames that share one could share one factorization.
"""

from __future__ import annotations

import os
import resource
import sys
import time
from pathlib import Path

# one BLAS thread for both sides, set before NumPy loads its BLAS (see above)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import trimesh  # noqa: E402
from scipy.optimize import lsq_linear  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import peak_memory_mb, shared_data  # noqa: E402

from fit.solve.weights import solve_weights  # noqa: E402

N_FRAMES = int(os.environ.get("BENCH_T", 35_000))
N_MARKERS = 66
N_BVLS = int(os.environ.get("BENCH_BVLS", 100))
N_SLICES = 5
MAX_WARM_UPS = 3
NOISE_MM = 0.2
CM_TO_MM = 10.0


def load_basis(root: Path, rng) -> tuple[np.ndarray, list[str]]:
    """Marker-space basis (198, 53) in mm and the shape names."""
    face = root / "ict-face"
    paths = sorted((face / "expressions").glob("*.obj"))
    if len(paths) != 53:
        sys.exit(f"expected the 53 ICT expressions in {face / 'expressions'}, found {len(paths)}")
    neutral = trimesh.load(face / "generic_neutral_mesh.obj", process=False).vertices
    picked = np.sort(rng.choice(len(neutral), N_MARKERS, replace=False))
    shapes = [trimesh.load(p, process=False).vertices[picked] - neutral[picked] for p in paths]
    basis = CM_TO_MM * np.stack(shapes).reshape(len(paths), -1).T
    return basis, [p.stem for p in paths]


def arkit_column(name: str, columns) -> str:
    """ICT name -> ARKit column: mouthSmile_L -> MouthSmileLeft, cheekPuff_L -> CheekPuff."""
    base = name[0].upper() + name[1:]
    for suffix, side in (("_L", "Left"), ("_R", "Right")):
        if base.endswith(suffix):
            sided = base[:-2] + side
            return sided if sided in columns else base[:-2]
    return base


def performance_weights(root: Path, names: list[str]) -> np.ndarray:
    """Real weights (N_FRAMES, 53) in [0, 1] from the ARKit performances."""
    tables = [pd.read_csv(p) for p in sorted((root / "arkit-performances").glob("*.csv"))]
    table = pd.concat(tables, ignore_index=True)
    weights = np.stack([table[arkit_column(n, table.columns)].to_numpy(float)
                        for n in names], axis=1)
    src = np.linspace(0.0, 1.0, len(weights))
    dst = np.linspace(0.0, 1.0, N_FRAMES)
    resampled = np.stack([np.interp(dst, src, col) for col in weights.T], axis=1)
    return np.clip(resampled, 0.0, 1.0)


def bvls(basis, frames):
    return np.array([lsq_linear(basis, d, bounds=(0.0, 1.0), method="bvls",
                                max_iter=10_000).x for d in frames])


def run(label, basis, truth, rng):
    data = truth @ basis.T + NOISE_MM * rng.standard_normal((len(truth), basis.shape[0]))
    subset = np.linspace(0, len(data) - 1, N_BVLS).astype(int)
    cold = warm_up(basis, [data[f[0]:f[-1] + 1]
                           for f in np.array_split(np.arange(len(data)), N_SLICES)])
    bvls(basis, data[subset[:2]])
    faults = page_faults()
    ours, theirs, rel, conv, iters, solved = [], [], [], [], [], []
    for frames in np.array_split(np.arange(len(data)), N_SLICES):
        start = time.perf_counter()
        sol = solve_weights(basis, data[frames[0]:frames[-1] + 1], lower=0.0, upper=1.0)
        ours.append(time.perf_counter() - start)
        picked = subset[(subset >= frames[0]) & (subset <= frames[-1])]
        start = time.perf_counter()
        ref_w = bvls(basis, data[picked])
        theirs.append(time.perf_counter() - start)
        ref_cost = 0.5 * np.sum((ref_w @ basis.T - data[picked]) ** 2, axis=1)
        rel.append(np.abs(sol.cost[picked - frames[0]] - ref_cost) / ref_cost)
        conv.append(sol.converged)
        iters.append(sol.n_iter)
        solved.append(sol.weights)
    faults = page_faults() - faults
    per_frame = sum(ours) / len(data)
    bvls_frame = sum(theirs) / len(subset)
    slices = [(t / max(1, n)) / (o / len(f)) for t, o, n, f in zip(
        theirs, ours, [len(r) for r in rel], np.array_split(np.arange(len(data)), N_SLICES))]
    print(f"{label:<24} {len(data):>6} {per_frame * 1e6:>9.1f} {sum(ours):>8.2f} "
          f"{bvls_frame * 1e6:>9.0f} {bvls_frame * len(data):>9.1f} "
          f"{bvls_frame / per_frame:>7.0f}x {min(slices):>6.0f}-{max(slices):<6.0f} "
          f"{np.concatenate(rel).max():>9.2e} {np.concatenate(conv).mean() * 100:>6.1f}% "
          f"{np.concatenate(iters).mean():>5.2f}")
    print(f"{'':<24} cold first call {cold * 1e6:.1f} us/f ({bvls_frame / cold:.0f}x); "
          f"{faults} page faults in the timed slices")
    return data, np.concatenate(solved)


def page_faults() -> int:
    """Minor page faults of this process so far."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt


def warm_up(basis, slices) -> float:
    """Solve every slice of `slices` in turn until a pass makes no new page faults (at most
    MAX_WARM_UPS passes); return the first, cold solve's time per frame, s."""
    start = time.perf_counter()
    solve_weights(basis, slices[0], lower=0.0, upper=1.0)
    cold = (time.perf_counter() - start) / len(slices[0])
    for _ in range(MAX_WARM_UPS):
        before = page_faults()
        for frames in slices:
            solve_weights(basis, frames, lower=0.0, upper=1.0)
        if page_faults() == before:
            break
    return cold


def active_set_stats(label, weights):
    """Distinct active sets over the frames, and how often neighbours share theirs."""
    at_lo, at_hi = weights <= 0.0, weights >= 1.0
    packed = np.concatenate([np.packbits(at_lo, axis=1), np.packbits(at_hi, axis=1)], axis=1)
    distinct = len(np.unique(packed, axis=0))
    bound = at_lo | at_hi
    same = np.mean((packed[1:] == packed[:-1]).all(axis=1)) * 100
    print(f"{label:<24} {distinct:>6} distinct active sets in {len(weights)} frames; "
          f"neighbours share theirs in {same:.1f}% of frames; "
          f"{np.count_nonzero(bound, axis=1).mean():.1f} weights at a bound a frame")


def main():
    root = shared_data()
    rng = np.random.default_rng(20240501)
    basis, names = load_basis(root, rng)
    sv = np.linalg.svd(basis, compute_uv=False)
    print(f"basis: {basis.shape[0]} rows (66 markers x 3) x {basis.shape[1]} shapes, "
          f"cond(B) = {sv[0] / sv[-1]:.3g}; bounds [0, 1]; noise {NOISE_MM} mm; "
          f"lsq_linear(bvls) on {N_BVLS} evenly spaced frames, total extrapolated")
    print(f"{'frames':<24} {'T':>6} {'ours us/f':>9} {'ours s(T)':>8} {'bvls us/f':>9} "
          f"{'bvls s(T)':>9} {'ratio':>8} {'ratio range':>13} {'max rel':>9} {'conv':>7} "
          f"{'iters':>5}")
    data, arkit = run("ARKit performances", basis, performance_weights(root, names), rng)
    uniform = run("i.i.d. uniform weights", basis,
                  rng.uniform(0.0, 1.0, (N_FRAMES, basis.shape[1])), rng)[1]
    print(f"BLAS threads: OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}")
    active_set_stats("ARKit performances", arkit)
    active_set_stats("i.i.d. uniform weights", uniform)
    part = data[:5000]
    mem = peak_memory_mb(lambda: solve_weights(basis, part, lower=0.0, upper=1.0))
    print(f"peak memory of a 5,000-frame solve: {mem:.0f} MB (tracemalloc): a few (T, n) "
          "arrays and the (m + 1, m, up to 2048) batches of reduced systems")


if __name__ == "__main__":
    main()
