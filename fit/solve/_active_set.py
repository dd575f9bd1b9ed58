"""Numerics of the batched box-constrained QP behind :func:`fit.solve.weights.solve_weights`.

Every frame ``t`` solves ``min_w ½ wᵀGw − c_tᵀw`` subject to ``lo ≤ w ≤ hi``,
with one symmetric positive semi-definite ``G`` (n × n) shared by all frames.
All frames iterate together: a frame's iterate is fixed by its *state*
(int8 per variable: -1 at the lower bound, +1 at the upper bound, 0 free) and
each iteration solves every frame's reduced system ``G_FF w_F = c_F − G_FA w_A``
(:mod:`fit.solve._reduced`: m × m systems, m = min(|F|, |A|), factored in batches;
on the usual Schur path the solution's λ is the gradient on the bound set, so
sign tests need no product). Elementwise work uses arithmetic on masks rather
than ``np.where``: the masks follow the data, and branching on them per
element costs more than the products.

Two phases: a primal-dual active-set (semismooth Newton) iteration, which
changes many variables at once and converges in a few iterations, then, for
frames where it has not converged (it can cycle when G is far from an
M-matrix), the monotone primal active-set method (one release per iteration,
step to the first blocking bound), which cannot cycle on a strictly convex
problem. Its iterations change one variable of a frame's state each, so every
other one borders the previous factorization instead of factoring anew.
Convergence is declared only from the KKT residual of the clipped final
weights (with the exact gradient), never from the iteration itself. Reduced
solves get iterative refinement (ill-conditioned G) only where the state is
optimal but the KKT residual misses the tolerance.

With numba (the ``speed`` extra) and an invertible G, each frame takes these same
iterations on its own in one compiled loop (:mod:`fit.solve._box_qp_kernel`): the same
number of them, the weights the same to rounding.
"""

from __future__ import annotations

import functools

import numpy as np

from fit.solve._reduced import (
    RANK_RTOL,
    BoxQP,
    ReducedSystems,
    dot,
    gradient_of,
    reduced_solve,
    schur_weights,
)
from mocap.util.blas import map_on_blas_threads
from mocap.util.optional import compiled

__all__ = ["RANK_RTOL", "BoxQP", "kkt_residual", "reduced_solve", "residual", "solve_box_qp",
           "start_state"]

#: Frames solved together (working set of the iterations); the blocks are shared among
#: Python threads (:func:`mocap.util.blas.map_on_blas_threads`). The last iterations of a
#: block hold few frames, and cost about what their calls cost: fewer, bigger blocks
#: pay that tail less often.
_BLOCK = 8192
#: Iterations of the primal-dual phase every frame takes before the monotone fallback
#: may take it over: many frames settle in two; the rest cycle or creep, and the
#: monotone phase finishes them with a guarantee of progress.
_PDAS_ITER = 2
#: ... except that a frame whose last primal-dual step still changed at least
#: ``_PDAS_MANY`` variables, fewer than the step before, goes on (up to
#: ``_PDAS_MAX_ITER`` steps): a shrinking change is the iteration converging, and with
#: that many variables left it changes them together where the monotone phase would
#: take one iteration each (bases with many weights at a bound, such as the ICT
#: expressions fitted to markers). A frame whose change does not shrink (a cycle) or
#: has few variables left goes to the monotone phase.
_PDAS_MANY = 8
_PDAS_MAX_ITER = 8
#: Frames of a compiled block that try, in turn, their own start and the state the frame
#: before ended in (each this many): the rest of the block starts from the one that took
#: fewer iterations. Which is better depends on the take (weights near a bound flip
#: between noisy frames): the neighbour's state takes a third fewer iterations on a
#: 35,000-frame ICT take fitted at its markers, half again as many on bench_solve's.
_FOLLOW_TRIAL = 32


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
    near_lo, near_hi = _near_bounds(lo, hi, _ATOL if atol is None else atol)
    out = np.empty(len(w))
    # blocks of frames: the dozen (frames, n) temporaries of a block stay in the cache
    for first in range(0, len(w), _KKT_ROWS):
        rows = slice(first, first + _KKT_ROWS)
        wb = w[rows]
        # Products with masks rather than np.where: no branches on the frames' data.
        rel = g[rows] / np.maximum(scale[rows], np.finfo(float).tiny)
        stat = np.maximum(rel * (wb > near_lo), -rel * (wb < near_hi))
        if not feasible:
            feas = np.maximum(np.maximum(lo - wb, wb - hi), 0.0) / np.maximum(1.0, np.abs(wb))
            np.maximum(stat, feas, out=stat)
        out[rows] = stat.max(axis=1, initial=0.0)
    return out


#: Frames of :func:`kkt_residual` checked at a time (~0.4 MB a temporary for 53 weights).
_KKT_ROWS = 1024
#: :func:`kkt_residual`'s default `atol`.
_ATOL = 1e-12


def _near_bounds(lo, hi, atol):
    """Where a weight counts as at its bound: within `atol` · max(1, |bound|) of a finite
    bound, (n,) each; -inf and +inf for no bound (never)."""
    lo_f, hi_f = (np.where(np.isfinite(b), b, 0.0) for b in (lo, hi))
    return (np.where(np.isfinite(lo), lo_f + atol * np.maximum(1.0, np.abs(lo_f)), -np.inf),
            np.where(np.isfinite(hi), hi_f - atol * np.maximum(1.0, np.abs(hi_f)), np.inf))


def residual(qp: BoxQP, w: np.ndarray, c: np.ndarray, grad=None, *,
             feasible: bool = False) -> np.ndarray:
    """KKT residual of frames ``w`` (T, n) for linear terms ``c`` (T, n).

    ``grad``, the gradient ``G w − c``, is computed when not given;
    ``feasible`` as in :func:`kkt_residual`.
    """
    grad = gradient_of(qp, w, c) if grad is None else grad
    return kkt_residual(w, grad, _scale(qp, w, c), qp.lo, qp.hi, feasible=feasible)


def start_state(qp: BoxQP, c: np.ndarray, unconstrained=None) -> np.ndarray:
    """Active set of the unconstrained minimizer (given, or solved) clipped to the bounds.

    Only the clipped weights that the gradient there pushes outwards stay bound.
    """
    if unconstrained is None:
        unconstrained = reduced_solve(qp, np.zeros(c.shape, np.int8), c, gradient=False)[0]
    w = np.clip(unconstrained, qp.lo, qp.hi)
    g = gradient_of(qp, w, c)
    state = np.subtract((w >= qp.hi) & (g < 0), (w <= qp.lo) & (g > 0), dtype=np.int8)
    state[:, qp.fixed] = -1
    return state


def _pdas(qp, c, u, state, max_iter, tol, n_iter, kkt):
    """Primal-dual active-set iterations; returns weights and the converged mask.

    Every frame takes ``min(_PDAS_ITER, max_iter)`` of them, and one still
    converging with many variables to change more (see ``_PDAS_MANY``), up to
    ``min(_PDAS_MAX_ITER, max_iter)``. ``kkt`` (T,) gets the KKT residual of the
    frames that converge.
    """
    T = len(c)
    w = np.empty_like(c)
    done = np.zeros(T, bool)
    todo = np.arange(T)
    changed = np.full(T, qp.n + 1)      # variables each frame's last step changed
    every = min(_PDAS_ITER, max_iter)   # steps every frame takes
    for step in range(min(_PDAS_MAX_ITER, max_iter)):
        if len(todo) == T:  # views, no copies
            s, ct, ut = state, c, u
        else:
            s, ct, ut = state[todo], c[todo], _rows_of(u, todo)
        wt, g = reduced_solve(qp, s, ct, unconstrained=ut)
        n_iter[todo] += 1
        new = _next_state(qp, s, wt, g)
        changes = np.count_nonzero(new != s, axis=1)
        # Only a state that reproduces itself is optimal (up to accuracy).
        check = np.flatnonzero(changes == 0)
        res = np.full(len(todo), np.inf)
        # (a state that reproduces itself has free weights inside the bounds)
        res[check] = residual(qp, wt[check], ct[check], feasible=True)
        redo = check[res[check] > tol]
        if redo.size and qp.refinements:
            wt[redo], g[redo] = reduced_solve(qp, s[redo], ct[redo], refine=True,
                                              unconstrained=_rows_of(ut, redo))
            res[redo] = residual(qp, wt[redo], ct[redo], g[redo])
            new[redo] = _next_state(qp, s[redo], wt[redo], g[redo])
            changes[redo] = np.count_nonzero(new[redo] != s[redo], axis=1)
        ok = res <= tol
        kkt[todo[ok]] = res[ok]
        if len(todo) == T:
            w = wt
        else:
            w[todo] = wt
        state[todo[~ok]] = new[~ok]
        done[todo[ok]] = True
        keep = ~ok
        if step + 1 >= every:
            keep &= (changes >= _PDAS_MANY) & (changes < changed[todo])
        changed[todo] = changes
        todo = todo[keep]
        if not todo.size:
            break
    return w, done


@functools.cache
def _compiled_solve():
    """:func:`fit.solve._box_qp_kernel.solve_frames`, or None (NumPy iterates):
    :func:`mocap.util.optional.compiled`."""
    return compiled("fit.solve._box_qp_kernel", "solve_frames", what="box-QP iteration",
                    fallback="NumPy iterates over all frames at once, about 1.5 times slower")


def _next_state(qp, state, w, g):
    """The primal-dual step: bind the free weights outside the bounds, free the
    bound ones whose multiplier (gradient ``g``) has the wrong sign.

    Arithmetic on masks, no branches; bound weights are at their bound
    exactly, so only free ones can be outside.
    """
    new = np.subtract(w > qp.hi, w < qp.lo, dtype=np.int8)
    new += state * (state * g <= 0)
    new[:, qp.fixed] = -1
    return new


def _rows_of(u, rows):
    """``u[rows]``, or None when there is no ``u`` (singular G)."""
    return None if u is None else u[rows]


def _primal(qp, c, u, w, state, max_iter, tol, n_iter, kkt):
    """Monotone primal active-set iterations from feasible ``w``, ``state`` (both in place).

    Each iteration changes one variable of a frame's state (binds the one
    blocking the step, or frees one), so every other iteration updates the
    previous iteration's factored systems (:meth:`ReducedSystems.update`)
    instead of factoring anew. The working arrays hold the frames not yet
    converged; a frame's weights and state are written back when it
    converges or the iterations end.
    """
    done = np.zeros(len(c), bool)
    todo = np.arange(len(c))
    s, wt, ct, ut = state.copy(), w, c, u
    # the last factored systems, each working frame's row in them and the variable it
    # changed since (set by every iteration before the next one reads it)
    systems, rows, change = None, None, None
    for _ in range(max_iter):
        if systems is None:
            systems, rows = ReducedSystems(qp, s), np.arange(len(todo))
            target, lam = systems.solve(ct, unconstrained=ut)
        else:
            target, lam = _updated(qp, systems, rows, change, s, ct, ut)
            systems = None
        n_iter[todo] += 1
        # the variable each frame changes (n: none, -1: solved anew, refined)
        change = np.full(len(todo), qp.n)
        alpha = _step_to_first_bound(qp, wt, target, s, change)
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
        g = gradient_of(qp, wt[check], ct[check])
        res = np.full(len(todo), np.inf)
        res[check] = kkt_residual(wt[check], g, scale[~sure], qp.lo, qp.hi, feasible=True)
        ok = res <= tol
        worst_g, wrong_g = _worst_multiplier(qp, s[check], g, scale[~sure])
        failed = ~ok[check]
        release = failed & (wrong_g > 0)
        for frames, var in ((at[sure], worst[sure]), (check[release], worst_g[release])):
            s[frames, var] = 0
            change[frames] = var
        redo = check[failed & ~release]
        if redo.size and qp.refinements:
            wt[redo], grad = reduced_solve(qp, s[redo], ct[redo], refine=True,
                                           unconstrained=_rows_of(ut, redo))
            res[redo] = residual(qp, wt[redo], ct[redo], grad)
            ok[redo] = res[redo] <= tol
            wt[redo] = np.clip(wt[redo], qp.lo, qp.hi)
            change[redo] = -1
        w[todo[ok]], state[todo[ok]], kkt[todo[ok]] = wt[ok], s[ok], res[ok]
        done[todo[ok]] = True
        keep = ~ok
        todo, s, wt, ct, ut = todo[keep], s[keep], wt[keep], ct[keep], _rows_of(ut, keep)
        rows, change = rows[keep], change[keep]
        if not todo.size:
            break
    w[todo], state[todo] = wt, s
    return done


def _updated(qp, systems, rows, change, s, c, u):
    """Weights and gradient of the working frames' states ``s`` from ``systems``.

    ``rows`` are the frames' rows in ``systems``, ``change`` the variable
    each changed since (n: none, -1: to be solved anew). Frames that the
    systems cannot update are solved anew.
    """
    single = change >= 0
    var = np.full(len(systems.via_bound), qp.n)
    var[rows[single]] = change[single]
    now = np.zeros(len(var), np.int8)
    now[rows[single]] = s[single, np.minimum(change[single], qp.n - 1)]
    lam, updated = systems.update(var, now)
    new = np.flatnonzero(~updated[rows] | ~single)
    if new.size == len(rows):
        return reduced_solve(qp, s, c, unconstrained=u)
    lam = lam[rows]
    target = schur_weights(qp, s, lam, u)
    if new.size:
        target[new], lam[new] = reduced_solve(qp, s[new], c[new], unconstrained=_rows_of(u, new))
    return target, lam


def _step_to_first_bound(qp, w, target, state, change):
    """Step every frame from feasible ``w`` towards ``target`` up to the first bound
    in the way; binds the free variable that blocks it.

    ``target`` (T, n) becomes the new weights and ``state`` is updated, both
    in place, and ``change`` (T,) gets the bound variable.
    Only the free weights that ``target`` puts outside the box can block
    (bound weights are at their bound in both). Returns the step length,
    (T,), 1 where nothing blocks.
    """
    alpha = np.ones(len(w))
    flat = np.flatnonzero((target < qp.lo) | (target > qp.hi))
    if not flat.size:
        return alpha
    frames, var = np.divmod(flat, qp.n)
    to, frm = target[frames, var], w[frames, var]
    up = to > qp.hi[var]
    bound = np.where(up, qp.hi[var], qp.lo[var])
    ratio = np.maximum((bound - frm) / (to - frm), 0.0)
    first = np.flatnonzero(np.r_[True, frames[1:] != frames[:-1]])
    moving = frames[first]
    alpha[moving] = np.minimum.reduceat(ratio, first)
    part, start = target[moving], w[moving]
    part -= start
    part *= alpha[moving, None]
    part += start
    target[moving] = np.clip(part, qp.lo, qp.hi, out=part)
    # One variable per frame, the first that blocks (of ties, the lowest): the
    # others, at their bound now, block the next step (of length 0), which the
    # factored systems can take as an update.
    blocked = np.flatnonzero(ratio <= alpha[frames])
    blocked = blocked[np.r_[True, frames[blocked][1:] != frames[blocked][:-1]]]
    frames, var = frames[blocked], var[blocked]
    target[frames, var] = bound[blocked]
    state[frames, var] = np.where(up[blocked], 1, -1)
    change[frames] = var
    return alpha


def _scale(qp, w, c):
    """Magnitude of the terms summed into the gradient ``G w − c``, (T, n), at least
    the smallest positive float (a divisor)."""
    scale = dot(np.abs(w), np.abs(qp.G))
    scale += np.abs(c)
    return np.maximum(scale, np.finfo(float).tiny, out=scale)


def _worst_multiplier(qp, state, g, scale):
    """Each frame's most wrong-signed multiplier: (variable, violation relative to
    ``scale``, from :func:`_scale`).

    The multiplier of a bound variable is its gradient ``g``; its sign is
    wrong when it pulls the variable into the box. Fixed variables never count.
    """
    wrong = state * g
    wrong /= scale
    wrong[:, qp.fixed] = 0.0
    worst = wrong.argmax(axis=1)
    return worst, wrong[np.arange(len(worst)), worst]


def solve_box_qp(qp: BoxQP, c: np.ndarray, *, tol: float, max_iter: int,
                 warm_start: bool, state: np.ndarray | None = None):
    """Solve every frame's box QP; returns (weights, n_iter, kkt, converged).

    Every frame starts from `state` when given (int8 (T, n): -1 at the lower
    bound, +1 at the upper, 0 free; e.g. the active set of a nearby
    problem's solution), else, with ``warm_start``, from :func:`start_state`
    (the active set of its clipped unconstrained minimizer), else with every
    weight free (one more iteration). Frames go through in blocks of ``_BLOCK``, shared
    among the BLAS's threads (the same result on any number of them).
    """
    T = len(c)
    w, n_iter, kkt = np.empty_like(c), np.zeros(T, np.int64), np.empty(T)
    if np.isinf(qp.lo).all() and np.isinf(qp.hi).all():
        # no bound can ever be active: one product with G^-1 (G^+ when singular,
        # the minimum-norm minimizer) and its check, no iteration, by blocks on the threads
        inverse = qp.inverse if qp.inverse is not None else np.linalg.pinv(
            qp.G, rcond=RANK_RTOL, hermitian=True)

        def product_block(start):
            part = slice(start, start + _BLOCK)
            w[part] = dot(c[part], inverse)
            kkt[part] = residual(qp, w[part], c[part])
        map_on_blas_threads(product_block, range(0, T, _BLOCK))
        n_iter[:] = 1
        return w, n_iter, kkt, kkt <= tol

    def solve_block(start):
        part = slice(start, start + _BLOCK)
        cp = c[part]
        u = None if qp.inverse is None else dot(cp, qp.inverse)
        if state is not None:
            initial = state[part].copy()
        else:
            initial = start_state(qp, cp, u) if warm_start else np.zeros(cp.shape, np.int8)
        w[part], n_iter[part], kkt[part] = _solve_from(qp, cp, u, initial, tol, max_iter,
                                                       in_order=state is None)

    map_on_blas_threads(solve_block, range(0, T, _BLOCK))
    return w, n_iter, kkt, kkt <= tol


def _solve_from(qp, c, u, state, tol, max_iter, *, in_order: bool = False):
    """Both phases from an initial state (updated in place): compiled frame by frame
    when numba is installed and G is invertible, else by NumPy. Compiled, frames `in_order`
    (a take's, none given a start of its own) may start from the state the frame before
    ended in (:data:`_FOLLOW_TRIAL`): the same minimizer, other iterations.

    Returns the clipped weights, the iterations and the KKT residual of
    each frame: that of its converged weights (which the clip leaves alone),
    computed anew for the others.
    """
    kernel = _compiled_solve() if u is not None else None
    if kernel is None:
        w, n_iter, kkt = _iterate(qp, c, u, state, tol, max_iter)
    else:
        w, n_iter, kkt = _iterate_compiled(kernel, qp, c, u, state, tol, max_iter,
                                           _FOLLOW_TRIAL if in_order else 0)
    clipped = np.clip(w, qp.lo, qp.hi)
    again = np.flatnonzero((kkt > tol) | (clipped != w).any(axis=1))
    kkt[again] = residual(qp, clipped[again], c[again], feasible=True)
    return clipped, n_iter, kkt


def _iterate(qp, c, u, state, tol, max_iter):
    """Both phases by NumPy, all frames at once, from `state` (in place): the weights, the
    iterations and the KKT residual of the converged frames (inf for the others)."""
    n_iter, kkt = np.zeros(len(c), np.int64), np.full(len(c), np.inf)
    w, done = _pdas(qp, c, u, state, max_iter, tol, n_iter, kkt)
    rest = np.nonzero(~done)[0]
    if rest.size:
        # PDAS's next state binds the weights outside the box, which the clip
        # puts at that bound; the other bound weights are at their bound
        ws, ss = np.clip(w[rest], qp.lo, qp.hi), state[rest]
        it, res = np.zeros(rest.size, np.int64), np.full(rest.size, np.inf)
        _primal(qp, c[rest], _rows_of(u, rest), ws, ss, max_iter, tol, it, res)
        w[rest], state[rest], kkt[rest] = ws, ss, res
        n_iter[rest] += it
    return w, n_iter, kkt


def _iterate_compiled(kernel, qp, c, u, state, tol, max_iter, trial=0):
    """:func:`_iterate` by the compiled loop (:mod:`fit.solve._box_qp_kernel`), frame by
    frame; `trial` as the kernel's."""
    w, n_iter, kkt = np.empty_like(c), np.empty(len(c), np.int64), np.empty(len(c))
    lo_value, hi_value = qp.finite_bounds
    kernel(qp.G, qp.inverse, qp.lo, qp.hi, lo_value, hi_value,
           *_near_bounds(qp.lo, qp.hi, _ATOL), qp.fixed, c, u, state, max_iter,
           min(_PDAS_ITER, max_iter), min(_PDAS_MAX_ITER, max_iter), _PDAS_MANY, tol,
           qp.refinements, trial, w, n_iter, kkt)
    return w, n_iter, kkt
