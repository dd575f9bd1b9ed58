"""Benchmark (issue 3, item 1): accuracy of RBF retargeting on the ICT face.

The ICT face (cm) is driven by the real ARKit performance ``alex_rom_3.csv``
(resampled to 30 Hz), seen by the 66 markers of ``tests/ict_marker_layout.toml``
(2 mm off the skin) with :func:`mocap.synth.capture.simulate_capture`: 0.2 mm noise,
head motion (15 deg, 30 mm), no gaps. Two sources of marker displacements:

* ``pipeline``: the whole chain as a user runs it: head stabilization
  (:func:`mocap.clean.ingest.ingest`), binding of the neutral frame (:func:`mocap.bind.bind_take`,
  landmarks + ICP, 2 mm skin offset), :func:`mocap.retarget.retargeting.retarget` (head frame aligned);
* ``truth``: the layout's own surface points as centers and the noise-free
  head-frame markers (:attr:`CaptureTruth.markers_head`) as data: the error of
  the interpolation alone.

The neutral frame is the frame of smallest total weight (the performance never
rests at zero: ARKit rest weights are ~0.05 each), so the truth compared with
is the vertex displacement ``v(t) - v(f) = (w(t) - w(f)) E``.

Regions of the error (neutral mesh): *face* = vertices within FACE_MM of a
face marker's surface point (the ICT mesh's neck, ears and back of the head
carry no marker and are left out); *lips* = vertices within LIPS_MM of the
mouth opening (the shortest boundary loop below the eyes).

Run: ``python bench/bench_retarget_accuracy.py [--seconds 100] [--source pipeline]``.
Pictures: ``bench/out/retarget_error_<variant>.png`` (mean vertex error, front view).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import REPO, shared_data, without_kept_geodesics  # noqa: E402

sys.path.insert(0, str(REPO / "tests"))
from helpers import layout_binding  # noqa: E402

from basis.artist import load_artist_basis  # noqa: E402
from mocap.bind import bind_take  # noqa: E402
from mocap.clean.ingest import IngestOptions, ingest  # noqa: E402
from mocap.markerset import load_markerset  # noqa: E402
from mocap.mesh.landmarks import load_mesh_landmarks  # noqa: E402
from mocap.mesh.layout import load_marker_layout  # noqa: E402
from mocap.mesh.mesh import boundary_loops  # noqa: E402
from mocap.retarget.retargeting import (  # noqa: E402
    RetargetOptions,
    build_retarget_operator,
    marker_displacements,
    retarget,
)
from mocap.synth.capture import simulate_capture  # noqa: E402
from mocap.synth.performance import read_performance  # noqa: E402
from mocap.viz.render import colorbar, image_grid, render_mesh, save_png  # noqa: E402

MM_PER_CM = 10.0
FACE_MM = 15.0
LIPS_MM = 10.0
RATE = 30.0
TESTS = REPO / "tests"

#: name -> options (epsilon in 1/cm: Gaussian width ~2 cm, compact support 4-5 cm).
VARIANTS = {
    "tps/euclidean": RetargetOptions(kernel="thin_plate_spline"),
    "gaussian/euclidean": RetargetOptions(kernel="gaussian", epsilon=0.5),
    "tps/euclidean+regions": RetargetOptions(use_regions=True),
    "gaussian/geodesic": RetargetOptions(kernel="gaussian", epsilon=0.5, distance="geodesic"),
    "wendland/geodesic": RetargetOptions(kernel="wendland_c2", epsilon=0.2,
                                         distance="geodesic"),
    "wendland/geodesic+regions": RetargetOptions(kernel="wendland_c2", epsilon=0.2,
                                                 distance="geodesic", use_regions=True),
    "gaussian/geodesic+regions": RetargetOptions(kernel="gaussian", epsilon=0.5,
                                                 distance="geodesic", use_regions=True),
}


def regions(mesh, centers):
    """Boolean masks (N,) of the face region and the lips."""
    near = cKDTree(centers).query(mesh.vertices)[0] * MM_PER_CM <= FACE_MM
    loops = boundary_loops(mesh)[1:]                       # the outer rim is the longest
    mouth = min(loops, key=lambda loop: mesh.vertices[loop, 1].mean())
    lips = cKDTree(mesh.vertices[mouth]).query(mesh.vertices)[0] * MM_PER_CM <= LIPS_MM
    return near, lips


def measure(operator, displacements, weights, neutral_frame, basis, masks):
    """Errors (mm) of one operator over all frames, chunk by chunk."""
    shapes = basis.displacements.reshape(len(basis.names), -1)
    dw = weights - weights[neutral_frame]
    sq_err = {k: 0.0 for k in masks}
    sq_true = {k: 0.0 for k in masks}
    samples = {k: [] for k in masks}
    per_vertex = np.zeros(basis.neutral.n_vertices)
    for frames, block in operator.iter_chunks(displacements, chunk_frames=256,
                                              dtype=np.float64):
        true = (dw[frames] @ shapes).reshape(block.shape)
        err = MM_PER_CM * np.linalg.norm(block - true, axis=-1)
        mag = MM_PER_CM * np.linalg.norm(true, axis=-1)
        per_vertex += err.sum(axis=0)
        for k, mask in masks.items():
            sq_err[k] += float(np.sum(err[:, mask] ** 2))
            sq_true[k] += float(np.sum(mag[:, mask] ** 2))
            samples[k].append(err[:, mask].astype(np.float32).ravel())
    out = {}
    for k in masks:
        e = np.concatenate(samples[k])
        out[k] = dict(mean=float(e.mean()), p95=float(np.percentile(e, 95)), max=float(e.max()),
                      rms=float(np.sqrt(sq_err[k] / e.size)),
                      rms_true=float(np.sqrt(sq_true[k] / e.size)))
    return out, per_vertex / len(displacements)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=100.0, help="capture length, s")
    parser.add_argument("--source", choices=("pipeline", "truth"), default="pipeline")
    parser.add_argument("--variants", nargs="*", default=list(VARIANTS))
    args = parser.parse_args()

    ict = shared_data() / "ict-face"
    basis = load_artist_basis(ict / "generic_neutral_mesh.obj", ict / "expressions",
                              units="cm")
    mesh = basis.neutral
    markerset = load_markerset(TESTS / "ict_markerset.toml")
    layout = load_marker_layout(TESTS / "ict_marker_layout.toml", mesh)
    performance = read_performance(shared_data() / "arkit-performances" / "alex_rom_3.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                   # TongueOut: no ICT shape
        sim = simulate_capture(basis, performance, layout, markerset.head, rate=RATE,
                               duration=args.seconds, noise_mm=0.2, seed=0)
    weights = sim.truth.weights
    neutral = int(np.argmin(np.abs(weights).sum(axis=1)))
    face_labels = markerset.face_markers
    print(f"ICT face {mesh.n_vertices} vertices; {sim.take.n_frames} frames at {RATE:g} Hz "
          f"({args.seconds:g} s of alex_rom_3), {len(face_labels)} face markers; neutral "
          f"frame {neutral}; source: {args.source}")

    start = time.perf_counter()
    if args.source == "pipeline":
        take = ingest(sim.take, markerset=markerset,
                      options=IngestOptions(fill="none", stabilize=True)).take
        landmarks = load_mesh_landmarks(TESTS / "ict_landmarks.toml", mesh)
        binding = bind_take(take, markerset, mesh, landmarks, frame=neutral,
                            skin_offset=2.0).binding
        first = retarget(take, binding, mesh, markerset, neutral_frame=neutral,
                         options=VARIANTS["tps/euclidean"])
        displacements, binding_face = first.displacements, binding
        print(f"binding: {binding.message}, rms {binding.rms:.2f} mm; head-frame "
              f"alignment {np.degrees(np.arccos((np.trace(first.rotation) - 1) / 2)):.3f} deg")
    else:
        binding_face = layout_binding(layout, face_labels)
        take = sim.take.replace(positions=sim.truth.markers_head).select(face_labels)
        displacements = marker_displacements(take, binding_face, neutral_frame=neutral)
    print(f"displacements ready in {time.perf_counter() - start:.1f} s")

    centers = binding_face.marker_points(mesh.vertices)[
        [binding_face.labels.index(x) for x in face_labels]]
    face, lips = regions(mesh, centers)
    masks = {"face": face, "lips": lips}
    print(f"face region: {face.sum()} vertices within {FACE_MM:g} mm of a face marker; lips: "
          f"{lips.sum()} vertices within {LIPS_MM:g} mm of the mouth opening\n")

    head = (f"{'variant':<27} {'build s':>7} | {'face mean':>9} {'p95':>6} {'max':>6} "
            f"{'rms':>6} {'rms/true':>8} | {'lips mean':>9} {'p95':>6} {'max':>6} {'rms':>6}")
    print(head + "\n" + "-" * len(head))
    results, pictures = {}, {}
    for name in args.variants:
        without_kept_geodesics()        # each variant's build its own geodesics
        start = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            op = build_retarget_operator(binding_face, mesh, markerset, face_labels,
                                         VARIANTS[name])
        build = time.perf_counter() - start
        stats, per_vertex = measure(op, displacements, weights, neutral, basis, masks)
        results[name], pictures[name] = stats, per_vertex
        f, l = stats["face"], stats["lips"]
        print(f"{name:<27} {build:>7.2f} | {f['mean']:>9.3f} {f['p95']:>6.2f} {f['max']:>6.2f} "
              f"{f['rms']:>6.3f} {f['rms'] / f['rms_true']:>8.1%} | {l['mean']:>9.3f} "
              f"{l['p95']:>6.2f} {l['max']:>6.2f} {l['rms']:>6.3f}"
              + ("  (regularized)" if caught else ""))
    f0 = next(iter(results.values()))["face"]
    print(f"\nerrors in mm over every frame and region vertex; RMS true displacement: face "
          f"{f0['rms_true']:.3f} mm, lips {next(iter(results.values()))['lips']['rms_true']:.3f} mm")

    best = min(results, key=lambda k: results[k]["face"]["rms"])
    worst = max(results, key=lambda k: results[k]["face"]["rms"])
    euclid = min((k for k in results if "euclidean" in k and "regions" not in k),
                 key=lambda k: results[k]["lips"]["mean"], default=None)
    local = min((k for k in results if "geodesic" in k or "regions" in k),
                key=lambda k: results[k]["lips"]["mean"], default=None)
    ratio = results[best]["face"]["rms"] / results[best]["face"]["rms_true"]
    print(f"aim 1: best face RMS error {results[best]['face']['rms']:.3f} mm ({best}) = "
          f"{ratio:.1%} of the RMS true displacement (aim <= 10 %): "
          f"{'met' if ratio <= 0.10 else 'NOT met'}")
    if euclid and local:
        lip_ratio = results[local]["lips"]["mean"] / results[euclid]["lips"]["mean"]
        print(f"aim 2: lip mean error {local} {results[local]['lips']['mean']:.3f} mm / best "
              f"Euclidean {euclid} {results[euclid]['lips']['mean']:.3f} mm = {lip_ratio:.2f} "
              f"(aim <= 0.7): {'met' if lip_ratio <= 0.7 else 'NOT met'}")

    out = REPO / "bench" / "out"
    out.mkdir(exist_ok=True)
    vmax = float(np.percentile(np.concatenate([pictures[best][face], pictures[worst][face]]),
                               99))
    images = []
    for name in dict.fromkeys((best, worst)):
        colors = np.where(face, pictures[name], np.nan)
        image = render_mesh(mesh.vertices, mesh.faces, view="front", size=(600, 700),
                            colors=colors, cmap="magma", vmin=0.0, vmax=vmax,
                            points=centers)
        images.append(image)
        path = out / f"retarget_error_{name.replace('/', '_').replace('+', '_')}.png"
        save_png(image, path)
        print(f"wrote {path}")
    grid = image_grid(images + [colorbar(vmin=0.0, vmax=vmax, cmap="magma", height=700)],
                      [f"best: {best}", f"worst: {worst}", "mean error, mm"][:len(images)]
                      + ["mm"])
    save_png(grid, out / "retarget_error_best_worst.png")
    print(f"wrote {out / 'retarget_error_best_worst.png'} (grey: outside the face region)")


if __name__ == "__main__":
    main()
