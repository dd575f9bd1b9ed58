"""Benchmark: the smoothness λ chosen by GCV against the truth, on the markers alone (no chain).

The ICT face (53 shapes) driven by ``alex_rom_4.csv`` at 30 Hz, seen by the
60 face markers of ``tests/ict_marker_layout.toml`` 2 mm off the skin, in
the head frame (true, no head motion, no gaps), plus 0.2 mm of noise: the
"2mm,σ" case of ``bench_ground_truth.py``'s table 1 (its linear marker basis,
:func:`bench_ground_truth.tangent_case`, mm; bounds [0, 1]). For each λ of a
sweep (shown, never picked on the truth) and for ``smoothness="gcv"``: the
RMSE of the weights against the truth, the GCV score of the unbounded
problem (:func:`fit.solve.gcv.gcv_score`, mm²) and the solve's time. The λ the
truth would pick is marked for comparison only. The chain's version of this
(``mocap2mesh run`` with ``[fit] smoothness = "gcv"``) is in
``bench_fit_options.py``.

Usage: ``python bench/bench_gcv.py``.
"""

from __future__ import annotations

import os
import time
import warnings

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from _common import shared_data  # noqa: E402
from bench_ground_truth import NOISE_MM, load_ict, tangent_case  # noqa: E402

from fit.solve.gcv import gcv_score  # noqa: E402
from fit.solve.weights import solve_weights  # noqa: E402

SWEEP = (0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0, 300.0, 1000.0)


def main() -> None:
    basis, markerset, layout, _, performance = load_ict(shared_data())
    B, markers, rest, weights = tangent_case(basis, performance, layout, markerset, offset=True)
    rng = np.random.default_rng(5)
    data = markers + NOISE_MM * rng.standard_normal(markers.shape) - rest
    Bm, D = B.reshape(len(B), -1).T, data.reshape(len(data), -1)
    print(f"alex_rom_4 at 30 Hz onto ICT, {markers.shape[1]} face markers 2 mm off the skin, true "
          f"head frame, {NOISE_MM} mm noise; {len(D)} frames x {Bm.shape[1]} shapes, "
          f"bounds [0, 1]; BLAS threads {os.environ['OPENBLAS_NUM_THREADS']}\n")
    print(f"{'smoothness':<14} {'λ':>9} {'RMSE w':>7} {'GCV mm²':>9} {'solve s':>7}")
    rows = []
    for label, option in [("none", 0.0)] + [(f"λ = {lam:g}", lam) for lam in SWEEP] \
            + [("GCV", "gcv")]:
        tic = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            sol = solve_weights(Bm, D, lower=0.0, upper=1.0, smoothness=option)
        seconds = time.perf_counter() - tic
        rmse = float(np.sqrt(np.mean((sol.weights - weights) ** 2)))
        score = float(gcv_score(Bm, D, sol.smoothness))
        rows.append((label, sol.smoothness, rmse))
        print(f"{label:<14} {sol.smoothness:>9.4g} {rmse:>7.4f} {score:>9.5f} {seconds:>7.2f}",
              flush=True)
    best = min(rows[1:-1], key=lambda r: r[2])
    print(f"\nthe sweep's least RMSE (the truth's pick, for comparison only): {best[0]}, "
          f"{best[2]:.4f}; GCV: λ = {rows[-1][1]:.4g}, {rows[-1][2]:.4f}; "
          f"no smoothing: {rows[0][2]:.4f}")


if __name__ == "__main__":
    main()
