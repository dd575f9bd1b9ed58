"""Benchmark: the session basis (one PCA/QE for every take of a run) against a dense PCA.

Takes: simulated captures of the ICT face (9,409 vertices, the 66-marker
layout of the tests: 60 face markers) driven by the two shared ARKit
performances at different starts, with head motion, noise and occlusions, each
take bound and retargeted on its own (its own operator W_k). Measured, in one
run:

- the session PCA (:func:`fit.pipeline.session_basis.session_basis`: pooled
  covariance of W_k D_k, never formed) against the baseline, a dense SVD of
  the mesh sequences materialized and concatenated: time, peak memory and
  their ratios, and how far apart they are (eigenvalues, principal angles);
- what the session basis costs a run: the stages each take goes through
  first (ingest, bind, retarget) against the whole of the take's run;
- why it matters: the angle between two takes' own PCA subspaces, and the
  reconstruction error α of each take in its own basis and in the session's.

Usage: ``python bench/bench_session_basis.py [--takes 3] [--seconds 8]``.
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np
from _common import REPO, best_time, peak_memory_mb, scratch_directory, shared_data
from scipy.linalg import subspace_angles, svd

import mocap
from basis.artist import load_artist_basis
from basis.pca import marker_moments
from fit.pipeline import BasisOptions, Reconstruction
from fit.pipeline.session_basis import TakeMoments, session_basis
from mocap.markerset import load_markerset
from mocap.mesh.layout import load_marker_layout
from mocap.synth.capture import simulate_capture
from mocap.synth.performance import read_performance

RATE_HZ = 60.0


def make_takes(root, n_takes, seconds, out: Path):
    """Simulated captures of the ICT face, written as C3D; returns the paths."""
    ict = root / "ict-face"
    basis = load_artist_basis(ict / "generic_neutral_mesh.obj", ict / "expressions", units="cm")
    markerset = load_markerset(REPO / "tests" / "ict_markerset.toml")
    layout = load_marker_layout(REPO / "tests" / "ict_marker_layout.toml", basis.neutral)
    performances = [read_performance(root / "arkit-performances" / f"alex_rom_{i}.csv")
                    for i in (3, 4)]
    paths = []
    for k in range(n_takes):
        performance = performances[k % 2]
        start = (k // 2) * seconds * 1.5
        sim = simulate_capture(basis, performance, layout, markerset.head, rate=RATE_HZ,
                               start=start, duration=seconds, noise_mm=0.2, n_gaps=10,
                               head_rotation_deg=8.0, head_translation_mm=15.0, seed=k)
        paths.append(out / f"take{k}.c3d")
        mocap.write(sim.take, paths[-1])
    return basis, markerset, paths


def dense_pooled(sequences):
    """Baseline: mean, eigenvalues (1/T) and components of the concatenated mesh frames."""
    flat = np.concatenate([x.reshape(len(x), -1) for x in sequences])
    mean = flat.mean(axis=0)
    _, s, vt = svd(flat - mean, full_matrices=False, overwrite_a=True, check_finite=False)
    return mean, s ** 2 / len(flat), vt


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--takes", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=8.0)
    args = parser.parse_args()
    root = shared_data()
    out = scratch_directory("bench_session_")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        artist, markerset, paths = make_takes(root, args.takes, args.seconds, out)
        recon = Reconstruction(markerset=markerset, mesh=artist.neutral,
                               landmarks=REPO / "tests" / "ict_landmarks.toml", basis=artist,
                               ingest={"max_gap": int(10 * RATE_HZ)})
        prep_seconds, prepared = [], []
        for path in paths:
            tic = time.perf_counter()
            prepared.append(recon.prepare(path))
            prep_seconds.append(time.perf_counter() - tic)
    moments = [TakeMoments(p.name, np.asarray(p.retargeted.operator.matrix),
                           marker_moments(p.retargeted.displacements)) for p in prepared]
    frames = sum(p.take.n_frames for p in prepared)
    n_vertices = artist.neutral.n_vertices
    print(f"{len(paths)} takes of {args.seconds:g} s at {RATE_HZ:g} Hz ({frames} frames in all, "
          f"{len(markerset.face_markers)} face markers), ICT face {n_vertices} vertices")

    shared = session_basis(moments, BasisOptions())
    ours = best_time(lambda: session_basis(moments, BasisOptions()))
    ours_mb = peak_memory_mb(lambda: session_basis(moments, BasisOptions()))
    sequences = [np.einsum("nm,tmc->tnc", np.asarray(p.retargeted.operator.matrix),
                           p.retargeted.displacements) for p in prepared]
    tic = time.perf_counter()
    mean, evals, vt = dense_pooled(sequences)
    dense = time.perf_counter() - tic
    dense_mb = peak_memory_mb(lambda: dense_pooled(sequences))
    m = shared.pca.n_components
    comps = shared.pca.components.reshape(m, -1)
    angle = np.degrees(subspace_angles(comps.T, vt[:m].T).max())
    rel = np.abs(shared.pca.eigenvalues / evals[:m] - 1).max()
    print(f"\nsession PCA, m = {m} (coverage 0.995), eigenproblem {shared.pca.message}")
    print(f"{'':<34}{'seconds':>10}{'peak MB':>10}")
    print(f"{'pooled implicit (ours)':<34}{ours:>10.3f}{ours_mb:>10.1f}")
    print(f"{'dense SVD of the pooled frames':<34}{dense:>10.3f}{dense_mb:>10.1f}")
    print(f"{'ratio dense / ours':<34}{dense / ours:>10.1f}{dense_mb / ours_mb:>10.1f}")
    print(f"agreement: eigenvalues to {rel:.2e} (relative), largest principal angle of the "
          f"{m}-subspaces {angle:.2e} deg, mean to "
          f"{np.abs(shared.pca.mean.ravel() - mean).max():.2e} cm")

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        own = [recon.process(p) for p in prepared]
        tic = time.perf_counter()
        common = [recon.process(p, session_basis=shared) for p in prepared]
        fit_seconds = (time.perf_counter() - tic) / len(prepared)
    first, second = (r.bases.pca for r in own[:2])
    print("\nwhy: the subspaces of the first k components of two takes' own PCAs are apart "
          "by (largest principal angle, deg):")
    for k in (1, 3, 5, 10):
        between = np.degrees(subspace_angles(first.components[:k].reshape(k, -1).T,
                                             second.components[:k].reshape(k, -1).T).max())
        print(f"  k = {k:>2}: {between:6.1f}")
    print(f"{'take':<8}{'m own':>7}{'α PCA own':>11}{'α PCA sess':>12}{'α QE own':>10}"
          f"{'α QE sess':>11}   PCA sha256 (session)")
    for p, a, b in zip(prepared, own, common):
        ea, eb = a.errors, b.errors
        print(f"{p.name:<8}{a.bases.n_components:>7}{ea['PCA'].summary()['alpha']:>11.3f}"
              f"{eb['PCA'].summary()['alpha']:>12.3f}{ea['QE'].summary()['alpha']:>10.3f}"
              f"{eb['QE'].summary()['alpha']:>11.3f}   {b.summary()['basis']['pca_sha256'][:16]}")
    one = {b.summary()["basis"]["pca_sha256"] for b in common}
    print(f"every take fitted in one basis: {len(one) == 1} ({len(one)} distinct PCA hash)")
    print(f"\ncost to a run: the stages before the basis take {np.mean(prep_seconds):.2f} s per "
          f"take, done once more for the session basis; basis + fit of a take "
          f"{fit_seconds:.2f} s (exports and report not included)")


if __name__ == "__main__":
    main()
