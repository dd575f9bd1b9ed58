"""Benchmark: weights and meshes recovered from a simulated capture with known truth (issue 5, item 2).

The ICT face (53 shapes, cm) is driven by the real ARKit performance
``alex_rom_4.csv`` (30 Hz), seen by the 66 markers of
``tests/ict_marker_layout.toml`` with :func:`mocap.synth.simulate_capture`
(0.2 mm noise, head motion, 40 gaps). The chain of ``mocap2mesh run`` then
fills the gaps, stabilizes, binds the neutral frame (the frame of smallest
total weight: the performance never rests at zero), retargets and fits the H
weights, in marker and in mesh space.

Displacements are taken from that neutral frame f, so the recoverable truth is
w(t) − w(f): with bounds [0, 1] the solved weights are compared with w(t)
(the rest offset w(f) is a bias no fit can remove), unbounded with w(t) − w(f).
Per-vertex error: ‖(ŵ(t) − (w(t) − w(f))) E‖ in mm over the face (vertices
within 15 mm of a marker).

Usage: ``python bench/bench_ground_truth.py``.
"""

from __future__ import annotations

import time
import warnings

import numpy as np
from _common import REPO, shared_data
from scipy.spatial import cKDTree

from basis.artist import load_artist_basis
from fit.ingest import IngestOptions
from fit.pipeline import (BasisResult, BindOptions, FitOptions, NamedBasis, bind_stage,
                          complete_span, fit_stage, ingest_stage, retarget_stage)
from mocap.layout import load_marker_layout
from mocap.markerset import load_markerset
from mocap.performance import read_performance
from mocap.synth import simulate_capture

MM_PER_CM = 10.0
FACE_MM = 15.0


def main() -> None:
    root = shared_data()
    ict = root / "ict-face"
    basis = load_artist_basis(ict / "generic_neutral_mesh.obj", ict / "expressions", units="cm")
    mesh = basis.neutral
    markerset = load_markerset(REPO / "tests" / "ict_markerset.toml")
    layout = load_marker_layout(REPO / "tests" / "ict_marker_layout.toml", mesh)
    from mocap.mesh_landmarks import load_mesh_landmarks
    landmarks = load_mesh_landmarks(REPO / "tests" / "ict_landmarks.toml", mesh)
    performance = read_performance(root / "arkit-performances" / "alex_rom_4.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                   # TongueOut: no ICT shape
        sim = simulate_capture(basis, performance, layout, markerset.head, rate=30.0,
                               noise_mm=0.2, n_gaps=40, seed=1)
    truth = sim.truth.weights
    assert tuple(sim.truth.shape_names) == tuple(basis.names)
    tic = time.perf_counter()
    ingested = ingest_stage(sim.take, markerset, IngestOptions(fill="auto"))
    take = complete_span(ingested.take, markerset.face_markers)
    offset = take.first_frame - sim.take.first_frame
    truth = truth[offset:offset + take.n_frames]
    frame = int(np.argmin(truth.sum(axis=1)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bound = bind_stage(take, markerset, mesh, landmarks,
                           options=BindOptions(frame=frame, skin_offset=2.0))
    retargeted = retarget_stage(take, bound, mesh, markerset)
    print(f"alex_rom_4: {take.n_frames} frames at 30 Hz, {len(retargeted.labels)} face "
          f"markers, {int(sim.truth.missing.sum())} missing samples filled, neutral frame "
          f"{frame} (Σw = {truth[frame].sum():.3f}, max w = {truth[frame].max():.3f}), "
          f"binding rms {bound.binding.rms:.2f} mm; ingest..retarget "
          f"{time.perf_counter() - tic:.1f} s")
    E = basis.displacements.reshape(len(basis.names), -1)
    centers = bound.binding.marker_points(mesh.vertices)
    face = cKDTree(centers).query(mesh.vertices)[0] * MM_PER_CM <= FACE_MM
    rel = truth - truth[frame]
    print(f"\n{'space':<7} {'bounds':<10} {'compared with':<14} {'RMSE w':>7} {'max |Δw|':>8} "
          f"{'mesh mean mm':>12} {'mesh p95 mm':>11} {'mesh max mm':>11} {'fit s':>6}")
    for space in ("marker", "mesh"):
        for eps, label, ref in ((0.0, "[0, 1]", truth), (1e6, "none", rel)):
            bases = BasisResult(bases={"H": NamedBasis(basis.names, basis.displacements)},
                                pca=None, n_components=0, qe=None)
            tic = time.perf_counter()
            fitted = fit_stage(take, bound, retargeted, bases,
                               options=FitOptions(space=space, h_epsilon=eps))
            seconds = time.perf_counter() - tic
            w = fitted.weights["H"]
            err = w - ref
            errs = []
            for start in range(0, len(w), 256):
                d = ((w[start:start + 256] - rel[start:start + 256]) @ E).reshape(
                    -1, mesh.n_vertices, 3)
                errs.append(MM_PER_CM * np.linalg.norm(d[:, face], axis=-1).ravel())
            errs = np.concatenate(errs)
            print(f"{space:<7} {label:<10} {'w(t)' if ref is truth else 'w(t) - w(f)':<14} "
                  f"{np.sqrt(np.mean(err ** 2)):>7.4f} {np.abs(err).max():>8.3f} "
                  f"{errs.mean():>12.3f} {np.percentile(errs, 95):>11.3f} {errs.max():>11.3f} "
                  f"{seconds:>6.2f}")
    print("\naim: RMSE between solved and true weights ≤ 0.02")


if __name__ == "__main__":
    main()
