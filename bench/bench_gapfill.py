"""Benchmark gap filling on the real capture ``captures/facial-sing.c3d``.

Run: ``python bench/bench_gapfill.py [--gaps 100] [--per-trial 10] [--seed 0] [--rigid-only]``

1. Face markers: known samples of the 31 face markers are removed as seeded
   random gaps of 10, 30, 60 and 120 frames (only where the truth is present,
   with a captured sample on each side, ``--per-trial`` gaps at a time until
   ``--gaps`` per length), then filled by each method; RMSE (mm, 3-D
   distance) and time per method and length, against a baseline of linear
   interpolation (``numpy.interp``). Aim: PCA at 60 and 120 frames at most
   half the RMSE of the spline fill.
2. Head markers: one of ``root-1``..``root-6`` removed for 200 frames (seeded
   positions, ``--head-gaps`` in all); aim: rigid fill under 1 mm RMSE.
   ``--rigid-only`` runs only this part (the same gaps as a full run).
"""

from __future__ import annotations

import argparse
import os
import time

# The PCA fill works on small matrices (~100 columns); on a shared 2-core machine
# multi-threaded BLAS only contends. Set before NumPy loads its BLAS.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from _common import shared_data  # noqa: E402

import mocap  # noqa: E402
from mocap.clean import fill_gaps  # noqa: E402

HEAD = [f"root-{i}" for i in range(1, 7)]
LENGTHS = (10, 30, 60, 120)
METHODS = ("spline", "pca", "auto")
HEAD_METHODS = ("rigid", "spline", "pca", "auto")


def load():
    take = mocap.read(shared_data() / "captures" / "facial-sing.c3d")
    return take.select([s for s in take.labels if s != "Unlabeled1"])


def draw_gaps(missing, markers, length, count, rng):
    """`count` gaps (marker, start) of `length` frames over captured samples only.

    A gap needs the truth in ``start - 1 .. start + length`` (so it neither
    touches nor merges with another gap) and must not touch one already drawn.
    """
    taken = missing.copy()
    gaps = []
    n_frames = len(missing)
    while len(gaps) < count:
        m = int(rng.choice(markers))
        start = int(rng.integers(1, n_frames - length - 1))
        if not taken[start - 1:start + length + 1, m].any():
            taken[start:start + length, m] = True
            gaps.append((m, start))
    return gaps


def linear_fill(positions):
    """Baseline: per-marker linear interpolation over the missing samples."""
    out = positions.copy()
    frames = np.arange(len(out))
    for m in range(out.shape[1]):
        seen = ~np.isnan(out[:, m, 0])
        for c in range(3):
            out[~seen, m, c] = np.interp(frames[~seen], frames[seen], out[seen, m, c])
    return out


def run_trials(take, gap_sets, length, methods, clusters):
    """Sum of squared errors, sample count and time per method over the trials."""
    stats = {m: [0.0, 0, 0.0] for m in methods + ("linear",)}
    truth = take.positions
    for gaps in gap_sets:
        pos = truth.copy()
        for m, s in gaps:
            pos[s:s + length, m] = np.nan
        holed = take.replace(positions=pos)
        rows = np.concatenate([np.arange(s, s + length) for _, s in gaps])
        cols = np.concatenate([np.full(length, m) for m, _ in gaps])
        for method in methods + ("linear",):
            t0 = time.perf_counter()
            if method == "linear":
                filled = linear_fill(pos)
            else:
                filled = fill_gaps(holed, method=method, clusters=clusters,
                                   max_gap=length).take.positions
            elapsed = time.perf_counter() - t0
            err = np.linalg.norm(filled[rows, cols] - truth[rows, cols], axis=1)
            ok = ~np.isnan(err)
            stats[method][0] += float((err[ok] ** 2).sum())
            stats[method][1] += int(ok.sum())
            stats[method][2] += elapsed
        # samples the method left missing are counted below as "unfilled"
    total = sum(len(g) for g in gap_sets) * length
    return {m: (np.sqrt(s / max(n, 1)), total - n, t) for m, (s, n, t) in stats.items()}


def print_table(title, results, methods):
    print(f"\n{title}")
    head = f"{'gap':>6} " + "".join(f"{m + ' mm':>12}" for m in methods + ("linear",))
    head += f"{'pca/spline':>12}{'unfilled':>10}" + "".join(f"{m + ' s':>10}" for m in methods)
    print(head)
    for length, res in results.items():
        line = f"{length:>6} " + "".join(f"{res[m][0]:>12.3f}" for m in methods + ("linear",))
        ratio = res["pca"][0] / res["spline"][0] if "pca" in res and "spline" in res else np.nan
        line += f"{ratio:>12.2f}{sum(res[m][1] for m in methods):>10d}"
        line += "".join(f"{res[m][2]:>10.2f}" for m in methods)
        print(line)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gaps", type=int, default=100, help="gaps per length")
    parser.add_argument("--per-trial", type=int, default=10, help="gaps removed at once")
    parser.add_argument("--head-gaps", type=int, default=30, help="200-frame head gaps")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rigid-only", action="store_true",
                        help="only the head-marker part (same gaps as a full run)")
    args = parser.parse_args()

    take = load()
    clusters = {"head": HEAD}
    rng = np.random.default_rng(args.seed)
    face = np.array([i for i, s in enumerate(take.labels) if s not in HEAD])
    print(f"facial-sing.c3d: {take.n_frames} frames at {take.rate:g} Hz, {take.n_markers} "
          f"markers ({len(face)} face), {int(take.missing.sum())} samples missing; "
          f"{args.gaps} gaps per length, {args.per_trial} at a time, seed {args.seed}")

    results = {}
    n_trials = -(-args.gaps // args.per_trial)
    for length in LENGTHS:
        gap_sets = [draw_gaps(take.missing, face, length, args.per_trial, rng)
                    for _ in range(n_trials)]        # drawn even if skipped: same head gaps
        if not args.rigid_only:
            results[length] = run_trials(take, gap_sets, length, METHODS, clusters)
    if results:
        print_table("face markers: RMSE (mm), unfilled samples, total fill time (s)",
                    results, METHODS)

    head_idx = take.indices(HEAD)
    head_sets = [draw_gaps(take.missing, head_idx, 200, 1, rng) for _ in range(args.head_gaps)]
    head = {200: run_trials(take, head_sets, 200, HEAD_METHODS, clusters)}
    print_table("head markers (one at a time): RMSE (mm), unfilled samples, time (s)",
                head, HEAD_METHODS)
    rigid = head[200]["rigid"][0]
    aims = f"rigid head fill < 1 mm: {rigid:.3f} mm ({'met' if rigid < 1 else 'NOT met'})"
    if results:
        pca60, pca120 = (results[n]["pca"][0] / results[n]["spline"][0] for n in (60, 120))
        aims = (f"PCA/spline RMSE at 60 and 120 frames <= 0.5: {pca60:.2f}, {pca120:.2f} "
                f"({'met' if max(pca60, pca120) <= 0.5 else 'NOT met'}); " + aims)
    print(f"\naims: {aims}")


if __name__ == "__main__":
    main()
