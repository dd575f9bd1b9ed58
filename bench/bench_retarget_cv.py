"""Benchmark (issue 13, items 1 and 2): retargeting validated without ground truth, and the lips.

Four parts, each printing its figures:

* ``speed``: the closed-form leave-one-marker-out residuals against refitting the
  operator without each marker (the naive baseline, one operator per marker), on
  the ICT face (9,409 vertices, 60 markers), side by side; and the cost of
  ``kernel = "auto"`` (88 variants) in :func:`mocap.retarget.retargeting.retarget`.
* ``auto``: :func:`mocap.retarget.selection.select_variant` (88 variants, lips read) on
  the same geometry, its variants of one kernel solved together as stacks
  (:func:`mocap.retarget.cross_validation.leave_one_out_many`) against each solved alone
  (``leave_one_out`` one variant at a time: ``helpers.one_variant_at_a_time``; the lips are
  read a kernel's variants at once in both), side by side, with the process's memory as the
  system has it and then as the command sets it. A 20 s take: the cost is per variant (the
  displacements enter through their (M, M) Gram matrix and 32 lip frames), not per frame.
* ``sim``: the ICT face driven by the ARKit performance ``alex_rom_3.csv`` (100 s at
  30 Hz, 0.2 mm noise, head motion), seen by the markers of
  ``tests/ict_marker_layout.toml`` moved off the lips as on the real take of the
  issue (:func:`helpers.off_lip_layout`: lip markers 10-18 mm from the lip line, the
  corner markers 10 mm out, three markers per lip), through the whole chain
  (:class:`fit.pipeline.Reconstruction`: ingest, bind, retarget, bases, fit) with the
  former default (TPS, Euclidean) and with ``auto``: the lip-seal warnings, the mesh
  lip gap against the truth's at the widest frames; for every variant ``auto`` tried,
  its cross-validated marker error against its ground-truth vertex error (Spearman's
  rank correlation), and beside them the floor: the best linear map from these
  markers' displacements to the true vertex displacements (least squares over the
  truth, fitted on alternate 1 s blocks, scored on the others). ``--layout ict`` runs
  the same on the layout as it is (markers on the lips).
* ``sing``: facial-sing.c3d (real, no truth) on the ICT face, TPS and ``auto``: the
  lip-seal warnings and each mesh's widest opening against the lip markers'.

Run: ``python bench/bench_retarget_cv.py [--parts speed auto sim sing] [--layout off-lips|ict]``.
Pictures in ``bench/out/``: ``retarget_cv_lips_<case>.png`` (lip seal), ``retarget_cv_
markers_<case>.png`` (held-out error per marker), ``retarget_cv_vs_truth_<layout>.png``.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path
from unittest.mock import patch

import numpy as np
import scipy.sparse as sp
from matplotlib.ticker import ScalarFormatter
from scipy.spatial import cKDTree
from scipy.stats import spearmanr

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import REPO, best_time, memory_as_the_command, shared_data  # noqa: E402

sys.path.insert(0, str(REPO / "tests"))
from helpers import (  # noqa: E402
    ICT_LANDMARKS_TOML,
    ICT_LAYOUT_TOML,
    ICT_MARKERSET_TOML,
    jaw_open_peak_time,
    layout_binding,
    lip_regions,
    off_lip_layout,
    one_variant_at_a_time,
)

import mocap  # noqa: E402
from basis.artist import load_artist_basis  # noqa: E402
from fit.pipeline import Reconstruction  # noqa: E402
from fit.report.retarget_qa import plot_cross_validation, plot_lip_seal  # noqa: E402
from mocap.markerset import load_markerset  # noqa: E402
from mocap.mesh.landmarks import load_mesh_landmarks  # noqa: E402
from mocap.mesh.layout import load_marker_layout  # noqa: E402
from mocap.mesh.mouth import find_mouth  # noqa: E402
from mocap.retarget import selection  # noqa: E402
from mocap.retarget.cross_validation import MarkerGeometry, leave_one_out  # noqa: E402
from mocap.retarget.lip_seal import lip_witness  # noqa: E402
from mocap.retarget.rbf import build_rbf_operator  # noqa: E402
from mocap.retarget.retargeting import marker_displacements  # noqa: E402
from mocap.synth.capture import simulate_capture  # noqa: E402
from mocap.synth.performance import read_performance  # noqa: E402
from mocap.take import Take  # noqa: E402
from mocap.viz.figures import new_figure, save_figure  # noqa: E402

OUT = REPO / "bench" / "out"
RATE = 30.0
#: Vertices scored against the truth: within this distance of a bound marker point, mm.
FACE_MM = 20.0
#: "The widest frames": this many frames of the largest true lip gap.
WIDEST = 10
#: Frames between the vertex-error samples of the 88 variants.
TRUTH_STEP = 3


def _dense(matrix):
    return matrix.toarray() if sp.issparse(matrix) else np.asarray(matrix)


def _load_ict():
    ict = shared_data() / "ict-face"
    basis = load_artist_basis(ict / "generic_neutral_mesh.obj", ict / "expressions", units="cm")
    landmarks = load_mesh_landmarks(ICT_LANDMARKS_TOML, basis.neutral)
    return basis, landmarks


def _reconstruct(take, markerset, basis, landmarks, kernel):
    recon = Reconstruction(markerset=markerset, mesh=basis.neutral, landmarks=landmarks,
                           basis=basis, bind={"skin_offset": 2.0},
                           retarget={"kernel": kernel})
    tic = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = recon.process(take)
    lips = [str(w.message) for w in caught if "lip seal" in str(w.message)]
    return result, lips, time.perf_counter() - tic


# ---------------------------------------------------------------- speed

def part_speed(basis, landmarks) -> None:
    mesh = basis.neutral
    layout = load_marker_layout(ICT_LAYOUT_TOML, mesh)
    markerset = load_markerset(ICT_MARKERSET_TOML)
    labels = markerset.face_markers
    idx = [layout.index(x) for x in labels]
    corners = layout.vertex_ids[idx]
    geometry = MarkerGeometry(layout.positions(mesh.vertices, offset=False)[idx], corners,
                              layout.weights[idx], layout.face_ids[idx], mesh.vertices,
                              mesh.faces, tuple(labels))
    m = len(labels)
    print(f"speed: ICT face {mesh.n_vertices} vertices, {m} markers; closed form vs refitting "
          "without each marker (measured under load)")
    between, _, fields = geometry.distances("geodesic")
    for name, options, pre in (("tps euclidean", dict(kernel="thin_plate_spline"), None),
                               ("gaussian geodesic", dict(kernel="gaussian", epsilon=0.4,
                                                          distance="geodesic"),
                                (fields, between))):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            shift = leave_one_out(geometry, **options).shifts["all"]   # held fixed in both

        def naive():
            rows = np.zeros((m, m))
            for k in range(m):
                keep = np.delete(np.arange(m), k)
                extra = {} if pre is None else {
                    "precomputed": (pre[0][keep], pre[1][np.ix_(keep, keep)])}
                op = build_rbf_operator(geometry.centers[keep], mesh.vertices, **extra,
                                        smoothing=shift, **options)
                rows[k, keep] = geometry.bary[k] @ _dense(op.matrix)[corners[k]]
            return rows

        def closed():
            return leave_one_out(geometry, **options).matrix

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t_naive = best_time(naive, repeat=1)
            t_closed = best_time(closed, repeat=3)
            diff = np.abs(naive() - closed()).max()
        print(f"  {name:<18} refit per marker {t_naive:7.2f} s   closed form {t_closed:6.3f} s"
              f"   ratio {t_naive / t_closed:6.0f}x   max difference {diff:.1e}"
              + (f" (diagonal shift {shift:.2g} kept)" if shift else ""))


# ---------------------------------------------------------------- auto

def part_auto(basis, landmarks) -> None:
    mesh = basis.neutral
    layout = load_marker_layout(ICT_LAYOUT_TOML, mesh)
    markerset = load_markerset(ICT_MARKERSET_TOML)
    performance = read_performance(shared_data() / "arkit-performances" / "alex_rom_3.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                  # TongueOut: no ICT shape
        sim = simulate_capture(basis, performance, layout, markerset.head, rate=RATE,
                               start=max(0.0, jaw_open_peak_time(performance) - 10.0),
                               duration=20.0, noise_mm=0.2, seed=0)
    truth = sim.truth                                    # in the head frame: no alignment
    head = np.einsum("tji,tmj->tmi", truth.rotation,
                     sim.take.positions - truth.translation[:, None])
    labels = markerset.face_markers
    face = Take(sim.take.labels, head, rate=RATE).select(labels)
    binding = layout_binding(layout, labels)
    neutral = int(np.argmin(np.abs(truth.weights).sum(axis=1)))
    d = marker_displacements(face, binding, neutral_frame=neutral)
    geometry = MarkerGeometry.from_binding(binding, mesh, labels)
    regions = lip_regions(markerset, labels)
    mouth, witness = find_mouth(mesh, landmarks), lip_witness(markerset, labels)

    def select():
        return selection.select_variant(geometry, d, regions=regions, mm_per_unit=10.0,
                                        mouth=mouth, witness=witness)

    def alone():
        with patch.object(selection, "leave_one_out_many", one_variant_at_a_time):
            return select()

    together, each = select(), alone()                   # the geodesic distances cached
    same = (together.chosen == each.chosen and all(
        np.isclose(a.score_mm, b.score_mm, rtol=1e-10, equal_nan=True) and a.note == b.note
        for a, b in zip(together.candidates, each.candidates)))
    print(f"\nauto: select_variant on the ICT face ({geometry.n_markers} markers, "
          f"{len(together.candidates)} variants, lips read: {together.lips_checked}), a "
          f"{len(d)}-frame take (the cost is per variant, not per frame); the same scores "
          f"and choice: {same}")
    for memory in ("memory as the system has it", memory_as_the_command()):
        t_each = best_time(alone, repeat=5)
        t_together = best_time(select, repeat=5)
        print(f"  {memory}: one variant at a time {t_each * 1e3:6.1f} ms, a kernel's "
              f"variants together {t_together * 1e3:6.1f} ms, ratio {t_each / t_together:.2f}x "
              f"({1 - t_together / t_each:.0%} off)")


# ---------------------------------------------------------------- the simulation

def _take_weights(result, truth, first_frame):
    """The true weights of the frames of the reconstructed take (its ends may be trimmed)."""
    start = result.take.first_frame - first_frame
    return truth.weights[start:start + result.take.n_frames]


def _truth_lips(result, basis, truth, first_frame):
    mouth = result.retargeted.mouth
    ids = mouth.vertex_ids
    weights = _take_weights(result, truth, first_frame)
    lips = basis.neutral.vertices[ids] + np.einsum("tn,nvc->tvc", weights,
                                                   basis.displacements[:, ids])
    return 10.0 * mouth.gap(lips)


def _variant_truth_errors(result, basis, truth, first_frame, vertices, regions):
    """RMS vertex error (mm) of every scored variant of the selection, every TRUTH_STEP frames."""
    geometry = MarkerGeometry.from_binding(result.binding, basis.neutral, result.retargeted.labels)
    between, _, fields = geometry.distances("geodesic")
    frames = np.arange(0, result.take.n_frames, TRUTH_STEP)
    d = result.retargeted.displacements[frames]
    true = _true_displacements(result, basis, truth, first_frame, vertices)[frames]
    errors = {}
    for i, c in enumerate(result.retargeted.selection.candidates):
        if not np.isfinite(c.score_mm):
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            op = build_rbf_operator(
                geometry.centers, geometry.vertices[vertices], kernel=c.kernel,
                epsilon=c.epsilon, distance=c.distance, labels=geometry.labels,
                precomputed=(fields[:, vertices], between) if c.distance == "geodesic" else None,
                regions=regions if c.use_regions else None)
        errors[i] = _rms_mm(np.matmul(_dense(op.matrix), d), true)
    return errors


def _true_displacements(result, basis, truth, first_frame, vertices):
    """True vertex displacements (T, V, 3), cm, from the take's rest pose (the bound frame)."""
    weights = _take_weights(result, truth, first_frame)
    frame, window = result.bound.frame, result.bound.window
    lo = max(0, frame - window // 2)
    rest = weights[lo:lo + window].mean(axis=0)
    shapes = basis.displacements[:, vertices].reshape(len(basis.names), -1)
    return ((weights - rest) @ shapes).reshape(len(weights), len(vertices), 3)


def _rms_mm(a, b) -> float:
    return 10.0 * float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=-1))))


def _floor(result, basis, truth, first_frame, vertices):
    """The best linear maps from the markers' displacements to the true vertex displacements.

    Fitted by least squares on alternate 1 s blocks, scored (RMS mm) on the others:
    ``shared`` (one weight per vertex and marker, the same for x, y and z: the class
    of every RBF operator) and ``general`` (any linear map of all 3M coordinates).
    Returns both, the test frames (mask) and the shared map's weights (V, M).
    """
    d = result.retargeted.displacements
    y = _true_displacements(result, basis, truth, first_frame, vertices)
    train = (np.arange(len(d)) // int(RATE)) % 2 == 0
    test = ~train
    m = d.shape[1]
    a = d[train].transpose(0, 2, 1).reshape(-1, m)
    b = y[train].transpose(0, 2, 1).reshape(-1, len(vertices))
    w = np.linalg.lstsq(a, b, rcond=None)[0]                                   # (M, V)
    shared = _rms_mm(np.matmul(w.T, d[test]), y[test])
    g = np.linalg.lstsq(d[train].reshape(train.sum(), -1), y[train].reshape(train.sum(), -1),
                        rcond=None)[0]
    general = _rms_mm((d[test].reshape(test.sum(), -1) @ g).reshape(y[test].shape), y[test])
    return shared, general, test, w.T


def _plot_scores(scores, errors, chosen, best, floor, path, title) -> None:
    fig = new_figure(7.5, 5.5)
    ax = fig.add_subplot()
    ax.axhline(floor, color="grey", ls="--", lw=1.0,
               label=f"floor: best linear map from these markers ({floor:.2f} mm)")
    ax.scatter(scores, errors, s=14, color="tab:blue", alpha=0.7, label="a variant")
    ax.scatter([scores[chosen]], [errors[chosen]], s=90, facecolor="none",
               edgecolor="tab:red", lw=1.8, label="chosen by auto")
    ax.scatter([scores[best]], [errors[best]], marker="x", s=70, color="black",
               label="best against the truth")
    ax.set_xscale("log")
    ax.set_yscale("log")
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_formatter(ScalarFormatter())
        axis.set_minor_formatter(ScalarFormatter())
    ax.tick_params(which="both", labelsize=8)
    ax.set_xlabel("cross-validated marker error (mm, RMS)")
    ax.set_ylabel("vertex error against the truth (mm, RMS)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    ax.set_title(title, fontsize=10)
    save_figure(fig, path)


def part_sim(basis, landmarks, layout_name: str, seconds: float) -> None:
    mesh = basis.neutral
    layout = load_marker_layout(ICT_LAYOUT_TOML, mesh)
    markerset = load_markerset(ICT_MARKERSET_TOML)
    if layout_name == "off-lips":
        layout, markerset = off_lip_layout(layout, mesh, markerset, landmarks)
    performance = read_performance(shared_data() / "arkit-performances" / "alex_rom_3.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                  # TongueOut: no ICT shape
        sim = simulate_capture(basis, performance, layout, markerset.head, rate=RATE,
                               duration=seconds, noise_mm=0.2, seed=0)
    print(f"\nsim ({layout_name}): {sim.take.n_frames} frames at {RATE:g} Hz of alex_rom_3, "
          f"{len(markerset.face_markers)} face markers, ICT face {mesh.n_vertices} vertices")
    results = {}
    for label, kernel in (("TPS", "thin_plate_spline"), ("auto", "auto")):
        result, lips, seconds_taken = _reconstruct(sim.take, markerset, basis, landmarks,
                                                   kernel)
        results[label] = result
        s = result.stage_seconds
        sel = result.retargeted.selection
        print(f"  {label}: chain {seconds_taken:.1f} s (retarget {s['retarget']:.2f} s"
              + (f", of which choosing among {len(sel.candidates)} variants {sel.seconds:.2f} s"
                 if sel else "") + "), "
              f"variant {result.retargeted.cross_validation.variant}, held-out marker RMS "
              f"{result.retargeted.cross_validation.rms:.3f} mm")
        for message in lips:
            print(f"    warning: {message.split(': ', 1)[1][:200]}")
        case = f"{layout_name}_{label}"
        plot_lip_seal(result.lip_seal, OUT / f"retarget_cv_lips_sim_{case}.png")
        plot_cross_validation(result.retargeted.cross_validation,
                              OUT / f"retarget_cv_markers_sim_{case}.png", markerset=markerset)
    auto, tps = results["auto"], results["TPS"]
    first = sim.take.first_frame
    truth_gap = _truth_lips(auto, basis, sim.truth, first)
    widest = np.argsort(truth_gap)[-WIDEST:]
    print(f"  lip gap at the {WIDEST} widest frames (mm): truth {truth_gap[widest].mean():.1f}"
          f" (rest {auto.lip_seal.rest_gap:.1f}); lip markers open by "
          f"{auto.lip_seal.marker_opening[widest].mean():.1f}")
    for label, result in results.items():
        check = result.lip_seal
        for name in check.mesh_gap:
            gap = check.mesh_gap[name][widest]
            print(f"    {label:<4} {name:<4} {gap.mean():5.1f} mm, |gap - truth| mean "
                  f"{np.abs(gap - truth_gap[widest]).mean():5.1f} max "
                  f"{np.abs(gap - truth_gap[widest]).max():5.1f} (aim <= 2 for W·D of auto); "
                  f"shut frames {int(check.shut(name).sum())}")
    check = tps.lip_seal
    truth_open = (truth_gap - check.rest_gap) >= check.marker_open_mm
    shut = check.shut("W·D")
    print(f"  TPS W·D shut in {int(shut.sum())} frames; of the {int(truth_open.sum())} frames "
          f"where the true mouth opens by >= {check.marker_open_mm:.1f} mm, "
          f"{shut[truth_open].mean():.0%} flagged; flagged frames with the true mouth open by "
          f">= {check.open_mm:g} mm: "
          f"{np.mean(truth_gap[shut] - check.rest_gap >= check.open_mm):.0%}")

    centers = MarkerGeometry.from_binding(auto.binding, mesh, auto.retargeted.labels).centers
    vertices = np.flatnonzero(cKDTree(centers).query(mesh.vertices)[0] * 10.0 <= FACE_MM)
    labels = auto.retargeted.labels
    regions = lip_regions(markerset, labels)
    tic = time.perf_counter()
    errors = _variant_truth_errors(auto, basis, sim.truth, first, vertices, regions)
    selection = auto.retargeted.selection
    keys = sorted(errors)
    scores = np.array([selection.candidates[i].score_mm for i in keys])
    errs = np.array([errors[i] for i in keys])
    rho = spearmanr(scores, errs).statistic
    best = keys[int(np.argmin(errs))]
    chosen = selection.chosen
    print(f"  {len(keys)} variants scored against the truth ({len(vertices)} vertices within "
          f"{FACE_MM:g} mm of a marker, every {TRUTH_STEP}rd frame, "
          f"{time.perf_counter() - tic:.0f} s): "
          f"Spearman rank correlation of the cross-validated marker error with the vertex "
          f"error {rho:.3f} (aim >= 0.8)")
    cv_best = keys[int(np.argmin(scores))]
    print(f"    chosen by auto: {selection.best.name}: vertex RMS {errors[chosen]:.3f} mm; "
          f"truth-best: {selection.candidates[best].name}: {errors[best]:.3f} mm; ratio "
          f"{errors[chosen] / errors[best]:.3f} (aim <= 1.10); lowest score alone: "
          f"{selection.candidates[cv_best].name}: {errors[cv_best]:.3f} mm")
    shared, general, test, _ = _floor(auto, basis, sim.truth, first, vertices)
    mouth = auto.retargeted.mouth
    _, _, _, at_lips = _floor(auto, basis, sim.truth, first, mouth.vertex_ids)
    lips_rest = mesh.vertices[mouth.vertex_ids]
    test_widest = np.flatnonzero(test)[np.argsort(truth_gap[test])[-WIDEST:]]
    floor_gap = 10.0 * mouth.gap(lips_rest + np.matmul(
        at_lips, auto.retargeted.displacements[test_widest]))
    frames = np.flatnonzero(test)
    d = auto.retargeted.displacements[frames]
    true = _true_displacements(auto, basis, sim.truth, first, vertices)[frames]
    chosen_err = _rms_mm(np.matmul(_dense(auto.retargeted.operator.matrix)[vertices], d), true)
    tps_err = _rms_mm(np.matmul(_dense(tps.retargeted.operator.matrix)[vertices],
                                tps.retargeted.displacements[frames]),
                      _true_displacements(tps, basis, sim.truth, first, vertices)[frames])
    motion = 10.0 * float(np.sqrt(np.mean(np.sum(true ** 2, axis=-1))))
    print(f"  floor (best linear map from these markers, fitted on alternate 1 s blocks, "
          f"scored on the others): {shared:.3f} mm (the RBF class: one weight per vertex and "
          f"marker), {general:.4f} mm (any linear map of the 3M coordinates); on those frames "
          f"auto {chosen_err:.3f} mm = {chosen_err / shared:.1f} x the floor "
          f"({chosen_err / motion:.1%} of the {motion:.2f} mm RMS true motion), TPS "
          f"{tps_err:.3f} mm = {tps_err / shared:.1f} x the floor")
    print(f"  the floor's lip gap at the {WIDEST} widest test frames: {floor_gap.mean():.1f} mm, "
          f"truth {truth_gap[test_widest].mean():.1f}, auto W·D "
          f"{auto.lip_seal.mesh_gap['W·D'][test_widest].mean():.1f}")
    _plot_scores(scores, errs, keys.index(chosen), keys.index(best), shared,
                 OUT / f"retarget_cv_vs_truth_{layout_name}.png",
                 f"{layout_name}: {len(keys)} variants; Spearman's rank correlation {rho:.2f}")


# ---------------------------------------------------------------- facial-sing

def part_sing(basis, landmarks) -> None:
    markerset = load_markerset(REPO / "tests" / "facial_sing_markerset.toml")
    take = mocap.read(shared_data() / "captures" / "facial-sing.c3d")
    print(f"\nsing: facial-sing.c3d, {take.n_frames} frames at {take.rate:g} Hz, "
          f"{len(markerset.face_markers)} face markers, on the ICT face")
    for label, kernel in (("TPS", "thin_plate_spline"), ("auto", "auto")):
        result, lips, seconds = _reconstruct(take, markerset, basis, landmarks, kernel)
        check = result.lip_seal
        s = result.stage_seconds
        sel = result.retargeted.selection
        print(f"  {label}: chain {seconds:.1f} s (retarget {s['retarget']:.2f} s"
              + (f", choosing {sel.seconds:.2f} s" if sel else "") + "), variant "
              f"{result.retargeted.cross_validation.variant}, held-out marker RMS "
              f"{result.retargeted.cross_validation.rms:.3f} mm; lip markers open by up to "
              f"{check.marker_opening.max():.1f} mm (threshold {check.marker_open_mm:.1f})")
        for name in check.mesh_gap:
            print(f"    {name:<4} widest opening {check.mesh_opening(name).max():5.1f} mm, shut "
                  f"frames {int(check.shut(name).sum())}, parted {int(check.parted(name).sum())}")
        for message in lips:
            print(f"    warning: {message.split(': ', 1)[1][:220]}")
        plot_lip_seal(check, OUT / f"retarget_cv_lips_sing_{label}.png")
        plot_cross_validation(result.retargeted.cross_validation,
                              OUT / f"retarget_cv_markers_sing_{label}.png", markerset=markerset)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--parts", nargs="*", default=["speed", "auto", "sim", "sing"],
                        choices=["speed", "auto", "sim", "sing"])
    parser.add_argument("--layout", choices=["off-lips", "ict"], default="off-lips")
    parser.add_argument("--seconds", type=float, default=100.0, help="simulated capture, s")
    args = parser.parse_args()
    OUT.mkdir(exist_ok=True)
    basis, landmarks = _load_ict()
    if "speed" in args.parts:
        part_speed(basis, landmarks)
    if "auto" in args.parts:
        part_auto(basis, landmarks)
    if "sim" in args.parts:
        part_sim(basis, landmarks, args.layout, args.seconds)
    if "sing" in args.parts:
        part_sing(basis, landmarks)
    print(f"\npictures in {OUT}")


if __name__ == "__main__":
    main()
