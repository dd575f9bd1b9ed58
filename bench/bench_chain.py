"""Benchmark: the whole chain on a 35,000-frame, 66-marker take onto the ICT face (issue 5, item 3).

The take is simulated (:func:`mocap.synth.capture.simulate_capture`: the ICT face
driven by ``alex_rom_4.csv``, sampled at 276 Hz so that its 127 s give 35,000
frames; 66 markers of ``tests/ict_marker_layout.toml``, 0.2 mm noise, head
motion, 60 gaps) and written to C3D. Timed per stage, as ``mocap2mesh run``
runs them (:mod:`fit.pipeline.stages`): read, ingest (gap fill, stabilization),
bind (with the layout's 2 mm skin offset), retarget (W, its variant chosen with the
mesh's lips read, as ``run`` reads them), bases (PCA of W·D without Ξ, quasi-eigen),
fit (H at the exact marker centres, QE, PCA in marker space), the lip-seal check
(the lip gap of W·D and of every basis's mesh in every frame), exports (CSV, compact
mesh npz, glb per basis) and the QA figures (no video). Peak memory: the process's
maximum resident set size, after the first run. The stages run twice, each run into new
files: the first run is the chain as it runs once (the total's aim); the second runs where
the process has touched its memory before, as the floors are timed (each the best of a few
runs on arrays the process made), so that its ratio to the floor compares like with like.
The first run's ratio is printed beside it: the gap between the two is the cost of memory
the process had not touched yet (page faults), not of the stage's own work. Before them,
the same take goes through ``mocap2mesh run`` in a fresh process, as a user runs it (2 mm
skin offset, no video; printed after them): its wall time (the issue's aim, 20 s) and the
stages its manifest records, which add to the ones above the report's held-out fits, mesh
renders and further figures, and the cost of a fresh process's first touches of its
memory. The process's
memory is set as the command sets it (:mod:`mocap.util.process_memory`), for the stages,
their floors and ``run`` alike.

Floors, timed in the same run on the same arrays: what each stage cannot go
under.

* read: the file's bytes mapped (``numpy.memmap``) and its points' coordinates
  widened into the new float64 array of the take's positions;
* ingest: one pass over the take, one 3 × 3 SVD a frame (the rigid fit of
  head stabilization) and, for every gap the PCA fill fills, the principal
  axes of its window (one GEMM of the window's rows of the target and its
  donors, and its eigh); not a tight floor: the fill's distance weights and
  the stabilization's robust weights read the take a few times more;
* bind: one pass over the face markers' positions, each coordinate's column
  read in full once (what selecting its middle sample, the median of the
  neutral frame's rest pose, costs at least: every sample compared once; the
  selection, :mod:`mocap.util.order_statistics`, reads them twice and
  partitions a tenth), and the AABB tree of the mesh that the closest-point
  queries of ICP search;
* retarget: the heat method's geodesic fields from the corners of the
  markers' faces (its three factorizations and three back-substitutions per
  corner, all corners at once: :func:`heat_method_floor`), one LU
  factorization of the (M + 4)² kernel system per variant that
  ``kernel = "auto"`` scores, and one kernel evaluation at the N vertices;
* bases: one GEMM of the centred marker displacements (T × 3M)ᵀ(T × 3M) and
  its eigendecomposition;
* fit: per basis, what checking its answer takes: every frame's reduced
  system at the answer's active set (its weights at a bound held there) solved
  once, by the solver's batched kernel, after the GEMM of its right-hand
  sides, and the reconstruction's GEMM; for H, its exact marker centres
  evaluated once at the answer. H's fit at the exact centres is timed again
  beside the bounded fit of its linear (tangent) model, and their ratio
  printed (the issue's aim: at most 2×), with the least that ratio can be for
  the chord steps the fit took: each step beyond the linear model's solve
  costs at least one product of the vertices the markers read (the centres)
  and one of the moved data's right-hand sides (:func:`chord_step_floor`);
* lip seal: the lips' vertices of every frame of each sequence (one product each)
  and one pass over them (each frame's centroid): the gap reads every vertex, but not
  every pair of an upper- and a lower-lip vertex (those it can rule out, it does not
  measure: :mod:`mocap.mesh._mouth_kernel`);
* exports (the cleaned take's C3D, and per basis its npz, weights CSV, mesh sequence and
  glb): the same number of bytes written by one ``ndarray.tofile``. The weights CSVs'
  text (the shortest that reads back exactly) is not bound by it: its floats' formatting
  by ``repr`` alone is printed beside it, which the CSV writer's whole-array formatting
  (:mod:`mocap.util.float_text`) runs under (``mocap2mesh run`` writes the CSVs on a
  thread of their own beside the binary exports, and takes the ones still waiting once
  those are written; without the compiled text, in a figure helper);
* QA figures + HTML: the figures' pixels encoded once more by the report's PNG
  encoder and the page's bytes written (:func:`_common.report_floor`).

Baseline, the naive chain, on the first ``--naive-frames`` frames: an RBF
(scipy ``RBFInterpolator``) rebuilt for every frame, a dense SVD of the
materialized Ξ for PCA, ``scipy.optimize.lsq_linear`` per frame for QE and
PCA, and for H at the exact marker centres ``scipy.optimize.least_squares``
per frame on the whole deformed mesh (the first ``--naive-frames // 40``
frames). Ratios are per frame.

Usage: ``python bench/bench_chain.py [--frames 35000] [--naive-frames 200]``.
"""

from __future__ import annotations

import argparse
import os
import resource
import time
import warnings
from functools import partial
from pathlib import Path

import igl
import numpy as np
import scipy.linalg
import scipy.sparse
from _common import (
    REPO,
    best_time,
    memory_as_the_command,
    report_floor,
    run_take,
    scratch_directory,
    shared_data,
    without_kept_geodesics,
)
from scipy.interpolate import RBFInterpolator
from scipy.optimize import least_squares, lsq_linear

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
from fit.pipeline.stages import lip_seal_stage
from fit.report import build_report
from fit.report.figure_queue import FigureQueue
from fit.report.forked_helpers import start_fork_server
from fit.solve._reduced import BoxQP, reduced_solve
from fit.solve.marker_basis import marker_basis
from fit.solve.marker_centres import solve_at_marker_centres
from fit.solve.weights import solve_weights
from mocap.clean._pca_fill import WINDOW_FRAMES, pca_donors
from mocap.clean.ingest import IngestOptions
from mocap.markerset import load_markerset
from mocap.mesh.landmarks import load_mesh_landmarks
from mocap.mesh.layout import load_marker_layout
from mocap.synth.capture import simulate_capture
from mocap.synth.performance import read_performance
from mocap.util.blas import TasksBeside
from mocap.util.float_text import compiled_lines_ready, csv_lines


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


def fit_h_exact_naively(bound, retargeted, basis, data) -> None:
    """H at the exact marker centres, frame by frame: ``least_squares`` on the whole mesh."""
    layout = bound.binding.centre_layout(retargeted.mesh, retargeted.labels)
    V0, E = retargeted.mesh.vertices, basis.displacements
    rest = layout.positions(V0)
    for d in data:
        least_squares(lambda w, d=d: (layout.positions(V0 + np.tensordot(w, E, axes=1))
                                      - rest - d).ravel(),
                      np.zeros(len(E)), bounds=(basis.lower, basis.upper))


def _peak_rss_gb(pid: int) -> float:
    """Peak resident memory (GB) of the running process `pid` (Linux; 0 elsewhere)."""
    try:
        with open(f"/proc/{pid}/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1e6     # kB, as ru_maxrss
    except OSError:
        pass
    return 0.0


def pca_fill_windows(fill) -> list:
    """The matrix whose principal axes the PCA fill needs, of every gap it filled: the
    window's frames (``WINDOW_FRAMES`` either side) where the target and every marker
    visible throughout the gap are visible, (frames, 3 (1 + donors)) each."""
    if fill is None:
        return []
    positions, missing = fill.take.positions, fill.take.filled != 0
    visible = ~np.isnan(positions[..., 0]) & ~missing
    labels = list(fill.take.labels)
    windows = []
    for gap in fill.gaps[fill.gaps["method"] == "pca"].itertuples():
        target = labels.index(gap.marker)
        cols = np.r_[target, pca_donors(visible, target, gap.start, gap.stop)]
        rows = slice(max(0, gap.start - WINDOW_FRAMES), gap.stop + WINDOW_FRAMES)
        complete = visible[rows][:, cols].all(axis=1)
        windows.append(positions[rows][complete][:, cols].reshape(int(complete.sum()), -1))
    return windows


def heat_method_floor(vertices, faces, sources) -> float:
    """Seconds of the heat method's own work for geodesic fields from `sources` (S,), as
    libigl discretizes it: its three factorizations (the heat step with Neumann and with
    Dirichlet boundary values, the Poisson step) and three solves for every source, all
    sources at once (one multi-column back-substitution per factor)."""
    faces = np.asarray(faces, dtype=np.int64)
    boundary = np.unique(igl.boundary_facets(faces)[0])
    unit = np.zeros((len(vertices), len(sources)))
    unit[sources, np.arange(len(sources))] = 1.0
    none = np.zeros(0, np.int64)

    def run():
        L = igl.cotmatrix(vertices, faces)
        M = igl.massmatrix(vertices, faces, igl.MASSMATRIX_TYPE_VORONOI)
        edges = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
        t = np.mean(np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)) ** 2
        heat = (M - t * L).tocsc()
        mean = scipy.sparse.csc_matrix(M.diagonal()[None, :])
        for A, known, Aeq in ((heat, none, scipy.sparse.csc_matrix((0, len(vertices)))),
                              (heat, boundary, scipy.sparse.csc_matrix((0, len(vertices)))),
                              ((-0.5 * L).tocsc(), none, mean)):
            data = igl.min_quad_with_fixed_data()
            igl.min_quad_with_fixed_precompute(A, known, Aeq, True, data)
            igl.min_quad_with_fixed_solve(data, unit, np.zeros((len(known), len(sources))),
                                          np.zeros((Aeq.shape[0], len(sources))))
    return best_time(run)


def read_floor(path: Path) -> tuple[float, str]:
    """The read stage's floor: the file memory-mapped (no copy of its bytes) and its
    points' coordinates (float32 words, as the simulation writes them) widened into a new
    (T, M, 3) float64 array, the positions any reader gives a take; the layout from the
    C3D header's own fields."""
    header = np.fromfile(path, np.uint8, count=512)
    n_points, analog_words = (int(v) for v in header[2:6].view("<u2"))
    if header[12:16].view("<f4")[0] >= 0:
        raise SystemExit(f"{path}: the read floor expects float storage (a negative scale)")
    offset = 512 * (int(header[16:18].view("<u2")[0]) - 1)
    frame_words = 4 * n_points + analog_words

    def read_and_widen():
        n_frames = (path.stat().st_size - offset) // (4 * frame_words)
        words = np.memmap(path, "<f4", mode="r", offset=offset, shape=(n_frames, frame_words))
        positions = np.empty((n_frames, n_points, 3))
        positions[...] = words[:, :4 * n_points].reshape(n_frames, n_points, 4)[:, :, :3]
        return positions
    return best_time(read_and_widen), (f"the file's {path.stat().st_size / 1e6:.0f} MB mapped, "
                                       f"its coordinates widened to float64")


def measure_floors(path: Path, out: Path, take, bound, retargeted, bases, fill,
                   weights) -> dict:
    """Each stage's floor (see the module docstring) for the take read from `path` and the
    chain's outputs in `out`: stage name to (seconds, what it is)."""
    floors = {}
    floors["read"] = read_floor(path)
    rotations = np.broadcast_to(np.eye(3), (take.n_frames, 3, 3))
    windows = pca_fill_windows(fill)
    floors["ingest"] = (
        best_time(lambda: (take.positions.copy(), np.linalg.svd(rotations),
                           [np.linalg.eigh(z.T @ z) for z in windows])),
        f"one pass over the take, a 3x3 SVD a frame, a GEMM and eigh per PCA-filled gap "
        f"({len(windows)}) (not tight)")
    face = take.select(retargeted.labels).positions
    tree = igl.AABB()
    floors["bind"] = (
        best_time(lambda: np.count_nonzero(face.reshape(take.n_frames, -1).T.copy() < 0.0,
                                           axis=1))
        + best_time(lambda: tree.init(retargeted.mesh.vertices, retargeted.mesh.faces)),
        "one pass over the face markers, each coordinate's samples compared once (the least "
        "a selection of the rest pose's median reads), the mesh's AABB tree")
    M = len(retargeted.labels)
    selection = retargeted.selection
    n_variants = len(selection.candidates) if selection else 1
    rng = np.random.default_rng(0)
    system = rng.standard_normal((M + 4, M + 4)) + (M + 4) * np.eye(M + 4)
    vertices, centres = retargeted.mesh.vertices, rng.standard_normal((M, 3))
    binding = bound.binding
    corners = np.unique(binding.vertex_ids[[binding.labels.index(x) for x in
                                            retargeted.labels]])
    floors["retarget (W)"] = (
        heat_method_floor(retargeted.mesh.vertices, retargeted.mesh.faces, corners)
        + best_time(lambda: [scipy.linalg.lu_factor(system) for _ in range(n_variants)])
        + best_time(lambda: np.sqrt(((vertices[:, None] - centres) ** 2).sum(axis=2))),
        f"the heat method's 3 factorizations and 3 solves for each of the {len(corners)} "
        f"corners of the markers' faces, {n_variants} factorizations of the {M + 4}² system, "
        "one kernel at the vertices")
    D = retargeted.displacements.reshape(take.n_frames, -1)

    def pca_floor():
        centred = D - D.mean(axis=0)
        np.linalg.eigh(centred.T @ centred)
    floors["bases (PCA, QE)"] = (best_time(pca_floor), f"one GEMM ({D.shape[1]}² of "
                                 f"{take.n_frames} frames) and its eigh")

    problems = []
    for name, b in bases.bases.items():
        at = marker_basis(binding, b.displacements, retargeted.labels,
                          mesh=retargeted.mesh if b.on_skin else None)
        free = at[b.n_fixed:].reshape(len(at) - b.n_fixed, -1).T           # (3M, n)
        w = weights[name][:, b.n_fixed:]
        lo, hi = (np.broadcast_to(np.asarray(x, float), (len(at),))[b.n_fixed:]
                  for x in (b.lower, b.upper))
        qp = BoxQP.build(free.T @ free, lo, hi)
        # the active set of the answer: the weights at a bound; without bounds, the
        # system is BᵀB's for every frame: one product with its (pseudo-)inverse
        state = np.subtract(w >= hi, w <= lo, dtype=np.int8)
        unbounded = None if np.isfinite(np.r_[lo, hi]).any() else \
            np.linalg.pinv(qp.G, hermitian=True)
        problems.append((free, qp, state, unbounded, at, weights[name]))

    def final_solves():
        for free, qp, state, unbounded, at, full in problems:
            if unbounded is None:
                reduced_solve(qp, state, D @ free, gradient=False)
            else:
                (D @ free) @ unbounded
            np.tensordot(full, at, axes=1)                                  # reconstruction
        layout.positions_under_weights(retargeted.mesh.vertices, H.displacements,
                                       weights["H"])
    H = bases.bases["H"]
    tangent = marker_basis(binding, H.displacements, retargeted.labels, mesh=retargeted.mesh)
    layout = binding.centre_layout(retargeted.mesh, retargeted.labels)
    exact = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        linear_h = best_time(lambda: solve_weights(tangent, retargeted.displacements,
                                                    lower=H.lower, upper=H.upper), repeat=1)
        exact_h = best_time(lambda: exact.append(solve_at_marker_centres(
            layout, retargeted.mesh.vertices, H.displacements, tangent,
            retargeted.displacements, lower=H.lower, upper=H.upper)), repeat=1)
    steps, step_floor = chord_step_floor(exact[-1], problems[list(bases.bases).index("H")][0],
                                         layout, retargeted.mesh.vertices, H.displacements, D)
    floors["fit (H, QE, PCA)"] = (best_time(final_solves),
                                  f"per basis, each frame's system at the answer's active set "
                                  f"and the reconstruction; for H, its exact centres once (H "
                                  f"at the exact centres {exact_h:.2f} s = "
                                  f"{exact_h / linear_h:.1f}× its bounded linear model's "
                                  f"{linear_h:.2f} s; aim ≤ 2×. Its {steps:.2f} chord steps a "
                                  f"frame beyond the linear model's solve, each at its floor "
                                  f"({step_floor:.2f} s: the products of the centres and of "
                                  f"the right-hand sides), put the exact fit at ≥ "
                                  f"{1 + steps * step_floor / linear_h:.1f}× the linear model)")
    floors["lip seal"] = lip_seal_floor(retargeted, bases, weights)
    exported = [f for f in out.iterdir() if f.suffix in {".c3d", ".csv", ".npz", ".glb"}]
    size = sum(f.stat().st_size for f in exported)
    blob = np.zeros(size, np.uint8)
    target = out / "floor.bin"

    def write_bytes():
        blob.tofile(target)
        os.unlink(target)
    cells = [np.column_stack([np.arange(take.n_frames) / take.rate, w]).ravel().tolist()
             for w in weights.values()]
    n_cells = sum(len(c) for c in cells)
    by_repr = best_time(lambda: [",".join(map(repr, c)) for c in cells], repeat=1)
    tables = [np.column_stack([np.arange(take.n_frames) / take.rate, w]) for w in weights.values()]
    ours = best_time(lambda: [b"".join(csv_lines(np.arange(len(t)), t)) for t in tables],
                     repeat=1)
    text = "compiled" if compiled_lines_ready() else "NumPy"
    floors["exports"] = (best_time(write_bytes),
                         f"tofile of the same {size / 1e6:.0f} MB; the CSVs' text is not bound by "
                         f"it (their {n_cells / 1e6:.1f}M floats by repr alone: {by_repr:.2f} s, "
                         f"by our {text} text: {ours:.2f} s)")
    report = out / "report"
    floors["QA figures + HTML"] = (
        min(report_floor(report.rglob("*"), out / "floor")[0] for _ in range(3)),
        f"{len(list(report.rglob('*.png')))} PNGs encoded, the page written")
    return floors


def chord_step_floor(fit, free, layout, vertices, displacements, D) -> tuple[float, float]:
    """The chord steps the exact-centre fit `fit` took per frame beyond its first (the
    linear model's) solve, and one step's floor, s: the two products every step makes of
    all frames, the vertices the markers read under the weights (the neutral's among them:
    the centres' whole cost but placing the markers on them) and the moved data's
    right-hand sides ``D @ free`` (the solve after them, by a factor of the last step's
    where the active set holds, left out: a lower bound)."""
    operator = layout.under_weights(vertices, displacements).operator         # (3K, n + 1)
    weights = np.vstack([fit.solution.weights.T, np.ones(len(D))])           # (n + 1, T)
    return float(np.mean(fit.n_steps - 1)), best_time(lambda: (operator @ weights, D @ free))


def lip_seal_floor(retargeted, bases, weights) -> tuple[float, str]:
    """The lip-seal stage's floor (see the module docstring) and what it is."""
    mouth, lips = retargeted.mouth, retargeted.mouth.vertex_ids
    rows = retargeted.operator.matrix[lips]
    rows = rows.toarray() if scipy.sparse.issparse(rows) else np.asarray(rows)
    shapes = [b.displacements[:, lips].reshape(len(b.displacements), -1)
              for b in bases.bases.values()]
    n_sequences = 1 + len(shapes)
    average = np.full(len(lips), 1.0 / len(lips))

    def vertices():
        return [np.matmul(rows, retargeted.displacements),
                *(w @ e for w, e in zip(weights.values(), shapes))]
    made = vertices()
    seconds = best_time(vertices) + best_time(
        lambda: [np.matmul(average, m.reshape(len(m), len(lips), -1)) for m in made])
    return seconds, (f"the lips' {len(lips)} vertices of the {n_sequences} sequences (one "
                     f"product each) and one pass over them (not their "
                     f"{len(mouth.upper) * len(mouth.lower):,} pairs a frame)")


def run_as_a_user(out: Path, capture: Path, frames: int) -> str:
    """``mocap2mesh run`` on `capture` in a fresh process, as a user runs the take: a line of
    its wall time and the stages the manifest records (which take the held-out fits, the
    renders and the other figures the chain leaves out)."""
    ict = shared_data() / "ict-face"
    wall, take = run_take(out, capture, mesh=ict / "generic_neutral_mesh.obj",
                          basis=ict / "expressions",
                          landmarks=REPO / "tests" / "ict_landmarks.toml", max_gap=frames)
    stages = ", ".join(f"{k} {v:.2f}" for k, v in take["stage_seconds"].items())
    return (f"\nmocap2mesh run on the same take, a fresh process as a user runs it (2 mm skin "
            f"offset, no video): {wall:.1f} s (aim ≤ 20 s); in the take "
            f"{take['seconds']:.1f} s ({stages}); start, imports, inputs and the record "
            f"{wall - take['seconds']:.1f} s")


def run_chain(source: Path, out: Path, artist, markerset, landmarks, max_gap: int):
    """The chain's stages on the take `source` / "take.c3d", as ``mocap2mesh run`` runs them,
    writing into `out`; return the seconds of each stage and what they made."""
    out.mkdir()
    without_kept_geodesics()            # one take, as `run` of one take solves its fields
    mesh = artist.neutral
    times = {}

    def timed(name, fn):
        tic = time.perf_counter()
        result = fn()
        times[name] = time.perf_counter() - tic
        return result

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        raw = timed("read", lambda: mocap.read(source / "take.c3d"))
        ingested = timed("ingest", lambda: ingest_stage(
            raw, markerset, IngestOptions(fill="auto", max_gap=max_gap)))  # every gap
        take = complete_span(ingested.take, markerset.face_markers)
        bound = timed("bind", lambda: bind_stage(take, markerset, mesh, landmarks,
                                                 options=BindOptions(skin_offset=2.0)))
        retargeted = timed("retarget (W)", lambda: retarget_stage(take, bound, mesh, markerset,
                                                                  mesh_landmarks=landmarks))
        bases = timed("bases (PCA, QE)", lambda: basis_stage(retargeted, artist))
        fitted = timed("fit (H, QE, PCA)", lambda: fit_stage(take, bound, retargeted, bases))
        timed("lip seal", lambda: lip_seal_stage(take, bound, retargeted, bases, fitted))

        def exports():
            # as `mocap2mesh run` does: the CSVs (text) queued first, for the figure helpers,
            # or, where the fit loaded the compiled CSV text, written on a thread here
            # meanwhile, this one taking those it has not started once its own are written
            here = compiled_lines_ready()
            csvs = [(out / f"weights-{name}.csv", fitted.weights[name], b.names)
                    for name, b in bases.bases.items()]
            for task in csvs if not here else ():
                figures.submit(write_weights_csv, *task, rate=take.rate)
            texts = TasksBeside(partial(write_weights_csv, *task, rate=take.rate)
                                for task in csvs) if here else None
            mocap.write(take, out / "take.c3d")
            for name, b in bases.bases.items():
                w = fitted.weights[name]
                save_basis(ArtistBasis(b.names, mesh, b.displacements), out / f"basis-{name}.npz",
                           dtype="float32")
                write_mesh_sequence(out / f"mesh-{name}.npz", mesh, b.displacements, w,
                                    names=b.names, rate=take.rate)
                write_gltf(out / f"face-{name}.glb", mesh, b.displacements, b.names, weights=w,
                           rate=take.rate)
            if texts is not None:
                texts.finish()
            figures.run()
        # as `mocap2mesh run` does: the figure helpers start with the exports, write the
        # weights CSVs, then draw the figures
        with FigureQueue() as figures:
            timed("exports", exports)
            face = take.select(retargeted.labels)
            (out / "report").mkdir()
            timed("QA figures + HTML", lambda: build_report(
                face, fitted.reconstructed, face.positions[bound.frame], out / "report",
                markerset=markerset, pca=bases.pca, ingest=ingested, video=False,
                figures=figures))
            helpers = [_peak_rss_gb(pid) for pid in figures.pids]
    return times, take, ingested, bound, retargeted, bases, fitted, helpers


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=35_000)
    parser.add_argument("--naive-frames", type=int, default=200)
    args = parser.parse_args()
    memory = memory_as_the_command()
    # as the command does: the figure helpers' server forked before any thread starts
    start_fork_server()
    out = scratch_directory("bench_chain_")
    artist, markerset, sim_take = simulate(args.frames, out / "take.c3d")
    mesh = artist.neutral
    landmarks = load_mesh_landmarks(REPO / "tests" / "ict_landmarks.toml", mesh)
    print(f"take: {sim_take.n_frames} frames, {sim_take.n_markers} markers "
          f"({len(markerset.face_markers)} face), {int(sim_take.missing.sum())} missing "
          f"samples; ICT face {mesh.n_vertices} vertices, {artist.n_shapes} shapes; "
          f"{memory}")
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    # before the chain runs here: with the memory this process keeps after them (2.3 GB),
    # the fresh process took 11.2-11.6 s (its ingest and retargeting half as long again)
    # against 9.1 s before them, and 9.2-9.3 s from a shell
    as_a_user = run_as_a_user(out, out / "take.c3d", sim_take.n_frames)
    times, take, ingested, bound, retargeted, bases, fitted, helpers = run_chain(
        out, out / "first", artist, markerset, landmarks, sim_take.n_frames)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    again = run_chain(out, out / "again", artist, markerset, landmarks, sim_take.n_frames)[0]
    floors = measure_floors(out / "take.c3d", out / "first", take, bound, retargeted, bases,
                            ingested.fill, fitted.weights)
    total = sum(times.values())
    floor_total = sum(f for f, _ in floors.values())
    T = take.n_frames
    print(f"\n{'stage':<20} {'first s':>8} {'again s':>8} {'floor s':>8} {'ratio':>7}"
          f"{'first':>7}   floor")
    for name, sec in times.items():
        floor, what = floors[name]
        print(f"{name:<20} {sec:>8.2f} {again[name]:>8.2f} {floor:>8.3f} "
              f"{again[name] / floor:>6.1f}× {sec / floor:>5.1f}×   {what}")
    print(f"{'total':<20} {total:>8.2f} {sum(again.values()):>8.2f} {floor_total:>8.3f} "
          f"{sum(again.values()) / floor_total:>6.1f}× {total / floor_total:>5.1f}×   "
          f"(aim ≤ 20 s, the first run)")
    print("ratio: the stage run again in the same process, as its floor is timed (memory the "
          "process touched before); first: its first run")
    print(f"peak RSS {peak:.2f} GB (after the simulation: {rss0:.2f} GB; aim ≤ 1.5 GB); "
          f"{len(helpers)} figure helper(s), peak RSS {max(helpers, default=0):.2f} GB; "
          f"PCA m = {bases.n_components}")
    print(as_a_user)


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
    fit_naive = 0.0
    for name, b in bases.bases.items():
        at = binding.marker_points(b.displacements)[:, rows]
        B = at[b.n_fixed:].reshape(len(at) - b.n_fixed, -1).T
        data = (D - at[:b.n_fixed].sum(axis=0)).reshape(n, -1)
        tic = time.perf_counter()
        if name == "H":
            n_h = max(2, n // 40)
            fit_h_exact_naively(bound, retargeted, b, D[:n_h])
            h_exact_naive = (time.perf_counter() - tic) * n / n_h
            fit_naive += h_exact_naive
            tangent = marker_basis(binding, b.displacements, retargeted.labels, mesh=mesh)
            tic = time.perf_counter()
            for d in D.reshape(n, -1):
                lsq_linear(tangent.reshape(len(tangent), -1).T, d, bounds=(b.lower, b.upper),
                           method="bvls")
            h_linear_naive = time.perf_counter() - tic
            continue
        for d in data:
            lsq_linear(B, d, method="bvls")
        fit_naive += time.perf_counter() - tic
    naive["fit (H, QE, PCA)"] = fit_naive
    print(f"\nnaive chain on {n} frames vs ours on {T} (per frame):")
    print(f"{'stage':<20} {'naive ms/frame':>14} {'ours ms/frame':>13} {'ratio':>8}")
    for name, sec in naive.items():
        ours = 1e3 * times[name] / T
        print(f"{name:<20} {1e3 * sec / n:>14.3f} {ours:>13.4f} {1e3 * sec / n / ours:>7.0f}×")
    linear_naive = fit_naive - h_exact_naive + h_linear_naive
    print(f"{'':<20} (with H by lsq_linear on its linear model instead of least_squares at "
          f"the exact centres: {1e3 * linear_naive / n:.3f} ms/frame, "
          f"{linear_naive / n / (times['fit (H, QE, PCA)'] / T):.0f}×)")
    naive_total = sum(naive.values()) / n
    ours_total = sum(times[k] for k in naive) / T
    print(f"{'retarget+bases+fit':<20} {1e3 * naive_total:>14.3f} {1e3 * ours_total:>13.4f} "
          f"{naive_total / ours_total:>7.0f}×")
    others = sum(sec for name, sec in times.items() if name not in naive)
    print(f"whole chain, the other stages counted as ours in both: naive "
          f"{naive_total * T + others:.0f} s, ours {total:.1f} s, "
          f"{(naive_total * T + others) / total:.0f}× (aim ≥ 100×)")
    print(f"naive chain extrapolated to {T} frames: {naive_total * T / 60:.0f} min "
          f"(the SVD grows faster than linearly)")


if __name__ == "__main__":
    main()
