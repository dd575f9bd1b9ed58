"""Benchmark: PCA of a mesh sequence without materializing it, vs a dense SVD.

A 35,000-frame, 66-marker take (the quasi-eigen paper's size) retargeted to
the 9,409-vertex ICT face by an RBF operator W: implicit PCA
(:func:`basis.pca.pca_from_operator`) against a dense SVD of the materialized
Ξ = W·D for 6,000 frames (the paper's training size; it reports 158 min), and
the streaming methods on the same 6,000 materialized frames. Displacements
are a smooth synthetic signal of 25 active modes plus noise.

Usage: ``python bench/bench_pca.py [--frames 35000] [--dense-frames 6000]``.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import trimesh
from _common import best_time, peak_memory_mb, shared_data
from scipy.linalg import subspace_angles, svd

from basis.pca import PCA_METHODS, pca_from_operator, pca_streaming

RATE_HZ = 120.0
N_MARKERS = 66
PAPER_MINUTES = 158


def rbf_operator(root):
    """W (N, 66) on the ICT neutral mesh from 66 Multi-PIE landmark vertices, and its origin."""
    mesh = trimesh.load(root / "ict-face" / "generic_neutral_mesh.obj", process=False)
    landmarks = json.loads((root / "ict-face" / "vertex_indices.json").read_text())
    centers = mesh.vertices[landmarks["multi_pie_68_landmarks"][:N_MARKERS]]
    try:
        from mocap.retarget.rbf import build_rbf_operator
    except ImportError:
        return _thin_plate_operator(centers, mesh.vertices), "own thin-plate spline (no mocap.retarget.rbf)"
    op = build_rbf_operator(centers, mesh.vertices, kernel="thin_plate_spline")
    return op.matrix, "mocap.retarget.rbf.build_rbf_operator, thin_plate_spline"


def _thin_plate_operator(centers, points):
    """Fallback: r² log r kernel with an affine tail, solved for the identity."""
    def kernel(a, b):
        r = np.linalg.norm(a[:, None] - b[None], axis=2)
        return np.where(r > 0, r ** 2 * np.log(np.where(r > 0, r, 1)), 0.0)
    m = len(centers)
    poly = np.hstack([np.ones((m, 1)), centers])
    system = np.block([[kernel(centers, centers), poly], [poly.T, np.zeros((4, 4))]])
    coef = np.linalg.solve(system, np.vstack([np.eye(m), np.zeros((4, m))]))
    return np.hstack([kernel(points, centers), np.ones((len(points), 1)), points]) @ coef


def synthetic_take(n_frames, rng, n_modes=25, noise_mm=0.05):
    """Marker displacements (T, 66, 3), mm: smooth modes of decaying amplitude + noise."""
    t = np.arange(n_frames)[:, None] / RATE_HZ
    freq = rng.uniform(0.05, 2.0, size=(3, n_modes))
    phase = rng.uniform(0, 2 * np.pi, size=(3, n_modes))
    activation = sum(np.sin(2 * np.pi * freq[i] * t + phase[i]) for i in range(3))
    shapes = rng.normal(size=(n_modes, 3 * N_MARKERS)) * (8.0 * 0.8 ** np.arange(n_modes))[:, None]
    disp = activation @ shapes
    disp += noise_mm * rng.normal(size=disp.shape)
    return disp.reshape(n_frames, N_MARKERS, 3)


def timed(fn):
    """Run ``fn()`` once under tracemalloc: (result, seconds, peak MB)."""
    out = {}

    def run():
        start = time.perf_counter()
        out["result"] = fn()
        out["seconds"] = time.perf_counter() - start
    peak = peak_memory_mb(run)
    return out["result"], out["seconds"], peak


def dense_svd(operator, disp):
    """Baseline: materialize Ξ (T, N, 3), centre it, thin SVD; eigenvalues and axes."""
    xi = (operator @ disp).reshape(len(disp), -1)
    xi -= xi.mean(axis=0)
    _, s, vt = svd(xi, full_matrices=False, overwrite_a=True, check_finite=False)
    return s ** 2 / len(disp), vt


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=35000)
    parser.add_argument("--dense-frames", type=int, default=6000)
    parser.add_argument("--components", type=int, default=30,
                        help="components of the streaming methods")
    args = parser.parse_args()

    operator, origin = rbf_operator(shared_data())
    disp = synthetic_take(args.frames, np.random.default_rng(0))
    head = disp[:args.dense_frames]
    n_vertices = operator.shape[0]
    print(f"W: {operator.shape[0]} vertices x {operator.shape[1]} markers ({origin}); "
          f"take: {args.frames} frames, 25 modes + noise")

    print(f"\n{'method':<38}{'frames':>8}{'time [s]':>12}{'peak [MB]':>12}")

    def row(name, frames, seconds, mem):
        print(f"{name:<38}{frames:>8}{seconds:>12.3f}{mem:>12.0f}", flush=True)

    t_full = best_time(lambda: pca_from_operator(operator, disp))
    mem_full = peak_memory_mb(lambda: pca_from_operator(operator, disp))
    full = pca_from_operator(operator, disp)
    row("implicit pca_from_operator", args.frames, t_full, mem_full)
    t_imp = best_time(lambda: pca_from_operator(operator, head))
    mem_imp = peak_memory_mb(lambda: pca_from_operator(operator, head))
    implicit = pca_from_operator(operator, head)
    row("implicit pca_from_operator", len(head), t_imp, mem_imp)

    (evals, vt), t_dense, mem_dense = timed(lambda: dense_svd(operator, head))
    row("dense SVD of materialized Xi", len(head), t_dense, mem_dense)
    xi = operator @ head
    streaming = {}
    for method in PCA_METHODS:
        streaming[method], t, mem = timed(lambda: pca_streaming(
            xi, n_components=args.components, method=method))
        row(f"pca_streaming {method} (m={args.components})", len(head), t, mem)
    del xi

    print(f"\nspeed-up of implicit over dense SVD at {len(head)} frames: x{t_dense / t_imp:,.0f}"
          f"  (paper: {PAPER_MINUTES} min = {PAPER_MINUTES * 60} s for 6,000 frames)")
    if len(head) != 6000:
        print(f"dense SVD extrapolated to 6,000 frames with its O(T^2 * 3N) cost: "
              f"~{t_dense * (6000 / len(head)) ** 2:,.0f} s (an estimate, not measured)")
    print(f"Xi of the full take would be {args.frames * n_vertices * 3 * 8 / 1e9:.1f} GB "
          "in float64", flush=True)

    k = 18
    print(f"\nagreement with the dense SVD at {len(head)} frames, top {k} components:")
    for name, model in [("implicit", implicit)] + list(streaming.items()):
        rel = np.max(np.abs(model.eigenvalues[:k] - evals[:k]) / evals[:k])
        angle = subspace_angles(model.components[:k].reshape(k, -1).T, vt[:k].T).max()
        total = abs(model.total_variance - evals.sum()) / evals.sum()
        print(f"  {name:<12} eigenvalues max rel diff {rel:.1e}, largest principal angle "
              f"{angle:.1e} rad, total variance rel diff {total:.1e}")
    print(f"\nfull take: {full.n_for_coverage(0.995)} components cover 99.5% "
          f"(paper: 18), {full.n_components} of numerical rank")


if __name__ == "__main__":
    main()
