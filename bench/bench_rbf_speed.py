"""Benchmark: RBF retargeting of a 35,000-frame take of 66 markers onto the ICT face.

Compares, in one run:
* ``RBFOperator.apply`` (one GEMM per cache-sized tile of frames and vertices) against
  ``scipy.interpolate.RBFInterpolator`` rebuilt for every frame (timed on a
  subset of frames and extrapolated: the full take would take many minutes);
* the same against a bare float32 GEMM of the same shapes, W (N, M) @ D (M, 3T), the
  two timed alternately in one run (best of three each) so that a load on the machine
  weighs on both;
* operator build times (Euclidean thin-plate spline; geodesic Wendland, heat
  method included);
* peak memory of the whole take streamed to disk in chunks (``iter_chunks``),
  as the peak RSS of a child process run first (interpreter, mesh, operator,
  input take and chunks all included).

Both on the BLAS threads of ``OPENBLAS_NUM_THREADS`` (1 unless set).

Run: ``python bench/bench_rbf_speed.py [--frames 35000]``.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import trimesh  # noqa: E402
from scipy.interpolate import RBFInterpolator  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import best_time, shared_data, without_kept_geodesics  # noqa: E402

from mocap.retarget.rbf import build_rbf_operator  # noqa: E402

N_MARKERS = 66
SCIPY_FRAMES = 30


def load_face():
    """ICT neutral mesh (cm): vertices (9409, 3) and triangles (quads split by trimesh)."""
    mesh = trimesh.load(shared_data() / "ict-face" / "generic_neutral_mesh.obj", process=False)
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def marker_vertices(vertices, n=N_MARKERS):
    """`n` vertices spread over the face by farthest-point sampling."""
    chosen = [int(np.argmax(vertices[:, 1]))]
    nearest = np.linalg.norm(vertices - vertices[chosen[0]], axis=1)
    for _ in range(n - 1):
        chosen.append(int(np.argmax(nearest)))
        nearest = np.minimum(nearest, np.linalg.norm(vertices - vertices[chosen[-1]], axis=1))
    return np.array(chosen)


def displacements(centers, n_frames, seed=0):
    """Smooth synthetic marker displacements (T, M, 3), mm: a few travelling waves."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames)[:, None, None] / 120.0
    out = np.zeros((n_frames, len(centers), 3))
    for _ in range(4):
        k, freq, amp = rng.normal(size=3) / 10.0, rng.uniform(0.2, 2.0), rng.uniform(0.5, 3.0, 3)
        out += amp * np.sin(2 * np.pi * freq * t + (centers @ k)[None, :, None])
    return out


def stream_child(n_frames: int) -> None:
    """Child process: build, stream the whole take to a file, print ru_maxrss (MB)."""
    vertices, faces = load_face()
    idx = marker_vertices(vertices)
    op = build_rbf_operator(vertices[idx], vertices, kernel="wendland_c2", epsilon=1 / 5.0,
                            distance="geodesic", mesh=(vertices, faces))
    d = displacements(vertices[idx], n_frames)
    with tempfile.TemporaryFile() as sink:
        for _, block in op.iter_chunks(d):
            block.tofile(sink)
        size = sink.tell()
    print(peak_rss_mb(), size / 1e9)


def peak_rss_mb() -> float:
    """Peak resident memory of this process, MB: VmHWM (per address space, so not
    inherited from the parent across fork/exec as ru_maxrss can be), else ru_maxrss."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def against_gemm(op, compact, d) -> tuple[float, float, float]:
    """Seconds of ``op.apply(d)`` and of the bare float32 GEMM W @ D (M, 3T), best of three
    timed alternately so that a load on the machine weighs on both, and of
    ``compact.apply(d)`` once; all write the same bytes into one buffer, touched first
    (no page faults timed)."""
    out = np.ones((len(d), op.n_points, 3), np.float32)
    w32, rhs = op.matrix.astype(np.float32), np.ones((op.n_centers, 3 * len(d)), np.float32)
    gemm_out = out.reshape(op.n_points, 3 * len(d))
    ours = bare = float("inf")
    for _ in range(3):
        ours = min(ours, best_time(lambda: op.apply(d, out=out), repeat=1))
        bare = min(bare, best_time(lambda: np.matmul(w32, rhs, out=gemm_out), repeat=1))
    return ours, bare, best_time(lambda: compact.apply(d, out=out), repeat=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=35_000)
    parser.add_argument("--stream-child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.stream_child:
        stream_child(args.frames)
        return
    vertices, faces = load_face()
    idx = marker_vertices(vertices)
    centers = vertices[idx]
    d = displacements(centers, args.frames)
    n, m, t = len(vertices), len(centers), args.frames
    print(f"ICT face: {n} vertices, {len(faces)} triangles; {m} markers; {t} frames")
    child = subprocess.run([sys.executable, __file__, "--frames", str(t), "--stream-child"],
                           capture_output=True, text=True, check=True)
    peak_mb, written_gb = (float(x) for x in child.stdout.split())
    print(f"\nstreamed take (geodesic Wendland, iter_chunks -> file, {written_gb:.2f} GB "
          f"written): peak RSS {peak_mb:.0f} MB (aim <= 2048 MB)")

    builds = {
        "euclidean thin_plate_spline": dict(),
        "geodesic wendland_c2 (r=5 cm)": dict(kernel="wendland_c2", epsilon=1 / 5.0,
                                              distance="geodesic", mesh=(vertices, faces)),
        "geodesic gaussian (eps=0.4/cm)": dict(kernel="gaussian", epsilon=0.4,
                                               distance="geodesic", mesh=(vertices, faces)),
    }
    print("\noperator build (aim <= 5 s, geodesic included)")
    ops = {}
    for name, options in builds.items():
        without_kept_geodesics()        # each build its own geodesics
        start = time.perf_counter()
        ops[name] = build_rbf_operator(centers, vertices, **options)
        print(f"  {name:34s} {time.perf_counter() - start:7.2f} s")
    op = ops["euclidean thin_plate_spline"]

    # scipy rebuilt per frame, on a subset of frames, extrapolated to the take.
    def scipy_subset():
        for frame in d[:SCIPY_FRAMES]:
            RBFInterpolator(centers, frame)(vertices)
    scipy_total = best_time(scipy_subset, repeat=1) / SCIPY_FRAMES * t
    check = RBFInterpolator(centers, d[0])(vertices)
    print(f"\nmax |ours - scipy| on frame 0 (float64): "
          f"{np.abs(op.apply(d[:1], dtype=np.float64)[0] - check).max():.2e} mm")

    compact = ops["geodesic wendland_c2 (r=5 cm)"]
    ours, bare, ours_compact = against_gemm(op, compact, d)

    print(f"\nretargeting {t} frames (float32 out, {t * n * 3 * 4 / 1e9:.2f} GB; "
          f"OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']})")
    print(f"  {'method':44s} {'time (s)':>9s} {'ratio':>8s}")
    rows = [
        (f"scipy RBFInterpolator per frame (x{t // SCIPY_FRAMES} of {SCIPY_FRAMES} fr.)",
         scipy_total, scipy_total / ours),
        ("bare float32 GEMM W @ D (M, 3T)", bare, ours / bare),
        ("RBFOperator.apply, dense W", ours, 1.0),
        (f"RBFOperator.apply, geodesic Wendland ({type(compact.matrix).__name__})",
         ours_compact, ours_compact / ours),
    ]
    for label, secs, ratio in rows:
        print(f"  {label:44s} {secs:9.2f} {ratio:8.2f}")
    print(f"  speed-up vs scipy: {scipy_total / ours:.0f}x (aim >= 100x); "
          f"apply / bare GEMM: {ours / bare:.2f}x (aim <= 1.5x)")


if __name__ == "__main__":
    main()
