"""Benchmark: shaded picture of the ICT face (9,409 vertices, 18,460 triangles).

Compares, in one run, ``mocap.viz.render.render_mesh`` (z-buffer, 2x
supersampling, per-pixel normals) with matplotlib's ``plot_trisurf`` of the
same mesh drawn to an RGB array of the same size (Agg canvas, front view,
one shade per triangle, no anti-aliasing). Also times our renderer without
supersampling, with a per-vertex colour map, with 68 landmark points, and at
the size of a cell of the report's mesh figures (216 x 248 px, a colour map
and markers, as ``fit.report.mesh_views.plot_mesh_frames`` draws 46 of them
for a run's report), and reports peak memory. Each of our cases runs both
ways, alternately: by NumPy's batches of fragments and by the compiled z-buffer
and shading (:mod:`mocap.viz._raster_kernel`, numba: the ``speed`` extra).

Run: ``python bench/bench_render.py [--size 800] [--repeat 3]``.
"""

from __future__ import annotations

import argparse
import json
import sys
from contextlib import contextmanager
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import best_time, peak_memory_mb, shared_data  # noqa: E402

from mocap.mesh.mesh import load_mesh  # noqa: E402
from mocap.util.optional import available  # noqa: E402
from mocap.viz import _raster  # noqa: E402
from mocap.viz.render import Camera, render_mesh  # noqa: E402

#: Zoom of the matplotlib 3-D axes so that the face fills the image as in render_mesh.
TRISURF_ZOOM = 1.15


def trisurf_image(vertices, faces, size: int) -> np.ndarray:
    """The matplotlib baseline: plot_trisurf seen from the front, as an RGB array."""
    fig = plt.figure(figsize=(size / 100, size / 100), dpi=100)
    ax = fig.add_axes((0, 0, 1, 1), projection="3d", proj_type="ortho")
    # matplotlib is Z-up: show the Y-up face upright, looking along -Z
    ax.plot_trisurf(vertices[:, 0], -vertices[:, 2], vertices[:, 1], triangles=faces,
                    color=(0.82, 0.80, 0.78), linewidth=0, antialiased=False, shade=True)
    ax.view_init(elev=0, azim=-90)
    ax.set_axis_off()
    box = vertices[:, [0, 2, 1]] * [1, -1, 1]
    for lim, lo, hi in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), box.min(0), box.max(0)):
        lim(lo, hi)
    ax.set_box_aspect(np.ptp(box, axis=0), zoom=TRISURF_ZOOM)
    fig.canvas.draw()
    image = np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy()
    plt.close(fig)
    return image


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=800, help="image side, pixels")
    parser.add_argument("--repeat", type=int, default=3, help="timing repeats (best kept)")
    args = parser.parse_args()
    root = shared_data() / "ict-face"
    mesh = load_mesh(root / "generic_neutral_mesh.obj")
    jaw = load_mesh(root / "expressions" / "jawOpen.obj")
    error = np.linalg.norm(jaw.vertices - mesh.vertices, axis=1)
    landmarks = json.loads((root / "vertex_indices.json").read_text())["multi_pie_68_landmarks"]
    v, f, size = mesh.vertices, mesh.faces, (args.size, args.size)

    cell = Camera.fit(v, size=(216, 248), margin=0.1)
    cases = {
        "render_mesh (2x supersampled)": lambda: render_mesh(v, f, size=size),
        "render_mesh (no supersampling)": lambda: render_mesh(v, f, size=size, supersample=1),
        "render_mesh + colour map": lambda: render_mesh(jaw.vertices, f, size=size,
                                                        colors=error),
        "render_mesh + 68 points": lambda: render_mesh(v, f, size=size,
                                                       points=v[landmarks]),
        "report cell 216x248 + map + points": lambda: render_mesh(
            jaw.vertices, f, camera=cell, colors=error, vmin=0.0, points=v[landmarks],
            point_radius=2.5, hidden_points="dim"),
    }
    print(f"ICT face: {mesh.n_vertices} vertices, {mesh.n_faces} triangles, "
          f"{args.size}x{args.size} px, best of {args.repeat}")
    base = best_time(lambda: trisurf_image(v, f, args.size), repeat=args.repeat)
    print(f"matplotlib plot_trisurf: {base:.3f} s; speed-up = its time / ours")
    ways = ["NumPy", "compiled"] if available("numba") else ["NumPy"]
    if len(ways) == 1:
        print("numba is not installed (the speed extra): NumPy only")
    print(f"{'case':36s} {'way':>9s} {'time (s)':>9s} {'peak MB':>8s} {'speed-up':>9s}")
    for name, fn in cases.items():
        times = {}
        for _ in range(args.repeat):            # alternately, so that a load weighs on both
            for way in ways:
                with _kernels(way == "compiled"):
                    times[way] = min(times.get(way, np.inf), best_time(fn, repeat=1))
        for way in ways:
            with _kernels(way == "compiled"):
                peak = peak_memory_mb(fn)
            print(f"{name:36s} {way:>9s} {times[way]:9.3f} {peak:8.0f} "
                  f"{base / times[way]:8.1f}x")
        if len(ways) == 2:
            print(f"{'':36s} {'NumPy / compiled':>19s} {times['NumPy'] / times['compiled']:.1f}x")


@contextmanager
def _kernels(on: bool):
    """Renders by the compiled z-buffer and shading (`on`, numba loaded) or by NumPy."""
    saved = _raster._compiled_kernels
    if on:
        import numba  # noqa: F401  (loaded: the kernels are used for any size)
    else:
        _raster._compiled_kernels = lambda: None
    try:
        yield
    finally:
        _raster._compiled_kernels = saved


if __name__ == "__main__":
    main()
