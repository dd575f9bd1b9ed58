"""Benchmark: ``mocap2mesh run`` on the ICT face and on the same face four times as dense.

Our users' meshes are not all the ICT face's 9,409 vertices: a production head or a scan
has several times as many. The ICT face is subdivided once (each triangle into four, new
vertices at the edges' midpoints: 37,280 vertices; the 53 shapes subdivided alike, so they
are the same surface motions), its OBJs written as a Python script writes them (``repr``:
17 significant digits), and the same simulated take (``--frames`` at 276 Hz, the marker
layout of the tests) runs through ``mocap2mesh run`` on both meshes, each in a fresh
process, no video. Printed: each stage on both and its ratio, against the vertex ratio
(4.0); a stage whose ratio is far above it does not scale with the mesh.

Beside it, on the dense face, the two steps that grew faster than the mesh, each against
its baseline in the same run: the shapes' vertex lines parsed by the compiled loop against
``numpy.loadtxt`` (what parses them without numba), and the lip gap of 4,096 frames by the
compiled loop (only the pairs that can be the nearest) against NumPy's products of every
pair of lip vertices (the same gap without numba).

Run: ``python bench/bench_dense_mesh.py [--frames 35000]``.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import REPO, best_time, run_take, scratch_directory, shared_data  # noqa: E402
from bench_chain import simulate  # noqa: E402

import mocap.mesh.mesh as mesh_module  # noqa: E402
from mocap.mesh.landmarks import load_mesh_landmarks  # noqa: E402
from mocap.mesh.mesh import load_mesh  # noqa: E402
from mocap.mesh.mouth import _expanded_least_squared_distances, find_mouth  # noqa: E402
from mocap.util.optional import compiled  # noqa: E402

TESTS = REPO / "tests"


def subdivided_face(ict: Path, out: Path) -> Path:
    """The ICT face and its 53 shapes subdivided once, as OBJs (``repr`` numbers) in `out`,
    with the ICT landmarks (the old vertices keep their ids); returns `out`."""
    neutral = load_mesh(ict / "generic_neutral_mesh.obj")
    vertices, faces = trimesh.remesh.subdivide(neutral.vertices, neutral.faces)
    if not np.array_equal(vertices[:neutral.n_vertices], neutral.vertices):
        raise SystemExit("trimesh's subdivision moved the old vertices: landmarks would move")
    face_lines = "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces.tolist())

    def write(path: Path, points: np.ndarray) -> None:
        path.write_text("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in points.tolist())
                        + face_lines, encoding="ascii")
    (out / "expressions").mkdir(parents=True)
    write(out / "neutral.obj", vertices)
    for shape in sorted((ict / "expressions").glob("*.obj")):
        moved, _ = trimesh.remesh.subdivide(load_mesh(shape).vertices, neutral.faces)
        write(out / "expressions" / shape.name, moved)
    landmarks = (TESTS / "ict_landmarks.toml").read_text(encoding="utf-8")
    (out / "landmarks.toml").write_text(landmarks.replace(
        f"n_vertices = {neutral.n_vertices}", f"n_vertices = {len(vertices)}"), encoding="utf-8")
    return out


def run(capture: Path, mesh: Path, shapes: Path, landmarks: Path, out: Path,
        frames: int) -> tuple[float, dict]:
    """``mocap2mesh run`` of `capture` on the face (a fresh process): wall seconds and the
    stage seconds of the take."""
    out.mkdir()
    wall, take = run_take(out, capture, mesh=mesh, basis=shapes, landmarks=landmarks,
                          max_gap=frames)
    return wall, {"start, inputs, record": wall - take["seconds"], **take["stage_seconds"]}


def parse_side_by_side(dense: Path) -> str:
    """The dense shapes' vertex lines: the compiled loop against ``numpy.loadtxt``."""
    neutral = load_mesh(dense / "neutral.obj")
    paths = sorted((dense / "expressions").glob("*.obj"))
    kernel = mesh_module._compiled_vertex_rows()
    slow = np.empty((3 * neutral.n_vertices, 3), np.int64)
    texts = [mesh_module._span(data, mesh_module._line_starts(data), b"v")[0]
             for data in map(mesh_module._obj_text, paths)]
    ours = best_time(lambda: [mesh_module._compiled_vertices(kernel, slow, text,
                                                             neutral.n_vertices)
                              for text in texts])
    numpy = best_time(lambda: [mesh_module._loadtxt_vertices(text, neutral.n_vertices)
                               for text in texts], repeat=1)
    size = sum(map(len, texts)) / 1e6
    return (f"the 53 shapes' vertex lines ({size:.0f} MB, repr): compiled {ours:.2f} s, "
            f"numpy.loadtxt {numpy:.2f} s, {numpy / ours:.1f}x")


def lip_gap_side_by_side(dense: Path) -> str:
    """The dense lips' gap in 4,096 moving frames: the compiled loop against NumPy's
    products of every pair."""
    mesh = load_mesh(dense / "neutral.obj", units="cm")
    mouth = find_mouth(mesh, load_mesh_landmarks(dense / "landmarks.toml", mesh))
    lips = mesh.vertices[mouth.vertex_ids]
    n_up = len(mouth.upper)
    # the lower lip opening and closing by up to 1 cm, noise of 0.02 cm
    t = np.linspace(0.0, 8.0 * np.pi, 4096)
    frames = np.repeat(lips[None], len(t), axis=0)
    frames[:, n_up:, 1] -= (0.5 + 0.5 * np.sin(t))[:, None]
    frames += np.random.default_rng(0).normal(0.0, 0.02, frames.shape)
    kernel = compiled("mocap.mesh._mouth_kernel", "least_squared_distances", what="lip gap",
                      fallback="")
    out = np.empty(len(frames))
    ours = best_time(lambda: kernel(frames, n_up, out))
    numpy = best_time(lambda: _expanded_least_squared_distances(frames, n_up))
    return (f"the lip gap, {n_up} x {len(lips) - n_up} lip vertices, 4,096 frames: compiled "
            f"{ours:.3f} s, NumPy's every pair {numpy:.3f} s, {numpy / ours:.1f}x")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=35_000)
    args = parser.parse_args()
    ict = shared_data() / "ict-face"
    out = scratch_directory("bench-dense-mesh-")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        simulate(args.frames, out / "take.c3d")
    dense = subdivided_face(ict, out / "dense")
    n_ict, n_dense = load_mesh(ict / "generic_neutral_mesh.obj").n_vertices, \
        load_mesh(dense / "neutral.obj").n_vertices
    print(f"take: {args.frames} frames at 276 Hz; ICT face {n_ict} vertices, subdivided "
          f"{n_dense} ({n_dense / n_ict:.1f}x)")
    wall_ict, ict_stages = run(out / "take.c3d", ict / "generic_neutral_mesh.obj",
                               ict / "expressions", TESTS / "ict_landmarks.toml", out / "ict",
                               args.frames)
    wall_dense, dense_stages = run(out / "take.c3d", dense / "neutral.obj",
                                   dense / "expressions", dense / "landmarks.toml",
                                   out / "dense-run", args.frames)
    print(f"\n{'stage':<24} {'ICT s':>7} {'dense s':>8} {'ratio':>6}")
    for name, seconds in ict_stages.items():
        print(f"{name:<24} {seconds:>7.2f} {dense_stages[name]:>8.2f} "
              f"{dense_stages[name] / seconds:>5.1f}x")
    print(f"{'run (wall)':<24} {wall_ict:>7.2f} {wall_dense:>8.2f} "
          f"{wall_dense / wall_ict:>5.1f}x")
    print("\nside by side on the dense face:")
    print("  " + parse_side_by_side(dense))
    print("  " + lip_gap_side_by_side(dense))


if __name__ == "__main__":
    main()
