"""Numerics of the batched box-constrained QP behind :func:`fit.solve.solve_weights`.

Every frame ``t`` solves ``min_w ½ wᵀGw − c_tᵀw`` subject to ``lo ≤ w ≤ hi``,
with one symmetric positive semi-definite ``G`` (n × n) shared by all frames.
All frames iterate together: a frame's iterate is fixed by its *state*
(int8 per variable: -1 at the lower bound, +1 at the upper bound, 0 free) and
each iteration solves every frame's reduced system ``G_FF w_F = c_F − G_FA w_A``.
No frame inverts an n × n matrix: G⁻¹ is computed once, and each frame
factors only an m × m system, m = min(|F|, |A|) (usually the few bound
weights, through the Schur complement of G⁻¹). Frames with the same m are
factored together (LDLᵀ vectorized over frames). Elementwise work uses
arithmetic on masks rather than ``np.where``: the masks follow the data, and
branching on them per element costs more than the products.

Two phases: a primal-dual active-set (semismooth Newton) iteration, which
changes many variables at once and converges in a few iterations, then, for
frames where it has not converged (it can cycle when G is far from an
M-matrix), the monotone primal active-set method (one release per iteration,
step to the first blocking bound), which cannot cycle on a strictly convex
problem. Convergence is declared only from the KKT residual of the clipped
final weights, never from the iteration itself. Reduced solves get iterative
refinement (ill-conditioned G) only where the state is optimal but the KKT
residual misses the tolerance.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

#: Most frames factored together (their (m, m, frames) systems stay in cache).
_CHUNK = 512
#: Fewest frames of a batch whose size is padded up to the next batch's.
_MIN_BATCH = 64
#: Rows of the products with G and G⁻¹ (see :func:`_dot`).
_DOT_ROWS = 64
#: Frames solved together (working set of the iterations).
_BLOCK = 16384
#: Iterations of the primal-dual phase before the monotone fallback takes over
#: (2: fewest reduced solves on the ARKit bench, 4.54 per frame; 5.73 with 1, 5.02 with 3).
_PDAS_ITER = 2
#: An eigenvalue of G below this fraction of the largest one counts as zero.
RANK_RTOL = 1e3 * np.finfo(float).eps
#: Above this condition number of G, reduced solves that must be exact get a
#: refinement step (two above its square).
_REFINE_COND = 1e6


@dataclass(frozen=True)
class BoxQP:
    """The shared part of every frame's problem: G, its inverse, bounds, rank."""

    G: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    rank: int
    cond: float
    #: G⁻¹ (symmetrized), None when G is singular.
    inverse: np.ndarray | None

    @classmethod
    def build(cls, G, lo, hi) -> "BoxQP":
        G = 0.5 * (G + G.T)
        eig = np.linalg.eigvalsh(G)
        top = max(eig[-1], np.finfo(float).tiny)
        rank = int(np.count_nonzero(eig > RANK_RTOL * top))
        cond = top / eig[0] if eig[0] > 0 else np.inf
        inverse = None
        if rank == len(G):
            inverse = np.linalg.inv(G)
            inverse = 0.5 * (inverse + inverse.T)
        return cls(G=G, lo=lo, hi=hi, rank=rank, cond=float(cond), inverse=inverse)

    @property
    def n(self) -> int:
        return self.G.shape[0]

    @property
    def singular(self) -> bool:
        return self.rank < self.n

    @property
    def fixed(self) -> np.ndarray:
        return self.lo == self.hi

    @cached_property
    def _finite_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) with infinite bounds replaced by 0."""
        return (np.where(np.isfinite(self.lo), self.lo, 0.0),
                np.where(np.isfinite(self.hi), self.hi, 0.0))

    def bound_values(self, state: np.ndarray) -> np.ndarray:
        """Bound values where ``state`` is ±1, 0 where free, shape of ``state``."""
        lo, hi = self._finite_bounds
        # a bound at zero contributes nothing: its product (a (T, n) pass) is skipped
        out = hi * (state > 0) if hi.any() else np.zeros(state.shape)
        if lo.any():
            out += lo * (state < 0)
        return out


def reduced_solve(qp: BoxQP, state: np.ndarray, c: np.ndarray, *, unconstrained=None,
                  refine: bool = False,
                  gradient: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """Weights with bound variables at their bounds and free ones stationary.

    Each frame solves ``G_FF w_F = c_F − G_FA w_A`` through the smaller of its
    free set F and bound set A: directly (|F| × |F|), or, when G is invertible
    and fewer variables are bound, through the Schur complement of G⁻¹:
    ``w = u + G⁻¹λ`` with ``(G⁻¹)_AA λ_A = w_A − u_A``, u = G⁻¹c the
    unconstrained minimizer (`unconstrained`, computed if not given), an
    |A| × |A| system, and λ (zero off A) is the gradient ``G w − c``.
    Frames are sorted by that size and factored in batches. With ``refine``,
    ill-conditioned problems get more passes (iterative refinement: each
    corrects ``w`` by the reduced solve of its residual).

    Returns
    -------
    w : ndarray, shape (T, n)
        The weights, exactly at their bounds on A.
    grad : ndarray, shape (T, n), or None
        The gradient ``G w − c``: after refinement, the product itself; else
        λ on the Schur path (zero on F, equal in exact arithmetic) and, on the
        direct path, the product if ``gradient`` (else None).
    """
    free = state == 0
    n_free = np.count_nonzero(free, axis=1)
    via_bound = (2 * n_free > qp.n) & (qp.inverse is not None)
    size = np.where(via_bound, qp.n - n_free, n_free)
    # each batch's entries of the (T, n + 1) right-hand side, as flat indices
    batches = [(rows * (qp.n + 1) + sel,
                _factor(qp, _principal(qp.inverse if bound else qp.G, sel)))
               for rows, bound, sel in _batches(free, via_bound, size)]
    w = qp.bound_values(state)
    # Frames of each path, as a slice when they are all of them (views, no copies).
    schur = slice(None) if via_bound.all() else np.flatnonzero(via_bound)
    direct = slice(None) if not via_bound.any() else np.flatnonzero(~via_bound)
    on_schur, on_direct = via_bound.any(), not via_bound.all()
    rhs = np.zeros((len(c), qp.n + 1))
    if on_schur:
        base = _dot(c[schur], qp.inverse) if unconstrained is None else unconstrained[schur]
        rhs[schur, :-1] = w[schur] - base
    if on_direct:
        rhs[direct, :-1] = c[direct] - _dot(w[direct], qp.G)
    lam = np.zeros((len(c), qp.n)) if on_schur else None
    passes = _refinements(qp.cond) if refine else 0
    for left in range(passes, -1, -1):
        coef = np.zeros_like(rhs)
        for flat, solve in batches:
            np.put(coef, flat, solve(rhs.take(flat)))
        coef = coef[:, :-1]
        if on_schur:
            lam[schur] += coef[schur]
            step = _dot(coef[schur], qp.inverse)
            step += base
            step *= free[schur]
            w[schur] += step
        if on_direct:
            w[direct] += coef[direct]
        if not left:
            break
        # the next pass solves for the correction from the residual -grad
        grad = _dot(w, qp.G) - c
        if on_schur:
            base = -_dot(grad[schur], qp.inverse)
            rhs[schur, :-1] = -base
        if on_direct:
            rhs[direct, :-1] = -grad[direct]
    if passes:
        return w, _dot(w, qp.G) - c
    if not on_direct:
        return w, lam
    if not gradient:
        return w, None
    grad = lam if on_schur else np.empty_like(w)
    grad[direct] = _dot(w[direct], qp.G) - c[direct]
    return w, grad


def _dot(a, mat):
    """``a @ mat`` for (T, n) ``a``, as products of ``_DOT_ROWS`` rows.

    Products that small stay single-threaded in BLAS: on a machine whose cores
    are busy, threaded products of skinny matrices mostly wait.
    """
    out = np.empty((len(a), mat.shape[1]))
    # one product per slice, written in place: 2.6x faster than a stacked
    # (T / 64, 64, n) matmul, which copies its result
    for first in range(0, len(a), _DOT_ROWS):
        np.matmul(a[first:first + _DOT_ROWS], mat, out=out[first:first + _DOT_ROWS])
    return out


def _refinements(cond: float) -> int:
    """Refinement steps that bring a reduced solve to full accuracy."""
    return 0 if cond <= _REFINE_COND else 1 if cond <= _REFINE_COND ** 2 else 2


def _batches(free, via_bound, size):
    """Batches (frames, via_bound, sel) of frames solved together.

    Frames sorted by path and size; a batch holds up to ``_CHUNK`` frames,
    and fewer than ``_MIN_BATCH`` frames of one size join (padded up) the
    frames of the next size.
    ``sel`` (width, frames) indexes each frame's smaller set, padded with n.
    """
    order = np.lexsort((size, via_bound))
    key = (size + (len(free[0]) + 1) * via_bound)[order]
    ends = np.r_[np.flatnonzero(np.diff(key)) + 1, len(order)]
    # each frame's smaller set: its bound variables on the Schur path, else its free ones
    index = _padded_index(free ^ via_bound[:, None], size)
    start = 0
    for end in ends:
        if end - start < _MIN_BATCH and end < len(order) and \
                via_bound[order[end]] == via_bound[order[start]]:
            continue
        for first in range(start, end, _CHUNK):
            rows = order[first:min(first + _CHUNK, end)]
            width = int(size[rows[-1]])
            if width:
                # contiguous: the principal submatrices gathered with it inherit its layout
                yield rows[None, :], bool(via_bound[rows[0]]), \
                    np.ascontiguousarray(index[rows, :width].T)
        start = end


def _padded_index(mask, count):
    """(T, max count): indices of the True entries of each row of ``mask``, padded with n.

    ``count`` (T,) is each row's number of True entries.
    """
    out = np.full((len(mask), max(int(count.max(initial=0)), 1)), mask.shape[1], np.intp)
    rows, cols = np.nonzero(mask)  # row by row, each row's entries in order
    out[rows, np.arange(len(rows)) - (np.cumsum(count) - count)[rows]] = cols
    return out


def _principal(mat, sel):
    """Principal submatrices ``mat[sel, sel]``, (m, m, frames) for ``sel`` (m, frames).

    Index n (the padding) selects a row and column of the identity.
    """
    n = len(mat)
    ext = np.zeros((n + 1, n + 1))
    ext[:n, :n] = mat
    out = np.take(ext.ravel(), sel[:, None, :] * (n + 1) + sel[None, :, :])
    diag = np.arange(len(sel))
    out[diag, diag] += sel == n
    return out


def _factor(qp, mats):
    """Solver ``rhs (m, frames) -> mats⁻¹ rhs`` for the batch ``mats`` (m, m, frames).

    LDLᵀ factorization without pivoting (the matrices are symmetric positive
    definite), by columns from the lower triangle only (Crout: one product per
    column, half the work of elimination), vectorized over frames; a
    pseudo-inverse when G is singular.
    """
    if qp.singular:
        top = np.linalg.eigvalsh(qp.G)[-1]
        pinv = np.linalg.pinv(mats.transpose(2, 0, 1), rcond=RANK_RTOL * top / max(top, 1.0),
                              hermitian=True)
        return lambda rhs: np.einsum("tij,jt->it", pinv, rhs)
    m = len(mats)
    d = np.empty(mats.shape[1:])
    for j in range(m):
        if j:
            scaled = mats[j, :j] * d[:j]
            mats[j, j] -= np.einsum("kt,kt->t", mats[j, :j], scaled)
            mats[j + 1:, j] -= np.einsum("ikt,kt->it", mats[j + 1:, :j], scaled)
        d[j] = mats[j, j]
        mats[j + 1:, j] /= d[j]

    def solve(rhs):
        x = rhs.copy()
        for k in range(m - 1):
            x[k + 1:] -= mats[k + 1:, k] * x[k]
        x /= d
        for k in range(m - 2, -1, -1):
            x[k] -= np.einsum("jt,jt->t", mats[k + 1:, k], x[k + 1:])
        return x
    return solve


def kkt_residual(w, g, scale, lo, hi, *, atol=None, feasible: bool = False) -> np.ndarray:
    """Worst KKT violation of each frame, dimensionless, shape (T,).

    Primal feasibility is measured in weight units relative to ``max(1, |w|)``;
    stationarity on interior variables, and the sign of the multiplier
    (the gradient ``g``) on variables at a bound, relative to ``scale``, the
    magnitude of the terms summed into ``g``. A variable counts as at a bound
    within ``atol`` (weight units, default 1e-12 · max(1, |bound|)).
    ``feasible`` says ``w`` is within the bounds by construction (clipped, or
    free weights inside and bound ones at their bound): its feasibility term,
    zero, is then not computed (six (T, n) passes fewer).
    """
    if atol is None:
        atol = 1e-12
    # Within atol of a finite bound; never for an infinite one.
    lo_f, hi_f = (np.where(np.isfinite(b), b, 0.0) for b in (lo, hi))
    near_lo = np.where(np.isfinite(lo), lo_f + atol * np.maximum(1.0, np.abs(lo_f)), -np.inf)
    near_hi = np.where(np.isfinite(hi), hi_f - atol * np.maximum(1.0, np.abs(hi_f)), np.inf)
    # Products with masks rather than np.where: no branches on the frames' data.
    rel = g / np.maximum(scale, np.finfo(float).tiny)
    stat = np.maximum(rel * (w > near_lo), -rel * (w < near_hi))
    if not feasible:
        feas = np.maximum(np.maximum(lo - w, w - hi), 0.0) / np.maximum(1.0, np.abs(w))
        np.maximum(stat, feas, out=stat)
    return stat.max(axis=1, initial=0.0)


def residual(qp: BoxQP, w: np.ndarray, c: np.ndarray, grad=None, *,
             feasible: bool = False) -> np.ndarray:
    """KKT residual of frames ``w`` (T, n) for linear terms ``c`` (T, n).

    ``grad``, the gradient ``G w − c``, is computed when not given;
    ``feasible`` as in :func:`kkt_residual`.
    """
    grad = _dot(w, qp.G) - c if grad is None else grad
    scale = _dot(np.abs(w), np.abs(qp.G)) + np.abs(c)
    return kkt_residual(w, grad, scale, qp.lo, qp.hi, feasible=feasible)


def start_state(qp: BoxQP, c: np.ndarray, unconstrained=None) -> np.ndarray:
    """Active set of the unconstrained minimizer (given, or solved) clipped to the bounds.

    Only the clipped weights that the gradient there pushes outwards stay bound.
    """
    if unconstrained is None:
        unconstrained = reduced_solve(qp, np.zeros(c.shape, np.int8), c, gradient=False)[0]
    w = np.clip(unconstrained, qp.lo, qp.hi)
    g = _dot(w, qp.G) - c
    state = np.where((w <= qp.lo) & (g > 0), -1,
                     np.where((w >= qp.hi) & (g < 0), 1, 0)).astype(np.int8)
    state[:, qp.fixed] = -1
    return state


def _pdas(qp, c, u, state, max_iter, tol, n_iter):
    """Primal-dual active-set iterations; returns weights and the converged mask."""
    T = len(c)
    w = np.empty_like(c)
    done = np.zeros(T, bool)
    todo = np.arange(T)
    for _ in range(max_iter):
        s, ct, ut = state[todo], c[todo], _rows_of(u, todo)
        wt, g = reduced_solve(qp, s, ct, unconstrained=ut)
        n_iter[todo] += 1
        # Bind the free weights outside the bounds, free the bound ones whose
        # multiplier has the wrong sign (arithmetic on masks: no branches).
        new = np.subtract(wt > qp.hi, wt < qp.lo, dtype=np.int8)
        new *= s == 0
        new += s * (s * g <= 0)
        new[:, qp.fixed] = -1
        # Only a state that reproduces itself is optimal (up to accuracy).
        check = np.nonzero((new == s).all(axis=1))[0]
        ok = np.zeros(len(todo), bool)
        # (a state that reproduces itself has free weights inside the bounds)
        ok[check] = residual(qp, wt[check], ct[check], feasible=True) <= tol
        redo = check[~ok[check]]
        if redo.size and _refinements(qp.cond):
            wt[redo], g[redo] = reduced_solve(qp, s[redo], ct[redo], refine=True,
                                              unconstrained=_rows_of(ut, redo))
            ok[redo] = residual(qp, wt[redo], ct[redo], g[redo]) <= tol
        w[todo] = wt
        state[todo] = np.where(ok[:, None], s, new)
        done[todo[ok]] = True
        todo = todo[~ok]
        if not todo.size:
            break
    return w, done


def _rows_of(u, rows):
    """``u[rows]``, or None when there is no ``u`` (singular G)."""
    return None if u is None else u[rows]


def _primal(qp, c, u, w, state, max_iter, tol, n_iter):
    """Monotone primal active-set iterations from feasible ``w``, ``state`` (both in place).

    The working arrays hold the frames not yet converged; a frame's weights
    and state are written back when it converges or the iterations end.
    """
    done = np.zeros(len(c), bool)
    todo = np.arange(len(c))
    s, wt, ct, ut = state.copy(), w, c, u
    for _ in range(max_iter):
        target, lam = reduced_solve(qp, s, ct, unconstrained=ut)
        n_iter[todo] += 1
        alpha = _step_to_first_bound(qp, wt, target, s)
        wt = target
        # Frames at their subproblem optimum: optimal, or release the worst
        # wrong-signed multiplier, or (nothing to release) refine the solve.
        at = np.flatnonzero(alpha >= 1.0)
        scale = _scale(qp, wt[at], ct[at])
        worst, wrong = _worst_multiplier(qp, s[at], lam[at], scale)
        # a multiplier of the solve clearly wrong-signed is released unchecked;
        # the others are checked with the exact gradient
        sure = wrong > tol
        check = at[~sure]
        g = _dot(wt[check], qp.G) - ct[check]
        ok = np.zeros(len(todo), bool)
        ok[check] = kkt_residual(wt[check], g, scale[~sure], qp.lo, qp.hi, feasible=True) <= tol
        worst_g, wrong_g = _worst_multiplier(qp, s[check], g, scale[~sure])
        failed = ~ok[check]
        release = failed & (wrong_g > 0)
        s[at[sure], worst[sure]] = 0
        s[check[release], worst_g[release]] = 0
        redo = check[failed & ~release]
        if redo.size and _refinements(qp.cond):
            wt[redo], grad = reduced_solve(qp, s[redo], ct[redo], refine=True,
                                           unconstrained=_rows_of(ut, redo))
            ok[redo] = residual(qp, wt[redo], ct[redo], grad) <= tol
            wt[redo] = np.clip(wt[redo], qp.lo, qp.hi)
        w[todo[ok]], state[todo[ok]] = wt[ok], s[ok]
        done[todo[ok]] = True
        keep = ~ok
        todo, s, wt, ct, ut = todo[keep], s[keep], wt[keep], ct[keep], _rows_of(ut, keep)
        if not todo.size:
            break
    w[todo], state[todo] = wt, s
    return done


def _step_to_first_bound(qp, w, target, state):
    """Step every frame from feasible ``w`` towards ``target`` up to the first bound
    in the way; binds the free variables that block it (ties too).

    ``target`` (T, n) becomes the new weights and ``state`` is updated, both
    in place. Only the free weights that ``target`` puts outside the box can
    block (bound weights are at their bound in both). Returns the step
    length, (T,), 1 where nothing blocks.
    """
    alpha = np.ones(len(w))
    frames, var = np.nonzero((target < qp.lo) | (target > qp.hi))
    if not frames.size:
        return alpha
    to, frm = target[frames, var], w[frames, var]
    up = to > qp.hi[var]
    bound = np.where(up, qp.hi[var], qp.lo[var])
    ratio = np.maximum((bound - frm) / (to - frm), 0.0)
    first = np.flatnonzero(np.r_[True, frames[1:] != frames[:-1]])
    alpha[frames[first]] = np.minimum.reduceat(ratio, first)
    moving = frames[first]
    target[moving] = np.clip(w[moving] + alpha[moving, None] * (target[moving] - w[moving]),
                             qp.lo, qp.hi)
    blocked = ratio <= alpha[frames]
    target[frames[blocked], var[blocked]] = bound[blocked]
    state[frames[blocked], var[blocked]] = np.where(up[blocked], 1, -1)
    return alpha


def _scale(qp, w, c):
    """Magnitude of the terms summed into the gradient ``G w − c``, (T, n)."""
    scale = _dot(np.abs(w), np.abs(qp.G))
    scale += np.abs(c)
    return scale


def _worst_multiplier(qp, state, g, scale):
    """Each frame's most wrong-signed multiplier: (variable, violation relative to ``scale``).

    The multiplier of a bound variable is its gradient ``g``; its sign is
    wrong when it pulls the variable into the box. Fixed variables never count.
    """
    wrong = state * g
    wrong /= np.maximum(scale, np.finfo(float).tiny)
    wrong[:, qp.fixed] = 0.0
    worst = wrong.argmax(axis=1)
    return worst, wrong[np.arange(len(worst)), worst]


def solve_box_qp(qp: BoxQP, c: np.ndarray, *, tol: float, max_iter: int,
                 warm_start: bool):
    """Solve every frame's box QP; returns (weights, n_iter, kkt, converged).

    With ``warm_start`` every frame starts from :func:`start_state` (the
    active set of its clipped unconstrained minimizer), else with every
    weight free (one more iteration). Frames go through in blocks of ``_BLOCK``.
    """
    T = len(c)
    if np.isinf(qp.lo).all() and np.isinf(qp.hi).all():
        # no bound can ever be active: one product with G^-1 (G^+ when singular,
        # the minimum-norm minimizer), no iteration
        inverse = qp.inverse if qp.inverse is not None else np.linalg.pinv(
            qp.G, rcond=RANK_RTOL, hermitian=True)
        w = _dot(c, inverse)
        kkt = residual(qp, w, c)
        return w, np.ones(T, np.int64), kkt, kkt <= tol
    w, n_iter = np.empty_like(c), np.zeros(T, np.int64)
    for start in range(0, T, _BLOCK):
        part = slice(start, start + _BLOCK)
        cp = c[part]
        u = None if qp.inverse is None else _dot(cp, qp.inverse)
        state = start_state(qp, cp, u) if warm_start else np.zeros(cp.shape, np.int8)
        w[part], n_iter[part] = _solve_from(qp, cp, u, state, tol, max_iter)
    kkt = residual(qp, w, c, feasible=True)  # clipped
    return w, n_iter, kkt, kkt <= tol


def _solve_from(qp, c, u, state, tol, max_iter):
    """Both phases from an initial state (updated in place); returns (clipped w, n_iter)."""
    n_iter = np.zeros(len(c), np.int64)
    w, done = _pdas(qp, c, u, state, min(_PDAS_ITER, max_iter), tol, n_iter)
    rest = np.nonzero(~done)[0]
    if rest.size:
        ws, ss = w[rest], state[rest]
        outside = (ss == 0) & ((ws < qp.lo) | (ws > qp.hi))
        ss = np.where(outside, np.where(ws < qp.lo, -1, 1), ss).astype(np.int8)
        ws = np.where(ss != 0, qp.bound_values(ss), ws)
        it = np.zeros(rest.size, np.int64)
        _primal(qp, c[rest], _rows_of(u, rest), ws, ss, max_iter, tol, it)
        w[rest], state[rest] = ws, ss
        n_iter[rest] += it
    return np.clip(w, qp.lo, qp.hi), n_iter
