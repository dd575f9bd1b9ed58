"""The box QP's two phases as one compiled loop over frames (numba, the ``speed`` extra).

:func:`fit.solve._active_set._solve_from` takes each iteration for all frames at once:
some fifty NumPy calls an iteration (batches of frames by the size of their reduced
system, principal submatrices gathered, an LDLᵀ factorization vectorized over frames, the
KKT checks), each a pass over (frames, n) arrays, and the monotone phase's frames, few
but many iterations each, pay those calls at every iteration. Here each frame takes its
iterations on its own, its arrays in the core's cache: from the same start, the same
iterations (the same reduced systems, steps, next states, checks and stopping rules),
each reduced system factored anew by Cholesky (no bordering). The weights are the same
to rounding, not to the bit (other summation orders, another factorization). Going frame
by frame, a frame can also start from the state the frame before ended in (``trial``).

For an invertible G (its principal submatrices, and those of G⁻¹, are positive
definite: Cholesky factors them without pivoting, as the NumPy path's LDLᵀ does). A
reduced solve gets iterative refinement where the NumPy path's does (an optimal state
whose KKT residual misses the tolerance, G ill-conditioned), from its own factor.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["solve_frames"]


@numba.njit(cache=True, nogil=True)
def solve_frames(G, inverse, lo, hi, lo_value, hi_value, near_lo, near_hi, fixed, c, u,
                 state, max_iter, every, most, many, tol, refinements, trial, w, n_iter,
                 kkt):  # pragma: no cover - compiled; tested against the NumPy iterations
    """Both phases of :func:`fit.solve._active_set._solve_from` for every frame, from its
    `state` (T, n) (in place).

    Parameters
    ----------
    G, inverse : ndarray of shape (n, n)
        G and G⁻¹.
    lo, hi : ndarray of shape (n,)
        The bounds (infinite where there is none); `lo_value`, `hi_value` the same with
        0 for an infinite bound (the value a bound variable takes).
    near_lo, near_hi : ndarray of shape (n,)
        Within these a weight counts as at its bound (-inf, +inf for no bound).
    fixed : ndarray of bool, shape (n,)
        Variables with ``lo == hi``: always at their (lower) bound.
    c, u : ndarray of shape (T, n)
        The linear terms and the unconstrained minimizers G⁻¹c.
    max_iter : int
        Most iterations of the monotone phase.
    every, most, many : int
        The primal-dual phase's rules (``_pdas``): steps every frame takes; most steps;
        fewest changes of a frame's last step for it to go on after `every` (and fewer
        than its step before).
    tol : float
        KKT tolerance.
    refinements : int
        Refinement passes of a reduced solve whose state is optimal but whose KKT
        residual misses `tol` (:attr:`fit.solve._reduced.BoxQP.refinements`).
    trial : int
        With frames in time order: frames 1 .. 2·`trial` start in turn from their own
        state and from the state the frame before ended in, and the other frames from
        the one of the two that took fewer iterations (0: each from its own).
    w, n_iter, kkt : ndarray of shape (T, n), (T,), (T,)
        Out: the weights (not clipped), iterations, and KKT residual of the converged
        frames (inf for the others).
    """
    n_frames, n = c.shape
    abs_G = np.abs(G)
    # scratch of the reduced solves: free and bound variables, system, right-hand side
    free, bound, mat, rhs = np.empty(n, np.int64), np.empty(n, np.int64), np.empty((n, n)), \
        np.empty(n)
    wt, target, g, scale = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    new = np.empty(n, np.int8)
    followed = False                    # this frame starts where the one before ended
    own = theirs = 0                    # iterations of the trial frames from each start
    for t in range(n_frames):
        s, ct, ut = state[t], c[t], u[t]
        if trial > 0 and t > 0:
            if 1 <= t - 1 <= 2 * trial:
                if followed:
                    theirs += n_iter[t - 1]
                else:
                    own += n_iter[t - 1]
            followed = t % 2 == 0 if t <= 2 * trial else theirs < own
            if followed:
                s[:] = state[t - 1]
        n_iter[t], kkt[t] = 0, np.inf
        # the primal-dual phase
        changed = n + 1
        converged = False
        for step in range(most):
            path = _reduced_solve(G, inverse, lo_value, hi_value, ct, ut, s, wt, g, free,
                                  bound, mat, rhs)
            n_iter[t] += 1
            changes = _next_state(lo, hi, fixed, s, wt, g, new)
            residual = np.inf
            if changes == 0:            # a state that reproduces itself: optimal?
                _scale(abs_G, ct, wt, scale)
                if path == 1:           # λ is the gradient on A only
                    _gradient(G, ct, wt, g)
                residual = _kkt_residual(g, wt, scale, lo, hi, near_lo, near_hi, True)
                if residual > tol and refinements:
                    _refine(G, inverse, ct, s, wt, g, path, refinements, free, bound, mat,
                            rhs, target)
                    _scale(abs_G, ct, wt, scale)
                    residual = _kkt_residual(g, wt, scale, lo, hi, near_lo, near_hi, False)
                    changes = _next_state(lo, hi, fixed, s, wt, g, new)
            if residual <= tol:
                kkt[t] = residual
                converged = True
                break
            s[:] = new
            if step + 1 >= every and not (changes >= many and changes < changed):
                break
            changed = changes
        if converged:
            w[t] = wt
            continue
        # the monotone primal phase, from the clipped weights of the last solve: its next
        # state binds the weights outside the box, which the clip puts at that bound
        for j in range(n):
            wt[j] = min(max(wt[j], lo[j]), hi[j])
        for _ in range(max_iter):
            path = _reduced_solve(G, inverse, lo_value, hi_value, ct, ut, s, target, g, free,
                                  bound, mat, rhs)
            n_iter[t] += 1
            if _step_to_first_bound(lo, hi, s, wt, target):
                continue
            # at the subproblem's optimum: optimal, or free the worst wrong-signed
            # multiplier, or (none) refine the solve
            _scale(abs_G, ct, wt, scale)
            worst, wrong = _worst_multiplier(fixed, s, g, scale)
            if wrong > tol:             # clearly wrong-signed: freed unchecked
                s[worst] = 0
                continue
            if path == 1:
                _gradient(G, ct, wt, g)
            residual = _kkt_residual(g, wt, scale, lo, hi, near_lo, near_hi, True)
            if residual <= tol:
                kkt[t] = residual
                break
            worst, wrong = _worst_multiplier(fixed, s, g, scale)
            if wrong > 0:
                s[worst] = 0
                continue
            if refinements:
                _refine(G, inverse, ct, s, wt, g, path, refinements, free, bound, mat, rhs,
                        target)
                _scale(abs_G, ct, wt, scale)
                residual = _kkt_residual(g, wt, scale, lo, hi, near_lo, near_hi, False)
                for j in range(n):
                    wt[j] = min(max(wt[j], lo[j]), hi[j])
                if residual <= tol:
                    kkt[t] = residual
                    break
        w[t] = wt


@numba.njit(cache=True, nogil=True)
def _reduced_solve(G, inverse, lo_value, hi_value, c, u, s, w, g, free, bound, mat,
                   rhs):  # pragma: no cover - compiled
    """Weights `w` (n,) of state `s`: bound variables at their bound, free ones from
    ``G_FF w_F = c_F − G_FA w_A``, through the smaller of F and A as
    :class:`fit.solve._reduced.ReducedSystems` does. Returns 1 on the Schur path (`g`
    gets λ, the gradient ``G w − c`` on A, 0 on F), 2 on the direct one (`g` gets the
    gradient ``G w − c``). `free`, `bound`, `rhs` are scratch; `mat` keeps the reduced
    system's factor (for :func:`_refine`).

    Products are sums of rows of G or G⁻¹ (symmetric) scaled by one number each: the
    rows are contiguous and their sums independent, where dot products would each be one
    chain of dependent additions.
    """
    n = len(s)
    n_free, n_bound = _split(s, free, bound)
    for j in range(n):
        w[j] = 0.0 if s[j] == 0 else hi_value[j] if s[j] > 0 else lo_value[j]
    if 2 * n_free > n:
        # the Schur complement of G⁻¹: (G⁻¹)_AA λ_A = w_A − u_A, w = u + G⁻¹λ
        for a in range(n_bound):
            for b in range(a + 1):
                mat[a, b] = inverse[bound[a], bound[b]]
            rhs[a] = w[bound[a]] - u[bound[a]]
        _factor(mat, n_bound)
        _solve_factored(mat, rhs, n_bound)
        g[:] = u
        for a in range(n_bound):
            row, lam = inverse[bound[a]], rhs[a]
            for j in range(n):
                g[j] += row[j] * lam
        for f in range(n_free):
            w[free[f]] = g[free[f]]
        g[:] = 0.0
        for a in range(n_bound):
            g[bound[a]] = rhs[a]
        return 1
    # directly: G_FF w_F = c_F − G_FA w_A (the weights bound at 0 add nothing), then the
    # gradient G w − c
    g[:] = c
    for b in range(n_bound):
        row, value = G[bound[b]], w[bound[b]]
        if value != 0.0:
            for j in range(n):
                g[j] -= row[j] * value
    for a in range(n_free):
        for b in range(a + 1):
            mat[a, b] = G[free[a], free[b]]
        rhs[a] = g[free[a]]
    _factor(mat, n_free)
    _solve_factored(mat, rhs, n_free)
    for a in range(n_free):
        w[free[a]] = rhs[a]
    _gradient(G, c, w, g)
    return 2


@numba.njit(cache=True, nogil=True)
def _split(s, free, bound):  # pragma: no cover - compiled
    """The free and the bound variables of state `s`, in order, into `free` and `bound`;
    returns how many of each."""
    n_free = n_bound = 0
    for j in range(len(s)):
        if s[j] == 0:
            free[n_free] = j
            n_free += 1
        else:
            bound[n_bound] = j
            n_bound += 1
    return n_free, n_bound


@numba.njit(cache=True, nogil=True)
def _refine(G, inverse, c, s, w, g, path, passes, free, bound, mat, rhs,
            base):  # pragma: no cover - compiled
    """Iterative refinement of the solve of state `s` that :func:`_reduced_solve` just
    made (its `path`, its factor in `mat`), as ``ReducedSystems.solve(refine=True)``:
    `passes` times, the reduced solve of the residual −(G w − c) corrects the free
    weights `w`; `g` gets the gradient ``G w − c`` of the result. `base` is scratch."""
    n = len(s)
    n_free, n_bound = _split(s, free, bound)
    for _ in range(passes):
        _gradient(G, c, w, g)
        if path == 1:
            # base = −G⁻¹ grad; (G⁻¹)_AA δλ = −base_A; w_F += (G⁻¹ δλ + base)_F
            base[:] = 0.0
            for k in range(n):
                row, value = inverse[k], g[k]
                for j in range(n):
                    base[j] -= row[j] * value
            for a in range(n_bound):
                rhs[a] = -base[bound[a]]
            _solve_factored(mat, rhs, n_bound)
            for a in range(n_bound):
                row, value = inverse[bound[a]], rhs[a]
                for j in range(n):
                    base[j] += row[j] * value
            for f in range(n_free):
                w[free[f]] += base[free[f]]
        else:
            for a in range(n_free):
                rhs[a] = -g[free[a]]
            _solve_factored(mat, rhs, n_free)
            for a in range(n_free):
                w[free[a]] += rhs[a]
    _gradient(G, c, w, g)


@numba.njit(cache=True, nogil=True)
def _factor(mat, m):  # pragma: no cover - compiled
    """Cholesky ``LLᵀ`` of ``mat[:m, :m]`` in place, from its lower triangle: L below the
    diagonal, the reciprocals of L's diagonal on it (a pivot that is not positive gives
    NaN or inf, and the frame's KKT check fails). Row by row of L, each entry one dot
    product of two contiguous rows of L and one product by a reciprocal, rather than
    updates of the rows below each new row: for the reduced systems' size (m ≤ n / 2, the
    smaller of the free and the bound set) those updates are short, and a division costs
    more than a product."""
    for i in range(m):
        for j in range(i):
            value = mat[i, j]
            for k in range(j):
                value -= mat[i, k] * mat[j, k]
            mat[i, j] = value * mat[j, j]
        value = mat[i, i]
        for k in range(i):
            value -= mat[i, k] * mat[i, k]
        mat[i, i] = 1.0 / np.sqrt(value)


@numba.njit(cache=True, nogil=True)
def _solve_factored(mat, rhs, m):  # pragma: no cover - compiled
    """``rhs[:m]`` ← ``(LLᵀ)⁻¹ rhs[:m]`` with L from :func:`_factor`, along L's rows."""
    for i in range(m):                      # L y = b
        value = rhs[i]
        for k in range(i):
            value -= mat[i, k] * rhs[k]
        rhs[i] = value * mat[i, i]
    for i in range(m - 1, -1, -1):          # Lᵀ x = y
        value = rhs[i] * mat[i, i]
        rhs[i] = value
        for k in range(i):
            rhs[k] -= mat[i, k] * value


@numba.njit(cache=True, nogil=True)
def _next_state(lo, hi, fixed, s, w, g, new):  # pragma: no cover - compiled
    """``_active_set._next_state`` of one frame into `new`; returns how many variables it
    changes."""
    changes = 0
    for j in range(len(s)):
        side = np.int8((w[j] > hi[j]) - (w[j] < lo[j]))
        if s[j] != 0 and not s[j] * g[j] > 0:
            side += s[j]
        if fixed[j]:
            side = -1
        new[j] = side
        changes += side != s[j]
    return changes


@numba.njit(cache=True, nogil=True)
def _step_to_first_bound(lo, hi, s, w, target):  # pragma: no cover - compiled
    """``_active_set._step_to_first_bound`` of one frame: `w` steps towards `target` up
    to the first free variable whose bound is in the way (of ties, the lowest), which is
    bound in `s`; True if one was (False: `w` is `target`)."""
    n = len(s)
    alpha = 1.0
    for j in range(n):
        if target[j] < lo[j] or target[j] > hi[j]:
            edge = hi[j] if target[j] > hi[j] else lo[j]
            alpha = min(alpha, max((edge - w[j]) / (target[j] - w[j]), 0.0))
    if alpha >= 1.0:
        w[:] = target
        return False
    blocked = -1
    for j in range(n):
        if target[j] < lo[j] or target[j] > hi[j]:
            edge = hi[j] if target[j] > hi[j] else lo[j]
            if blocked < 0 and max((edge - w[j]) / (target[j] - w[j]), 0.0) <= alpha:
                blocked = j
                s[j] = 1 if target[j] > hi[j] else -1
    for j in range(n):
        w[j] = min(max((target[j] - w[j]) * alpha + w[j], lo[j]), hi[j])
    w[blocked] = hi[blocked] if s[blocked] > 0 else lo[blocked]
    return True


@numba.njit(cache=True, nogil=True)
def _gradient(G, c, w, g):  # pragma: no cover - compiled
    """``G w − c`` of one frame into `g`, as a sum of the rows of G (symmetric) of the
    nonzero weights."""
    g[:] = -c
    for k in range(len(w)):
        if w[k] != 0.0:
            row, weight = G[k], w[k]
            for j in range(len(w)):
                g[j] += row[j] * weight


@numba.njit(cache=True, nogil=True)
def _scale(abs_G, c, w, out):  # pragma: no cover - compiled
    """``_active_set._scale`` of one frame into `out`: ``|w| |G| + |c|``, at least the
    smallest positive float."""
    n = len(w)
    for j in range(n):
        out[j] = abs(c[j])
    for k in range(n):
        if w[k] != 0.0:
            row, weight = abs_G[k], abs(w[k])
            for j in range(n):
                out[j] += row[j] * weight
    tiny = np.finfo(np.float64).tiny
    for j in range(n):
        out[j] = max(out[j], tiny)


@numba.njit(cache=True, nogil=True)
def _kkt_residual(g, w, scale, lo, hi, near_lo, near_hi,
                  feasible):  # pragma: no cover - compiled
    """``_active_set.kkt_residual`` of one frame `w`, its exact gradient `g`; `feasible`
    says `w` is within the bounds (no feasibility term). Infinite where the gradient is
    not finite."""
    out = 0.0
    for j in range(len(w)):
        if not np.isfinite(g[j]):
            return np.inf
        rel = g[j] / scale[j]
        if w[j] > near_lo[j]:
            out = max(out, rel)
        if w[j] < near_hi[j]:
            out = max(out, -rel)
        if not feasible:
            out = max(out, max(lo[j] - w[j], w[j] - hi[j]) / max(1.0, abs(w[j])))
    return out


@numba.njit(cache=True, nogil=True)
def _worst_multiplier(fixed, s, g, scale):  # pragma: no cover - compiled
    """``_active_set._worst_multiplier`` of one frame: (variable, violation)."""
    worst, wrong = 0, -np.inf
    for j in range(len(s)):
        value = 0.0 if fixed[j] else s[j] * g[j] / scale[j]
        if value > wrong:
            worst, wrong = j, value
    return worst, wrong
