"""Numerics of the batched box-constrained QP behind :func:`fit.solve.solve_weights`.

Every frame ``t`` solves ``min_w ½ wᵀGw − c_tᵀw`` subject to ``lo ≤ w ≤ hi``,
with one symmetric positive semi-definite ``G`` (n × n) shared by all frames.
All frames iterate together: a frame's iterate is fixed by its *state*
(int8 per variable: -1 at the lower bound, +1 at the upper bound, 0 free) and
each iteration solves every frame's reduced system ``G_FF w_F = c_F − G_FA w_A``.
Frames with the same free set share one inverse of their masked matrix, so an
iteration costs one (pseudo-)inverse per *distinct* free set plus a gathered
matrix-vector product per frame.

Two phases: a primal-dual active-set (semismooth Newton) iteration, which
changes many variables at once and converges in a few iterations, then, for
frames where it has not converged (it can cycle when G is far from an
M-matrix), the monotone primal active-set method (one release per iteration,
step to the first blocking bound), which cannot cycle on a strictly convex
problem. Convergence is declared only from the KKT residual of the clipped
final weights, never from the iteration itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Frames per chunk of the gathered (chunk, n, n) products (memory budget).
_CHUNK = 2048
#: Frames between two seeds of the warm start (they are solved first).
WARM_STRIDE = 16
#: Iterations of the primal-dual phase before the monotone fallback takes over.
_PDAS_ITER = 5
#: An eigenvalue of G below this fraction of the largest one counts as zero.
RANK_RTOL = 1e3 * np.finfo(float).eps
#: Above this condition number of G, each reduced solve gets one refinement step.
_REFINE_COND = 1e6


@dataclass(frozen=True)
class BoxQP:
    """The shared part of every frame's problem: G, bounds, rank."""

    G: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    rank: int
    cond: float

    @classmethod
    def build(cls, G, lo, hi) -> "BoxQP":
        G = 0.5 * (G + G.T)
        eig = np.linalg.eigvalsh(G)
        top = max(eig[-1], np.finfo(float).tiny)
        rank = int(np.count_nonzero(eig > RANK_RTOL * top))
        cond = top / eig[0] if eig[0] > 0 else np.inf
        return cls(G=G, lo=lo, hi=hi, rank=rank, cond=float(cond))

    @property
    def n(self) -> int:
        return self.G.shape[0]

    @property
    def singular(self) -> bool:
        return self.rank < self.n

    @property
    def fixed(self) -> np.ndarray:
        return self.lo == self.hi

    def bound_values(self, state: np.ndarray) -> np.ndarray:
        """Bound values where ``state`` is ±1, 0 where free, shape of ``state``."""
        lo = np.where(np.isfinite(self.lo), self.lo, 0.0)
        hi = np.where(np.isfinite(self.hi), self.hi, 0.0)
        return np.where(state < 0, lo, np.where(state > 0, hi, 0.0))


def _masked_inverses(qp: BoxQP, free: np.ndarray) -> np.ndarray:
    """(Pseudo-)inverses of G masked to each row of ``free`` (u, n), identity elsewhere."""
    scale = float(np.mean(np.diag(qp.G))) or 1.0
    both = free[:, :, None] & free[:, None, :]
    mats = np.where(both, qp.G, 0.0)
    diag = np.arange(qp.n)
    mats[:, diag, diag] += np.where(free, 0.0, scale)
    if qp.singular:
        top = np.linalg.eigvalsh(qp.G)[-1]
        return np.linalg.pinv(mats, rcond=RANK_RTOL * top / max(top, scale),
                              hermitian=True)
    return np.linalg.inv(mats)


def _apply(inverses: np.ndarray, which: np.ndarray, vec: np.ndarray) -> np.ndarray:
    """``inverses[which[t]] @ vec[t]`` for every frame, in chunks."""
    out = np.empty_like(vec)
    if len(inverses) == 1:
        return vec @ inverses[0].T
    for start in range(0, len(vec), _CHUNK):
        part = slice(start, start + _CHUNK)
        out[part] = np.matmul(inverses[which[part]], vec[part, :, None])[:, :, 0]
    return out


def reduced_solve(qp: BoxQP, state: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Weights with bound variables at their bounds and free ones stationary.

    Frames are grouped by free set; one refinement step is added when G is
    ill-conditioned, because an explicit inverse is not backward stable.
    """
    free = state == 0
    fixed_part = qp.bound_values(state)
    rhs = np.where(free, c - fixed_part @ qp.G, 0.0)
    keys, which = np.unique(np.packbits(free, axis=1), axis=0, return_inverse=True)
    which = which.ravel()
    masks = np.unpackbits(keys, axis=1, count=qp.n).astype(bool)
    inverses = _masked_inverses(qp, masks)
    step = _apply(inverses, which, rhs)
    if qp.cond > _REFINE_COND:
        resid = np.where(free, rhs - step @ qp.G, 0.0)
        step += _apply(inverses, which, resid)
    return fixed_part + np.where(free, step, 0.0)


def kkt_residual(w, g, scale, lo, hi, *, atol=None) -> np.ndarray:
    """Worst KKT violation of each frame, dimensionless, shape (T,).

    Primal feasibility is measured in weight units relative to ``max(1, |w|)``;
    stationarity on interior variables, and the sign of the multiplier
    (the gradient ``g``) on variables at a bound, relative to ``scale``, the
    magnitude of the terms summed into ``g``. A variable counts as at a bound
    within ``atol`` (weight units, default 1e-12 · max(1, |bound|)).
    """
    lo_f = np.where(np.isfinite(lo), lo, 0.0)
    hi_f = np.where(np.isfinite(hi), hi, 0.0)
    if atol is None:
        atol = 1e-12
    at_lo = np.isfinite(lo) & (w <= lo_f + atol * np.maximum(1.0, np.abs(lo_f)))
    at_hi = np.isfinite(hi) & (w >= hi_f - atol * np.maximum(1.0, np.abs(hi_f)))
    viol = np.where(at_lo & at_hi, 0.0,
                    np.where(at_lo, np.maximum(-g, 0.0),
                             np.where(at_hi, np.maximum(g, 0.0), np.abs(g))))
    stat = viol / np.maximum(scale, np.finfo(float).tiny)
    feas = np.maximum(np.maximum(lo - w, w - hi), 0.0) / np.maximum(1.0, np.abs(w))
    return np.maximum(stat, feas).max(axis=1, initial=0.0)


def residual(qp: BoxQP, w: np.ndarray, c: np.ndarray) -> np.ndarray:
    """KKT residual of frames ``w`` (T, n) for linear terms ``c`` (T, n)."""
    g = w @ qp.G - c
    scale = np.abs(w) @ np.abs(qp.G) + np.abs(c)
    return kkt_residual(w, g, scale, qp.lo, qp.hi)


def cold_state(qp: BoxQP, c: np.ndarray) -> np.ndarray:
    """State of the unconstrained minimizer clipped to the bounds."""
    w = reduced_solve(qp, np.zeros(c.shape, np.int8), c)
    state = np.where(w < qp.lo, -1, np.where(w > qp.hi, 1, 0)).astype(np.int8)
    state[:, qp.fixed] = -1
    return state


def _pdas(qp, c, state, max_iter, tol, n_iter):
    """Primal-dual active-set iterations; returns weights and the converged mask."""
    T = len(c)
    w = np.empty_like(c)
    done = np.zeros(T, bool)
    todo = np.arange(T)
    for _ in range(max_iter):
        s = state[todo]
        wt = reduced_solve(qp, s, c[todo])
        n_iter[todo] += 1
        ok = residual(qp, wt, c[todo]) <= tol
        g = wt @ qp.G - c[todo]
        new = s.copy()
        new[(s == 0) & (wt < qp.lo)] = -1
        new[(s == 0) & (wt > qp.hi)] = 1
        new[((s == -1) & (g < 0)) | ((s == 1) & (g > 0))] = 0
        new[:, qp.fixed] = -1
        w[todo] = wt
        state[todo] = np.where(ok[:, None], s, new)
        done[todo[ok]] = True
        todo = todo[~ok]
        if not todo.size:
            break
    return w, done


def _primal(qp, c, w, state, max_iter, tol, n_iter):
    """Monotone primal active-set iterations from feasible ``w`` (in place)."""
    done = np.zeros(len(c), bool)
    todo = np.arange(len(c))
    for _ in range(max_iter):
        if not todo.size:
            break
        s, wt, ct = state[todo], w[todo], c[todo]
        target = reduced_solve(qp, s, ct)
        n_iter[todo] += 1
        step = target - wt
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(step < 0, (qp.lo - wt) / step,
                             np.where(step > 0, (qp.hi - wt) / step, np.inf))
        ratio = np.where(s == 0, np.maximum(ratio, 0.0), np.inf)
        alpha = np.minimum(ratio.min(axis=1), 1.0)
        wt = wt + alpha[:, None] * step
        blocked = (s == 0) & (ratio <= alpha[:, None]) & (alpha[:, None] < 1.0)
        s = np.where(blocked, np.where(step < 0, -1, 1), s).astype(np.int8)
        wt = np.where(s != 0, qp.bound_values(s), np.clip(wt, qp.lo, qp.hi))
        g = wt @ qp.G - ct
        scale = np.abs(wt) @ np.abs(qp.G) + np.abs(ct)
        ok = kkt_residual(wt, g, scale, qp.lo, qp.hi) <= tol
        # Release the worst wrong-signed multiplier of frames at their subproblem optimum.
        wrong = np.where(s == -1, -g, np.where(s == 1, g, 0.0)) / np.maximum(
            scale, np.finfo(float).tiny)
        wrong[:, qp.fixed] = 0.0
        release = (alpha >= 1.0) & ~ok & (wrong.max(axis=1) > 0)
        rows = np.nonzero(release)[0]
        s[rows, wrong[rows].argmax(axis=1)] = 0
        w[todo], state[todo] = wt, s
        done[todo[ok]] = True
        todo = todo[~ok]
    return done


def solve_box_qp(qp: BoxQP, c: np.ndarray, *, tol: float, max_iter: int,
                 warm_start: bool):
    """Solve every frame's box QP; returns (weights, n_iter, kkt, converged).

    With ``warm_start``, every ``WARM_STRIDE``-th frame is solved first from a
    cold start (the clipped unconstrained minimizer), and every other frame
    starts from the final active set of the seed frame before it.
    """
    T = len(c)
    n_iter = np.zeros(T, np.int64)
    if warm_start and T > WARM_STRIDE:
        seeds = np.arange(0, T, WARM_STRIDE)
        w_seed, it_seed, state_seed = _solve_from(
            qp, c[seeds], cold_state(qp, c[seeds]), tol, max_iter)
        rest = np.setdiff1d(np.arange(T), seeds)
        w_rest, it_rest, _ = _solve_from(
            qp, c[rest], state_seed[rest // WARM_STRIDE], tol, max_iter)
        w = np.empty_like(c)
        w[seeds], w[rest] = w_seed, w_rest
        n_iter[seeds], n_iter[rest] = it_seed, it_rest
    else:
        w, n_iter, _ = _solve_from(qp, c, cold_state(qp, c), tol, max_iter)
    kkt = residual(qp, w, c)
    return w, n_iter, kkt, kkt <= tol


def _solve_from(qp, c, state, tol, max_iter):
    """Both phases from an initial state; returns (clipped weights, n_iter, state)."""
    state = state.copy()
    n_iter = np.zeros(len(c), np.int64)
    w, done = _pdas(qp, c, state, min(_PDAS_ITER, max_iter), tol, n_iter)
    rest = np.nonzero(~done)[0]
    if rest.size:
        ws, ss = w[rest], state[rest]
        outside = (ss == 0) & ((ws < qp.lo) | (ws > qp.hi))
        ss = np.where(outside, np.where(ws < qp.lo, -1, 1), ss).astype(np.int8)
        ws = np.where(ss != 0, qp.bound_values(ss), ws)
        it = np.zeros(rest.size, np.int64)
        _primal(qp, c[rest], ws, ss, max_iter, tol, it)
        w[rest], state[rest] = ws, ss
        n_iter[rest] += it
    w = np.clip(w, qp.lo, qp.hi)
    return w, n_iter, state
