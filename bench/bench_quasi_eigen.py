"""Benchmark: quasi-eigen faces of the ICT shapes from a real capture (issue 4, item 1).

facial-sing.c3d (31 face markers, 3000 frames at 100 Hz) is gap-filled and
head-stabilized, bound to the ICT face (automatic neutral frame) and
retargeted by the RBF operator W; the PCA of Ξ = W·D is computed exactly
without forming Ξ (:func:`basis.pca.pca_from_operator`), timed against a dense
SVD of Ξ materialized for the first ``--dense-frames`` frames (the baseline).
Prints the coverage curve, m for 99 % and 99.5 %, and the quasi-eigen faces
of the 53 ICT shapes at 99.5 %: relative moves and largest vertex moves
(sorted by move) and the missing PCA axes. Writes ``bench/out/qe_coverage.png``,
``bench/out/qe_moves.csv`` and comparison pictures ``bench/out/qe_<shape>.png``.

Usage: ``python bench/bench_quasi_eigen.py [--dense-frames 1000] [--shapes a,b,...]``.
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np
from _common import FACIAL_SING_MAX_GAP, REPO, best_time, peak_memory_mb, shared_data
from scipy.linalg import svd

import mocap
from basis.artist import load_artist_basis
from basis.comparison import comparison_sheet, move_table, save_move_table
from basis.coverage import plot_coverage
from basis.pca import pca_from_operator
from basis.quasi_eigen import quasi_eigen
from mocap.bind import bind_take
from mocap.clean.ingest import IngestOptions, ingest
from mocap.markerset import load_markerset
from mocap.mesh.landmarks import load_mesh_landmarks
from mocap.retarget.retargeting import RetargetOptions, retarget
from mocap.viz.render import save_png

OUT = REPO / "bench" / "out"
TELLING = ("jawOpen", "mouthSmile_L", "browInnerUp_L", "eyeBlink_L")


def real_experiment(root: Path, options: RetargetOptions = RetargetOptions()):
    """Ingest, bind and retarget facial-sing onto the ICT face: (Retargeting, binding, frame)."""
    take = mocap.read(root / "captures" / "facial-sing.c3d")
    markerset = load_markerset(REPO / "tests" / "facial_sing_markerset.toml")
    artist = load_artist_basis(root / "ict-face" / "generic_neutral_mesh.obj",
                               root / "ict-face" / "expressions", units="cm")
    landmarks = load_mesh_landmarks(REPO / "tests" / "ict_landmarks.toml", artist.neutral)
    ingested = ingest(take, markerset=markerset, options=IngestOptions(
        fill="auto", max_gap=FACIAL_SING_MAX_GAP, stabilize=True))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        bound = bind_take(ingested.cleaned, markerset, artist.neutral, landmarks)
        binding, frame = bound.binding, bound.frame
    for w in caught:
        print(f"  bind warning: {str(w.message)[:150]}")
    retargeted = retarget(ingested.take, binding, artist.neutral, markerset,
                          options=options, neutral_frame=frame)
    return retargeted, artist, binding, frame


def dense_pca(operator, disp):
    """Baseline: materialize Ξ (T, N, 3), centre it, thin SVD -> eigenvalues (1/T)."""
    xi = np.einsum("nm,tmc->tnc", operator, disp).reshape(len(disp), -1)
    xi -= xi.mean(axis=0)
    s = svd(xi, full_matrices=False, compute_uv=False, overwrite_a=True, check_finite=False)
    return s ** 2 / len(disp)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dense-frames", type=int, default=1000,
                        help="frames of the dense-SVD baseline (Ξ held in memory)")
    parser.add_argument("--shapes", default=",".join(TELLING),
                        help="shapes drawn in the comparison pictures")
    parser.add_argument("--kernel", default="thin_plate_spline", help="RBF kernel")
    parser.add_argument("--distance", default="euclidean", help="euclidean or geodesic")
    parser.add_argument("--epsilon", type=float, default=None, help="kernel shape, 1/cm")
    args = parser.parse_args()
    options = RetargetOptions(kernel=args.kernel, distance=args.distance, epsilon=args.epsilon)
    tag = "" if args.kernel == "thin_plate_spline" and args.distance == "euclidean" else (
        f"_{args.kernel}-{args.distance}")
    OUT.mkdir(parents=True, exist_ok=True)

    start = time.perf_counter()
    r, artist, binding, frame = real_experiment(shared_data(), options)
    operator = np.asarray(r.operator.matrix)
    disp = r.displacements
    print(f"facial-sing -> ICT: {r.n_frames} frames, {len(r.labels)} face markers, "
          f"neutral frame {frame}, binding rms {binding.rms:.2f} mm, scale "
          f"{binding.scale:.4f} cm/mm; W {operator.shape} ({r.operator.kernel}); "
          f"ingest+bind+retarget {time.perf_counter() - start:.1f} s")
    extent = np.abs(disp).max(axis=(0, 2))
    print(f"marker displacement from the neutral frame: median of per-marker max "
          f"{np.median(extent):.3f} cm, largest {extent.max():.3f} cm "
          f"({r.labels[int(np.argmax(extent))]})")

    print(f"\n{'PCA':<40}{'frames':>8}{'time [s]':>11}{'peak [MB]':>11}")
    t_imp = best_time(lambda: pca_from_operator(operator, disp))
    mem_imp = peak_memory_mb(lambda: pca_from_operator(operator, disp))
    model = pca_from_operator(operator, disp)
    print(f"{'implicit pca_from_operator':<40}{r.n_frames:>8}{t_imp:>11.3f}{mem_imp:>11.0f}")
    head = disp[:args.dense_frames]
    t_head = best_time(lambda: pca_from_operator(operator, head))
    small = pca_from_operator(operator, head)
    print(f"{'implicit pca_from_operator':<40}{len(head):>8}{t_head:>11.3f}")
    t0 = time.perf_counter()
    evals = dense_pca(operator, head)
    t_dense = time.perf_counter() - t0
    print(f"{'dense SVD of materialized Xi (baseline)':<40}{len(head):>8}{t_dense:>11.3f}")
    k = small.n_components
    rel = np.max(np.abs(small.eigenvalues - evals[:k]) / evals[0])
    print(f"speed-up x{t_dense / t_head:,.0f}; eigenvalues agree to {rel:.1e} of lambda_1 "
          f"({k} components of numerical rank)")

    cov = model.coverage()
    print(f"\nrank {model.n_components} (<= 3 x {len(r.labels)} markers = "
          f"{3 * len(r.labels)}); total variance {model.total_variance:.4g} cm^2")
    print("coverage, m = 1..30:")
    for row in range(0, 30, 10):
        print("  " + " ".join(f"{c:.4f}" for c in cov[row:row + 10]))
    m99, m995 = model.n_for_coverage(0.99), model.n_for_coverage(0.995)
    print(f"m for 99 %: {m99}    m for 99.5 %: {m995}   (paper, 66 markers: 18 for 99.5 %)")
    plot_coverage(model, OUT / f"qe_coverage{tag}.png", thresholds=(0.99, 0.995),
                  title="facial-sing on the ICT face: PCA coverage")

    pca = model.truncate(m995)
    t_qe = best_time(lambda: quasi_eigen(pca, artist.displacements, names=artist.names))
    qe = quasi_eigen(pca, artist.displacements, names=artist.names)
    table = move_table(qe, pca)
    save_move_table(table, OUT / f"qe_moves{tag}.csv")
    print(f"\nquasi-eigen faces of the {artist.n_shapes} ICT shapes on m = {m995} axes "
          f"({t_qe * 1e3:.1f} ms); sorted by relative move:")
    norms = np.linalg.norm(artist.displacements, axis=2).max(axis=1)
    print(f"  {'shape':<18}{'rel. move':>10}{'max vertex move [cm]':>22}{'H max [cm]':>12}"
          f"{'vertex':>8}")
    for i in np.argsort(-qe.relative_move):
        print(f"  {qe.names[i]:<18}{qe.relative_move[i]:>10.3f}{qe.max_vertex_move[i]:>22.3f}"
              f"{norms[i]:>12.3f}{qe.max_vertex[i]:>8}")
    rows = table[table.kind == "missing_axis"]
    print("missing axes (eps 0.05): " + (", ".join(
        f"{a} (column sum {c:.3f}, variance {100 * v:.2f} %)"
        for a, c, v in zip(rows.axis, rows.column_sum, rows.variance_share)) or "none"))
    print(f"median relative move {np.median(qe.relative_move):.3f}; "
          f"{int((qe.relative_move < 0.5).sum())} of {artist.n_shapes} shapes below 0.5")

    print("median relative move by m (truncation vs the rank-93 span of 31 markers):")
    for m in (m99, m995, 30, model.n_components):
        moves = quasi_eigen(model.truncate(m), artist.displacements).relative_move
        print(f"  m = {m:>3}: median {np.median(moves):.3f}, jawOpen "
              f"{moves[artist.index('jawOpen')]:.3f}, eyeBlink_L "
              f"{moves[artist.index('eyeBlink_L')]:.3f}")
    jump = np.linalg.norm(np.diff(disp, axis=0), axis=2) / binding.scale
    t, i = np.unravel_index(np.argmax(jump), jump.shape)
    print(f"largest frame-to-frame marker jump: {jump[t, i]:.1f} mm, {r.labels[i]} at frame "
          f"index {t + 1} (a label swap in the capture shows up here)")

    shapes = [s for s in args.shapes.split(",") if s]
    for name in shapes:
        save_png(comparison_sheet(artist.neutral, artist.displacements, qe, [name]),
                 OUT / f"qe_{name}{tag}.png")
    save_png(comparison_sheet(artist.neutral, artist.displacements, qe, shapes,
                              size=(260, 300)), OUT / f"qe_comparison{tag}.png")
    print(f"\nwrote {OUT}/qe_coverage.png, qe_moves.csv, qe_comparison.png and "
          f"qe_<shape>.png for {', '.join(shapes)}")


if __name__ == "__main__":
    main()
