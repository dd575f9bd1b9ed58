"""Benchmark: the bounded temporally smooth solve, new against the old whole-sequence iteration.

Problem: ``solve_weights(..., lower=0, upper=1, smoothness=λ)`` of the fit's
H weights as ``mocap2mesh run`` meets it on the ground-truth take of
``bench_fit_options.py``: the 53 ICT expressions at 66 seeded vertices, in
the mesh's units (cm, as the chain's marker-space fit; λ is in those units²),
driven by the real ARKit performance ``alex_rom_4.csv`` resampled to the
chain's 3,870 frames, imaged by the basis, plus 0.02 cm (0.2 mm) of noise.

Old: the previous ``fit.solve.temporal._bounded``, copied here as the baseline (the
library no longer has it): primal-dual active set over the whole sequence
from the frames' own optima (the exact per-frame solve, timed with it), one
full banded factorization per iteration until every frame meets KKT. New:
:func:`fit.solve.temporal.solve_smooth` (ADMM start, local settling of sparse
state changes, global banded solves, the last ones through the previous factor;
:mod:`fit.solve._smooth`). Both are timed in the same run, λ by λ, so the ratio
holds under load; "global" counts the whole-sequence solves (for the old one a
factorization each; for the new one a factorization, or a low-rank correction
of the last one), "solves/frame" the reduced solves a frame took part in
(global and local). Δ objective: the new sequence objective
minus the old, relative to |old|; KKT: the worst residual of each.

Usage: ``python bench/bench_smooth.py`` (one BLAS thread unless set).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import scipy.linalg  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import shared_data  # noqa: E402
from bench_solve import CM_TO_MM, arkit_column, load_basis  # noqa: E402

from fit.solve._active_set import RANK_RTOL, BoxQP, kkt_residual, solve_box_qp  # noqa: E402
from fit.solve._smooth import _step, gradient  # noqa: E402
from fit.solve.temporal import solve_smooth  # noqa: E402

N_FRAMES = 3870
NOISE_CM = 0.02
LAMBDAS = (0.1, 1.0, 10.0, 100.0, 1000.0)
TOL = 1e-9


def _old_banded(G, lam, free, ridge):
    """The old reduced sequence Hessian, upper banded (n + 1, T·n)."""
    T, n = free.shape
    scale = float(np.mean(np.diag(G))) or 1.0
    flat = free.ravel()
    ab = np.zeros((n + 1, T * n))
    deg = np.full(T, 2.0)
    deg[[0, -1]] = 1.0 if T > 1 else 0.0
    diag = (np.diag(G)[None, :] + ridge + lam * deg[:, None]).ravel()
    ab[n] = np.where(flat, diag, scale)
    cols = np.arange(n)
    for k in range(1, n):
        band = np.tile(np.where(cols >= k, G[(cols - k) % n, cols], 0.0), T)
        ab[n - k, k:] = (band * flat * np.roll(flat, k))[k:]
    if T > 1:
        ab[0, n:] = -lam * (flat[n:] & flat[:-n])
    return ab


def _laplacian(w):
    out = np.zeros_like(w)
    diff = np.diff(w, axis=0)
    out[:-1] -= diff
    out[1:] += diff
    return out


def old_solve(qp, c, lam, max_iter):
    """The old path: the per-frame exact start, then whole-sequence PDAS; (w, iterations)."""
    T, n = c.shape
    start = solve_box_qp(qp, c, tol=TOL, max_iter=max_iter, warm_start=True)[0]
    ridge = RANK_RTOL * np.linalg.eigvalsh(qp.G)[-1] if qp.singular else 0.0
    state = np.where(start <= qp.lo, -1, np.where(start >= qp.hi, 1, 0)).astype(np.int8)
    state[:, qp.fixed] = -1
    seen = {state.tobytes()}
    for it in range(1, max_iter + 1):
        free = state == 0
        fixed_part = qp.bound_values(state)
        grad_fixed = fixed_part @ qp.G + lam * _laplacian(fixed_part)
        rhs = np.where(free, c - grad_fixed, 0.0).ravel()
        step = scipy.linalg.solveh_banded(_old_banded(qp.G, lam, free, ridge), rhs)
        w = fixed_part + np.where(free, step.reshape(T, n), 0.0)
        g, scale = gradient(qp.G, c, lam, w)
        if (kkt_residual(w, g, scale, qp.lo, qp.hi) <= TOL).all():
            break
        new = _step(qp, state, w, g)       # the old update, unchanged in fit.solve._smooth
        key = new.tobytes()
        if key in seen:
            break
        seen.add(key)
        state = new
    return np.clip(w, qp.lo, qp.hi), it


def problem(root: Path):
    """G (53, 53) in cm², the linear terms C (T, 53) and the bounds."""
    basis, names = load_basis(root, np.random.default_rng(20240501))
    basis = basis / CM_TO_MM
    table = pd.read_csv(root / "arkit-performances" / "alex_rom_4.csv")
    weights = np.stack([table[arkit_column(n, table.columns)].to_numpy(float) for n in names], 1)
    src, dst = np.linspace(0, 1, len(weights)), np.linspace(0, 1, N_FRAMES)
    truth = np.clip(np.stack([np.interp(dst, src, col) for col in weights.T], axis=1), 0, 1)
    rng = np.random.default_rng(7)
    data = truth @ basis.T + NOISE_CM * rng.standard_normal((N_FRAMES, basis.shape[0]))
    n = basis.shape[1]
    return BoxQP.build(basis.T @ basis, np.zeros(n), np.ones(n)), data @ basis


def objective(qp, c, lam, w):
    return (0.5 * np.sum(w * (w @ qp.G)) - np.sum(c * w)
            + 0.5 * lam * np.sum(np.diff(w, axis=0) ** 2))


def main() -> None:
    qp, c = problem(shared_data())
    max_iter = 20 * qp.n + 20
    tic = time.perf_counter()
    solve_box_qp(qp, c, tol=TOL, max_iter=max_iter, warm_start=True)
    per_frame = time.perf_counter() - tic
    print(f"ICT H problem: {len(c)} frames x {qp.n} shapes, bounds [0, 1], cond(G) "
          f"{qp.cond:.3g}, cm units; per-frame exact solve {per_frame:.2f} s; "
          f"BLAS threads {os.environ['OPENBLAS_NUM_THREADS']}\n")
    print(f"{'λ':>7} {'old s':>7} {'global':>6} {'new s':>7} {'global':>6} "
          f"{'solves/frame':>12} {'ratio':>6} {'× per-frame':>11} {'Δ objective':>11} "
          f"{'KKT old':>8} {'KKT new':>8}")
    for lam in LAMBDAS:
        tic = time.perf_counter()
        w_old, it_old = old_solve(qp, c, lam, max_iter)
        old_s = time.perf_counter() - tic
        tic = time.perf_counter()
        w_new, n_iter, kkt_new, _ = solve_smooth(qp, c, lam, tol=TOL, max_iter=max_iter)
        new_s = time.perf_counter() - tic
        g, scale = gradient(qp.G, c, lam, w_old)
        kkt_old = kkt_residual(w_old, g, scale, qp.lo, qp.hi).max()
        f_old, f_new = objective(qp, c, lam, w_old), objective(qp, c, lam, w_new)
        print(f"{lam:>7g} {old_s:>7.2f} {it_old:>6} {new_s:>7.2f} {n_iter.min():>6} "
              f"{n_iter.mean():>12.1f} {old_s / new_s:>5.1f}x {new_s / per_frame:>10.1f}x "
              f"{(f_new - f_old) / abs(f_old):>11.1e} {kkt_old:>8.1e} {kkt_new.max():>8.1e}",
              flush=True)


if __name__ == "__main__":
    main()
