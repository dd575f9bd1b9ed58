"""Benchmark: the whole chain on a 35,000-frame, 66-marker take onto the ICT face (issue 5, item 3).

The take is simulated (:func:`mocap.synth.capture.simulate_capture`: the ICT face
driven by ``alex_rom_4.csv``, sampled at 276 Hz so that its 127 s give 35,000
frames; 66 markers of ``tests/ict_marker_layout.toml``, 0.2 mm noise, head
motion, 60 gaps) and written to C3D. Timed per stage, as ``mocap2mesh run``
runs them (:mod:`fit.pipeline.stages`): read + ingest (gap fill, stabilization),
bind (with the layout's 2 mm skin offset), retarget (W), bases (PCA of W·D
without Ξ, quasi-eigen), fit (H at the exact marker centres, QE, PCA in marker
space), exports (CSV, compact mesh npz, glb per basis) and the QA
figures (no video). Peak memory: the process's maximum resident set size.

Baseline, the naive chain, on the first ``--naive-frames`` frames: an RBF
(scipy ``RBFInterpolator``) rebuilt for every frame, a dense SVD of the
materialized Ξ for PCA, and ``scipy.optimize.lsq_linear`` per frame and basis.
Ratios are per frame.

Usage: ``python bench/bench_chain.py [--frames 35000] [--naive-frames 200]``.
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
from _common import REPO, shared_data
from scipy.interpolate import RBFInterpolator
from scipy.optimize import lsq_linear

import mocap
from basis.artist import ArtistBasis, load_artist_basis
from basis.basis_io import save_basis
from basis.gltf import write_gltf
from fit.exports import write_mesh_sequence, write_weights_csv
from fit.pipeline import (
    BindOptions,
    basis_stage,
    bind_stage,
    complete_span,
    fit_stage,
    ingest_stage,
    retarget_stage,
)
from fit.report import build_report
from mocap.clean.ingest import IngestOptions
from mocap.markerset import load_markerset
from mocap.mesh.landmarks import load_mesh_landmarks
from mocap.mesh.layout import load_marker_layout
from mocap.synth.capture import simulate_capture
from mocap.synth.performance import read_performance


def simulate(frames: int, path: Path):
    ict = shared_data() / "ict-face"
    basis = load_artist_basis(ict / "generic_neutral_mesh.obj", ict / "expressions", units="cm")
    markerset = load_markerset(REPO / "tests" / "ict_markerset.toml")
    layout = load_marker_layout(REPO / "tests" / "ict_marker_layout.toml", basis.neutral)
    performance = read_performance(shared_data() / "arkit-performances" / "alex_rom_4.csv")
    rate = 276.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = simulate_capture(basis, performance, layout, markerset.head, rate=rate,
                               duration=(frames - 0.5) / rate, noise_mm=0.2, n_gaps=60, seed=2)
    mocap.write(sim.take, path)
    return basis, markerset, sim.take


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=35_000)
    parser.add_argument("--naive-frames", type=int, default=200)
    args = parser.parse_args()
    out = Path(tempfile.mkdtemp(prefix="bench_chain_"))
    artist, markerset, sim_take = simulate(args.frames, out / "take.c3d")
    mesh = artist.neutral
    landmarks = load_mesh_landmarks(REPO / "tests" / "ict_landmarks.toml", mesh)
    print(f"take: {sim_take.n_frames} frames, {sim_take.n_markers} markers "
          f"({len(markerset.face_markers)} face), {int(sim_take.missing.sum())} missing "
          f"samples; ICT face {mesh.n_vertices} vertices, {artist.n_shapes} shapes")
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    times = {}

    def timed(name, fn):
        tic = time.perf_counter()
        result = fn()
        times[name] = time.perf_counter() - tic
        return result

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ingested = timed("read + ingest", lambda: ingest_stage(
            mocap.read(out / "take.c3d"), markerset,
            IngestOptions(fill="auto", max_gap=sim_take.n_frames)))      # every gap, asked
        take = complete_span(ingested.take, markerset.face_markers)
        bound = timed("bind", lambda: bind_stage(take, markerset, mesh, landmarks,
                                                 options=BindOptions(skin_offset=2.0)))
        retargeted = timed("retarget (W)", lambda: retarget_stage(take, bound, mesh, markerset))
        bases = timed("bases (PCA, QE)", lambda: basis_stage(retargeted, artist))
        fitted = timed("fit (H, QE, PCA)", lambda: fit_stage(take, bound, retargeted, bases))

        def exports():
            for name, b in bases.bases.items():
                w = fitted.weights[name]
                save_basis(ArtistBasis(b.names, mesh, b.displacements), out / f"basis-{name}.npz",
                           dtype="float32")
                write_weights_csv(out / f"weights-{name}.csv", w, b.names, rate=take.rate)
                write_mesh_sequence(out / f"mesh-{name}.npz", mesh, b.displacements, w,
                                    names=b.names, rate=take.rate)
                write_gltf(out / f"face-{name}.glb", mesh, b.displacements, b.names, weights=w,
                           rate=take.rate)
        timed("exports", exports)
        face = take.select(retargeted.labels)
        (out / "report").mkdir()
        timed("QA figures + HTML", lambda: build_report(
            face, fitted.reconstructed, face.positions[bound.frame], out / "report",
            markerset=markerset, pca=bases.pca, ingest=ingested, video=False))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    total = sum(times.values())
    T = take.n_frames
    print(f"\n{'stage':<20} {'seconds':>8}")
    for name, sec in times.items():
        print(f"{name:<20} {sec:>8.2f}")
    print(f"{'total':<20} {total:>8.2f}   (aim < 60 s)")
    print(f"peak RSS {peak:.2f} GB (after the simulation: {rss0:.2f} GB; aim < 3 GB); "
          f"PCA m = {bases.n_components}")

    # naive chain on a subset of frames
    n = min(args.naive_frames, T)
    binding = bound.binding
    rows = [binding.labels.index(x) for x in retargeted.labels]
    centers = binding.marker_points(mesh.vertices)[rows]
    D = retargeted.displacements[:n]
    tic = time.perf_counter()
    xi = np.stack([RBFInterpolator(centers, d, kernel="thin_plate_spline")(mesh.vertices)
                   for d in D])
    naive = {"retarget (W)": time.perf_counter() - tic}
    tic = time.perf_counter()
    flat = xi.reshape(n, -1)
    np.linalg.svd(flat - flat.mean(axis=0), full_matrices=False)
    naive["bases (PCA, QE)"] = time.perf_counter() - tic
    tic = time.perf_counter()
    for name, b in bases.bases.items():
        at = binding.marker_points(b.displacements)[:, rows]
        B = at[b.n_fixed:].reshape(len(at) - b.n_fixed, -1).T
        data = (D - at[:b.n_fixed].sum(axis=0)).reshape(n, -1)
        lo, hi = (0, 1) if name == "H" else (-np.inf, np.inf)
        for d in data:
            lsq_linear(B, d, bounds=(lo, hi), method="bvls")
    naive["fit (H, QE, PCA)"] = time.perf_counter() - tic
    print(f"\nnaive chain on {n} frames vs ours on {T} (per frame):")
    print(f"{'stage':<20} {'naive ms/frame':>14} {'ours ms/frame':>13} {'ratio':>8}")
    for name, sec in naive.items():
        ours = 1e3 * times[name] / T
        print(f"{name:<20} {1e3 * sec / n:>14.3f} {ours:>13.4f} {1e3 * sec / n / ours:>7.0f}×")
    naive_total = sum(naive.values()) / n
    ours_total = sum(times[k] for k in naive) / T
    print(f"{'retarget+bases+fit':<20} {1e3 * naive_total:>14.3f} {1e3 * ours_total:>13.4f} "
          f"{naive_total / ours_total:>7.0f}×")
    print(f"naive chain extrapolated to {T} frames: {naive_total * T / 60:.0f} min "
          f"(the SVD grows faster than linearly)")


if __name__ == "__main__":
    main()
