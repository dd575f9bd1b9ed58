"""Reduced systems of the batched box QP: each frame's equations on its free weights.

Every frame ``t`` of :mod:`fit.solve._active_set` minimizes ``½ wᵀGw − c_tᵀw``
over ``lo ≤ w ≤ hi``, one symmetric positive semi-definite ``G`` (n × n)
for all frames. A frame's *state* (int8 per variable: -1 at the lower bound,
+1 at the upper bound, 0 free) fixes its bound set A and free set F; its
reduced system ``G_FF w_F = c_F − G_FA w_A`` gives the weights of that state.

No frame inverts an n × n matrix: G⁻¹ is computed once, and each frame
factors only an m × m system, m = min(|F|, |A|): directly, or (usually the
few bound weights) through the Schur complement of G⁻¹, whose solution λ
is the gradient on A. Frames of about the same m are factored together
(padded to the largest; LDLᵀ vectorized over frames, frames on the last
axis, the first right-hand side carried along). A factored system can then
take one change of its state (one variable bound or freed) by bordering
(:meth:`ReducedSystems.update`): no new factorization.

NumPy calls, not flops, bound the small systems: every column of a batch's
factorization or solve costs a few calls whatever its frames, so batches are
big and the (T, n) work avoids passes and copies (products with masks, slices
as views, in-place updates).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

#: Most frames factored together.
_CHUNK = 2048
#: Fewest frames of a batch whose size is padded up to the next batch's. Each
#: column of a batch's factorization costs a few NumPy calls whatever its
#: frames, and a call costs as much as ~10,000 flops: few, big batches beat
#: tight padding.
_MIN_BATCH = 512
#: ... but when G is singular, a pseudo-inverse (SVD) per frame costs m³ flops
#: whatever the batch: there padding is what costs.
_MIN_BATCH_SINGULAR = 64
#: Rows of the products with G and G⁻¹ (see :func:`dot`): a block of rows and
#: its result stay in the core's cache, and each call's overhead is paid once
#: per block, not per row.
_DOT_ROWS = 256
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

    @property
    def refinements(self) -> int:
        """Refinement steps that bring a reduced solve to full accuracy."""
        return 0 if self.cond <= _REFINE_COND else 1 if self.cond <= _REFINE_COND ** 2 else 2

    @cached_property
    def finite_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) with infinite bounds replaced by 0."""
        return (np.where(np.isfinite(self.lo), self.lo, 0.0),
                np.where(np.isfinite(self.hi), self.hi, 0.0))

    def state_of(self, weights: np.ndarray) -> np.ndarray:
        """The active set of `weights` (T, n): int8, -1 at (or below) the lower bound,
        +1 at (or above) the upper one, 0 between; fixed weights -1."""
        state = np.subtract(weights >= self.hi, weights <= self.lo, dtype=np.int8)
        state[:, self.fixed] = -1
        return state

    def bound_values(self, state: np.ndarray) -> np.ndarray:
        """Bound values where ``state`` is ±1, 0 where free, shape of ``state``."""
        lo, hi = self.finite_bounds
        # a bound at zero contributes nothing: its product (a (T, n) pass) is skipped
        out = hi * (state > 0) if hi.any() else np.zeros(state.shape)
        if lo.any():
            out += lo * (state < 0)
        return out


@dataclass
class _Batch:
    """Frames factored together: their rows (1, r) of the system, the indices
    sel (m, r) of each frame's smaller set (padded with n), their flat entries
    of a (T, n + 1) array, the gathered systems, and once solved their solver
    and last solution (m, r)."""

    rows: np.ndarray
    schur: bool
    sel: np.ndarray
    flat: np.ndarray
    #: the gathered systems (m + 1, m, r), factored in place by the first solve
    mats: np.ndarray
    solve: object = None
    x: np.ndarray | None = None


class ReducedSystems:
    """Every frame's reduced system for one state (T, n), factored by the first solve.

    Each frame solves ``G_FF w_F = c_F − G_FA w_A`` through the smaller of its
    free set F and bound set A: directly (|F| × |F|), or, when G is invertible
    and fewer variables are bound, through the Schur complement of G⁻¹:
    ``w = u + G⁻¹λ`` with ``(G⁻¹)_AA λ_A = w_A − u_A``, u = G⁻¹c the
    unconstrained minimizer, an |A| × |A| system; λ (zero off A) is the
    gradient ``G w − c``. Frames are sorted by that size and factored in batches.
    """

    def __init__(self, qp: BoxQP, state: np.ndarray):
        # a copy: the caller's state moves on, the factors stay with this one
        self.qp, self.state = qp, state.copy()
        self.free = free = state == 0
        n_free = np.count_nonzero(free, axis=1)
        self.via_bound = (2 * n_free > qp.n) & (qp.inverse is not None)
        size = np.where(self.via_bound, qp.n - n_free, n_free)
        self.batches = [
            _Batch(rows, bound, sel, rows * (qp.n + 1) + sel,
                   _principal(qp.inverse if bound else qp.G, sel, lower=not qp.singular))
            for rows, bound, sel in _batches(
                free, self.via_bound, size,
                _MIN_BATCH_SINGULAR if qp.singular else _MIN_BATCH)]
        # frames in a factored batch (not those with nothing to factor, m = 0)
        self.factored = np.zeros(len(state), bool)
        for batch in self.batches:
            self.factored[batch.rows[0]] = True
        self.unconstrained = None

    def solve(self, c: np.ndarray, *, unconstrained=None, refine: bool = False,
              gradient: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Weights with bound variables at their bounds and free ones stationary.

        ``c`` (T, n) the frames' linear terms, ``unconstrained`` G⁻¹c
        (computed if not given). With ``refine``, ill-conditioned problems get
        more passes (iterative refinement: each corrects ``w`` by the reduced
        solve of its residual).

        Returns
        -------
        w : ndarray, shape (T, n)
            The weights, exactly at their bounds on A.
        grad : ndarray, shape (T, n), or None
            The gradient ``G w − c``: after refinement, the product itself; else
            λ on the Schur path (zero on F, equal in exact arithmetic) and, on
            the direct path, the product if ``gradient`` (else None).
        """
        qp, via_bound, free = self.qp, self.via_bound, self.free
        w = qp.bound_values(self.state)
        # Frames of each path, as a slice when they are all of them (views, no copies).
        schur = slice(None) if via_bound.all() else np.flatnonzero(via_bound)
        direct = slice(None) if not via_bound.any() else np.flatnonzero(~via_bound)
        on_schur, on_direct = via_bound.any(), not via_bound.all()
        rhs = np.zeros((len(c), qp.n + 1))
        if on_schur:
            if unconstrained is None:
                unconstrained = np.zeros_like(c)
                unconstrained[schur] = dot(c[schur], qp.inverse)
            self.unconstrained = unconstrained
            base = unconstrained[schur]
            rhs[schur, :-1] = w[schur] - base
        if on_direct:
            rhs[direct, :-1] = c[direct] - dot(w[direct], qp.G)
        lam = None  # the sum of the passes' coefficients (λ on the Schur path)
        passes = qp.refinements if refine else 0
        for left in range(passes, -1, -1):
            coef = np.zeros_like(rhs)
            for batch in self.batches:
                if batch.solve is None:
                    batch.mats[-1] = rhs.take(batch.flat)
                    batch.solve, batch.x = _factor(qp, batch.mats)
                else:
                    batch.x = batch.solve(rhs.take(batch.flat))
                np.put(coef, batch.flat, batch.x)
            coef = coef[:, :-1]
            lam = coef if lam is None else lam + coef
            if on_schur:
                w[schur] += _free_part(qp, coef[schur], base, free[schur])
            if on_direct:
                w[direct] += coef[direct]
            if not left:
                break
            # the next pass solves for the correction from the residual -grad
            grad = gradient_of(qp, w, c)
            if on_schur:
                base = -dot(grad[schur], qp.inverse)
                rhs[schur, :-1] = -base
            if on_direct:
                rhs[direct, :-1] = -grad[direct]
        if passes:
            # the batches' solutions are corrections now: no update from them
            self.unconstrained = None
            return w, gradient_of(qp, w, c)
        if not on_direct:
            return w, lam
        if not gradient:
            return w, None
        # (lam holds the direct frames' free weights: overwritten)
        lam[direct] = gradient_of(qp, w[direct], c[direct])
        return w, lam

    def update(self, var: np.ndarray, now: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """λ after one change of state per frame, from the factors of :meth:`solve`.

        ``var`` (T,) is each frame's changed variable (n: none), ``now`` (T,)
        its new state (-1, +1 bound, 0 freed). Only frames solved (unrefined)
        through the Schur complement of a factored system (one variable bound
        at least) can be updated; for them, binding
        variable j borders the system with ``h = (G⁻¹)_Aj``: with
        ``v = (G⁻¹)_AA⁻¹ h``, ``λ_j = (r_j − hᵀλ_A) / ((G⁻¹)_jj − hᵀv)`` and
        ``λ_A −= v λ_j`` (r = w_A − u_A); freeing p (at slot e) is the same with
        ``h = e`` and zero for ``r_p`` and ``(G⁻¹)_pp``: λ_p becomes 0. The
        weights follow with :func:`schur_weights`.

        Returns
        -------
        lam : ndarray, shape (T, n)
            λ of the new states, on the rows where ``updated``.
        updated : ndarray of bool, shape (T,)
            The frames that could be updated.
        """
        qp, n = self.qp, self.qp.n
        updated = self.via_bound & self.factored & (self.unconstrained is not None)
        lam = np.zeros((len(var), n + 1))
        if not updated.any():
            return lam[:, :-1], updated
        ext = np.zeros((n + 1, n + 1))
        ext[:n, :n] = qp.inverse
        ext_diag = np.r_[np.diag(qp.inverse), 0.0]
        lo, hi = qp.finite_bounds
        for batch in self.batches:
            if not batch.schur:
                continue
            rows = batch.rows[0]
            j, side = var[rows], now[rows]
            changed = j < n
            add = changed & (side != 0)
            # column of G⁻¹ (bound variable) or the freed variable's slot
            freed = batch.sel == np.where(changed & ~add, j, -1)
            h = np.where(add, ext.ravel().take(batch.sel * (n + 1) + np.where(add, j, n)), freed)
            v = batch.solve(h)
            k = np.minimum(j, n - 1)
            rho = np.where(add, np.where(side > 0, hi[k], lo[k]) - self.unconstrained[rows, k],
                           0.0)
            denom = np.where(add, ext_diag[j], 0.0) - np.einsum("it,it->t", h, v)
            y = (rho - np.einsum("it,it->t", h, batch.x)) / np.where(changed, denom, 1.0)
            x = batch.x - v * y
            x *= ~freed  # a freed variable's λ is exactly 0
            np.put(lam, batch.flat, x)
            lam[rows[add], j[add]] = y[add]
        return lam[:, :-1], updated


def schur_weights(qp: BoxQP, state, lam, unconstrained) -> np.ndarray:
    """Weights ``u + G⁻¹λ`` of the free variables, bound values of the others, (T, n)."""
    w = qp.bound_values(state)
    w += _free_part(qp, lam, unconstrained, state == 0)
    return w


def _free_part(qp, lam, base, free):
    """Free weights ``base + G⁻¹λ`` (zero on the bound ones), (T, n)."""
    step = dot(lam, qp.inverse)
    step += base
    step *= free
    return step


def reduced_solve(qp: BoxQP, state: np.ndarray, c: np.ndarray, *, unconstrained=None,
                  refine: bool = False,
                  gradient: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """:meth:`ReducedSystems.solve` of the systems of ``state`` (T, n)."""
    return ReducedSystems(qp, state).solve(c, unconstrained=unconstrained, refine=refine,
                                           gradient=gradient)


def dot(a, mat):
    """``a @ mat`` for (T, n) ``a``, as products of ``_DOT_ROWS`` rows.

    Products that small stay single-threaded in BLAS: on a machine whose cores
    are busy, threaded products of skinny matrices mostly wait.
    """
    out = np.empty((len(a), mat.shape[1]))
    # one product per slice, written in place: a stacked (T / rows, rows, n)
    # matmul would copy its result
    for first in range(0, len(a), _DOT_ROWS):
        np.matmul(a[first:first + _DOT_ROWS], mat, out=out[first:first + _DOT_ROWS])
    return out


def gradient_of(qp: BoxQP, w, c) -> np.ndarray:
    """``G w − c`` (T, n), in one new array."""
    g = dot(w, qp.G)
    g -= c
    return g


def _batches(free, via_bound, size, min_batch):
    """Batches (frames, via_bound, sel) of frames solved together.

    Frames sorted by path and size; a batch holds up to ``_CHUNK`` frames,
    and fewer than ``min_batch`` frames of one size join (padded up) the
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
        if end - start < min_batch and end < len(order) and \
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
    n = mask.shape[1]
    out = np.full((len(mask), max(int(count.max(initial=0)), 1)), n, np.intp)
    # row by row, each row's entries in order (2.4x np.nonzero's speed)
    rows, cols = np.divmod(np.flatnonzero(mask), n)
    out[rows, np.arange(len(rows)) - np.repeat(np.cumsum(count) - count, count)] = cols
    return out


def _principal(mat, sel, *, lower: bool = False):
    """Principal submatrices ``mat[sel, sel]`` for ``sel`` (m, frames), as rows
    0..m-1 of an (m + 1, m, frames) array whose last row (unset) is for a
    right-hand side (see :func:`_factor`).

    Index n (the padding) selects a row and column of the identity. With
    ``lower``, only the lower triangle is gathered (the upper one is left
    unset: half the gather, for :func:`_factor`, which reads no more).
    """
    n, m = len(mat), len(sel)
    ext = np.zeros((n + 1, n + 1))
    ext[:n, :n] = mat
    flat, starts = ext.ravel(), sel * (n + 1)
    out = np.empty((m + 1, m, sel.shape[1]))
    # row by row, each one gather into its place: the (entries, frames) index array of
    # all rows at once costs several times the gather itself
    for k in range(m):
        cols = sel[:k + 1] if lower else sel
        np.take(flat, starts[k] + cols, out=out[k, :len(cols)], mode="clip")
    diag = np.arange(m)
    out[diag, diag] += sel == n
    return out


def _factor(qp, mats):
    """Factor the batch ``mats`` (m + 1, m, frames) in place: systems in rows
    0..m-1, a right-hand side in row m (one per frame).

    Returns the solver ``rhs (m, frames) -> systems⁻¹ rhs`` and the solution for
    row m. LDLᵀ factorization without pivoting (the matrices are symmetric
    positive definite), by columns from the lower triangle only (Crout: one
    product per column, half the work of elimination), vectorized over frames.
    The lower triangle keeps L D, not L (no pass dividing each column by its
    pivot; each row of L is formed when its column is, a j-vector), and row m
    rides along as one more row of L D, which makes it L⁻¹ b: the forward
    substitution for free. A pseudo-inverse when G is singular.
    """
    m = mats.shape[1]
    if qp.singular:
        top = np.linalg.eigvalsh(qp.G)[-1]
        pinv = np.linalg.pinv(mats[:m].transpose(2, 0, 1),
                              rcond=RANK_RTOL * top / max(top, 1.0), hermitian=True)

        def pseudo(rhs):
            return np.einsum("tij,jt->it", pinv, rhs)
        return pseudo, pseudo(mats[m])
    inv = np.empty(mats.shape[1:])  # 1 / D
    for j in range(m):
        if j:
            # column j of L D from the diagonal down (and of the rhs row), in one product
            mats[j:, j] -= np.einsum("ikt,kt->it", mats[j:, :j], mats[j, :j] * inv[:j])
        inv[j] = 1.0 / mats[j, j]
    ld = mats[:m]

    def back(y):
        """(D Lᵀ)⁻¹ y = ((L D)ᵀ)⁻¹ y, in place."""
        y[m - 1] *= inv[m - 1]
        for k in range(m - 2, -1, -1):
            y[k] -= np.einsum("jt,jt->t", ld[k + 1:, k], y[k + 1:])
            y[k] *= inv[k]
        return y

    def solve(rhs):
        x = rhs.copy()
        for k in range(m - 1):
            x[k + 1:] -= ld[k + 1:, k] * (x[k] * inv[k])
        return back(x)
    return solve, back(mats[m].copy())


