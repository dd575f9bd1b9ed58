"""Exact batched weight solver vs scipy's lsq_linear(method="bvls") frame by frame.

Basis: 66 vertices (seeded sample) of the 53 ICT expression shapes, as
displacements from the neutral in mm (a marker-space basis, K = 198).
Frames: known weights from the two real ARKit performances (mapped to the
ICT shape names, clipped to [0, 1]), concatenated and linearly resampled to
35,000 frames (~ the quasi-eigen paper's take), imaged by the basis, plus
0.2 mm Gaussian noise. A second row uses i.i.d. uniform weights (no temporal
coherence: the warm start cannot help). Bounds [0, 1].

Ours is timed once, on the whole 35,000-frame solve. lsq_linear runs on an
evenly spaced subset (100 frames); its total is extrapolated to all frames
(per-frame time × T), as the table header says. Environment: BENCH_T and
BENCH_BVLS override the two sizes for a quick run.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import trimesh
from scipy.optimize import lsq_linear

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import peak_memory_mb, shared_data  # noqa: E402

from fit.solve import solve_weights  # noqa: E402

N_FRAMES = int(os.environ.get("BENCH_T", 35_000))
N_MARKERS = 66
N_BVLS = int(os.environ.get("BENCH_BVLS", 100))
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
    start = time.perf_counter()
    sol = solve_weights(basis, data, lower=0.0, upper=1.0)
    ours = time.perf_counter() - start
    subset = np.linspace(0, len(data) - 1, N_BVLS).astype(int)
    start = time.perf_counter()
    ref_w = bvls(basis, data[subset])
    theirs = (time.perf_counter() - start) / len(subset)
    ref_cost = 0.5 * np.sum((ref_w @ basis.T - data[subset]) ** 2, axis=1)
    rel = np.abs(sol.cost[subset] - ref_cost) / ref_cost
    per_frame = ours / len(data)
    print(f"{label:<28} {len(data):>7} {per_frame * 1e6:>10.1f} {theirs * 1e6:>10.0f} "
          f"{theirs * len(data):>9.1f} {theirs / per_frame:>7.0f}x {rel.max():>10.2e} "
          f"{sol.converged.mean() * 100:>6.1f}% {sol.n_iter.mean():>5.2f}")
    return data


def main():
    root = shared_data()
    rng = np.random.default_rng(20240501)
    basis, names = load_basis(root, rng)
    sv = np.linalg.svd(basis, compute_uv=False)
    print(f"basis: {basis.shape[0]} rows (66 markers x 3) x {basis.shape[1]} shapes, "
          f"cond(B) = {sv[0] / sv[-1]:.3g}; bounds [0, 1]; noise {NOISE_MM} mm; "
          f"lsq_linear(bvls) on {N_BVLS} evenly spaced frames, total extrapolated")
    print(f"{'frames':<28} {'T':>7} {'ours us/f':>10} {'bvls us/f':>10} {'bvls s(T)':>9} "
          f"{'ratio':>8} {'max rel':>10} {'conv':>7} {'iters':>5}")
    data = run("ARKit performances", basis, performance_weights(root, names), rng)
    run("i.i.d. uniform weights", basis, rng.uniform(0.0, 1.0, (N_FRAMES, basis.shape[1])), rng)
    part = data[:5000]
    mem = peak_memory_mb(lambda: solve_weights(basis, part, lower=0.0, upper=1.0))
    print(f"peak memory of a 5,000-frame solve: {mem:.0f} MB (tracemalloc); the gathered "
          "(2048, n, n) chunks bound it, so it grows slowly with T")


if __name__ == "__main__":
    main()
