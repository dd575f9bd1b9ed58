"""Numerics of the temporally smooth weight solve behind :func:`fit.solve.temporal.solve_smooth`.

The sequence problem ``min Σ_t ½ w_tᵀG w_t − c_tᵀw_t + ½ λ Σ_t ‖w_t − w_{t−1}‖²``
has the Hessian ``I_T ⊗ G + λ L ⊗ I_n`` (L the path-graph Laplacian).

Unbounded, it diagonalizes exactly (:class:`Spectrum`: the DCT-II over frames
times the eigenvectors of G). In a box, a primal-dual active-set iteration
over the whole sequence: each step solves the reduced system of one state
(int8 per weight: -1 at the lower bound, +1 at the upper, 0 free) as one
banded positive-definite system of the free weights (bandwidth at most n, the
bound weights at their bound). Two things keep the number of those global solves
small:

- the start is the active set of a rough solution of the bounded problem by
  ``_ADMM_ITER`` steps of ADMM (the splitting w = z, z in the box), whose
  w-step is the unbounded solve of :class:`Spectrum` with Λ + λμ + ρ: a few
  products per step, no factorization, cheaper than the global steps it
  saves;
- once the state changes only in a few places, every change is first settled
  locally: frames within ``_WINDOW`` frames of a change iterate on their own
  (each window's reduced system, its neighbours outside held fixed: a small
  banded solve over the windows only) until their state stops changing, and
  only then does the whole sequence get solved again. Changes travel from
  frame to frame, one global step per frame without this.

The global steps grow with λ for a whole-sequence iteration from the
frames' own optima (changes travel one frame a step); the local phase keeps
them nearly flat (``bench/bench_smooth.py`` counts both). The last global
steps change only a few weights' freedom: a state at most ``_LOW_RANK_MAX``
variables from the factored one is solved through that factor (a low-rank
correction, :class:`_WholeFactor`) instead of factoring the whole sequence anew.

Only the global solve of a state decides convergence: the KKT conditions of
every frame of the whole sequence objective, to ``tol``. The local phase only
proposes the next state.

The linear terms may move while the iteration runs (``bounded(..., follow=)``):
the chord steps of the exact marker-centre fit change them after every global
solve, so that the steps and the active-set iteration converge together
instead of one full iteration per step. The whole sequence's factor is kept
while the state stays near it, so a step that keeps the state costs two
triangular solves; a new state's factor, or the columns that border the kept
one for a state near it, form on another thread while `follow` works
(neither the factorization nor the solves hold the GIL), since the state, not
the terms, decides them. The factor's buffer itself is allocated, and its pages
first touched, on such a thread while the ADMM start is computed.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import scipy.linalg

from fit.solve._active_set import RANK_RTOL, BoxQP, kkt_residual
from fit.solve._banded_cholesky import cho_solve_banded_upper, cholesky_banded_upper
from mocap.util.blas import run_beside, worker_threads
from mocap.util.optional import compiled

#: Frames either side of a state change that settle it locally.
_WINDOW = 3
#: The local phase runs only while the frames it involves are fewer than this
#: share of the take (else one global step costs less than the windows' steps).
_LOCAL_SHARE = 0.6
#: Local steps per local phase, at most.
_LOCAL_ITER = 30
#: ADMM steps of the start, and their over-relaxation α (the w-step's point enters the
#: z- and u-steps as α w + (1 − α) z; Boyd et al. 2011, §3.4.3, suggest 1.5-1.8): 25
#: relaxed steps give the active set 50 plain ones give.
_ADMM_ITER, _ADMM_RELAXATION = 25, 1.8


@dataclass(frozen=True)
class Spectrum:
    """G = V diag(Λ) Vᵀ and the Laplacian's eigenvalues μ_k = 4 sin²(πk / 2T).

    ``transform(c)`` gives the spectral coefficients Qᵀ C V of (T, n) linear
    terms (Q the orthonormal DCT-II over frames), ``inverse(s)`` maps
    coefficients back to weights.
    """

    eig: np.ndarray
    vec: np.ndarray
    mu: np.ndarray

    @classmethod
    def build(cls, G, n_frames: int) -> "Spectrum":
        eig, vec = np.linalg.eigh(G)
        mu = 4.0 * np.sin(np.pi * np.arange(n_frames) / (2 * n_frames)) ** 2
        return cls(eig=eig, vec=vec, mu=mu)

    # the n columns' transforms are shared among the worker threads (each column's result
    # is the same on any number of them)
    def transform(self, c):
        return _fft().dct(c @ self.vec, type=2, norm="ortho", axis=0,
                          workers=worker_threads())

    def inverse(self, spectral):
        return _fft().idct(spectral, type=2, norm="ortho", axis=0,
                           workers=worker_threads()) @ self.vec.T

    def denominators(self, lam):
        """Λ_j + λ μ_k, (T, n), and where it counts as nonzero (a pseudo-inverse elsewhere)."""
        denom = self.eig[None, :] + lam * self.mu[:, None]
        floor = RANK_RTOL * max(self.eig[-1], np.finfo(float).tiny)
        return denom, denom > floor


def _fft():
    """:mod:`scipy.fft`, imported on first use: a fit without temporal smoothness does not
    pay for its import (50 ms with :mod:`scipy.special`)."""
    import scipy.fft
    return scipy.fft


def unbounded(spectrum: Spectrum, spectral, lam):
    """Minimizer (T, n) of the unbounded sequence problem from Qᵀ C V (``spectral``)."""
    denom, ok = spectrum.denominators(lam)
    return spectrum.inverse(np.where(ok, spectral / np.where(ok, denom, 1.0), 0.0))


def rough(spectrum: Spectrum, spectral, lam, lo, hi, n_steps: int):
    """A point (T, n) in the box near the bounded minimizer, by ``n_steps`` of ADMM.

    ADMM on ``f(w) + ι_box(z)`` with ``w = z``: w-steps solve the unbounded
    problem with ρ added to the Hessian (diagonal in the spectral basis),
    z-steps clip, both over-relaxed by ``_ADMM_RELAXATION``. ρ = √(Λ_min · (Λ_max +
    4λ)), the geometric mean of the Hessian's extreme eigenvalues (Λ_min the
    smallest nonzero one), the usual choice for a quadratic. Only its active
    set is used, and the bounded iteration that starts from it is exact: the steps
    run in float32 (half the bytes through the transforms: 35,000 frames × 53 weights,
    25 steps 2.28 → 1.37 s), from the float64 unbounded minimizer clipped, and the
    last clip is in float64, so that a weight at a bound is at it exactly.
    """
    eig = spectrum.eig
    positive = eig[eig > RANK_RTOL * max(eig[-1], np.finfo(float).tiny)]
    rho = float(np.sqrt(positive[0] * (eig[-1] + 4.0 * lam))) if positive.size else 1.0
    z = np.clip(unbounded(spectrum, spectral, lam), lo, hi)
    if not n_steps:
        return z
    single = replace(spectrum, vec=spectrum.vec.astype(np.float32))
    denom = (eig[None, :] + lam * spectrum.mu[:, None] + rho).astype(np.float32)
    spectral = spectral.astype(np.float32)
    lo32, hi32 = (np.asarray(b, dtype=np.float32) for b in (lo, hi))
    z = z.astype(np.float32)
    u = np.zeros_like(z)
    for step in range(n_steps):
        w = single.inverse((spectral + single.transform(rho * (z - u))) / denom)
        w *= _ADMM_RELAXATION
        w += (1.0 - _ADMM_RELAXATION) * z
        if step == n_steps - 1:
            return np.clip(w.astype(np.float64) + u, lo, hi)
        z = np.clip(w + u, lo32, hi32)
        u += w - z


def degree(n_frames: int) -> np.ndarray:
    """Degree of each frame in the path graph, (T,)."""
    deg = np.full(n_frames, 2.0)
    deg[[0, -1]] = 1.0 if n_frames > 1 else 0.0
    return deg


def gradient(G, c, lam, w, frames=None, *, scale: bool = True):
    """Gradient of the sequence objective at rows ``frames`` (sorted) of ``w`` (all when
    None).

    Returns the gradient and the magnitude of its terms (None without ``scale``),
    (F, n) each, F the number of frames.
    """
    whole = frames is None
    wf, cf = (w, c) if whole else (w[frames], c[frames])
    deg = degree(len(w))[:, None] if whole else degree(len(w))[frames][:, None]
    grad = wf @ G - cf + lam * (deg * wf - _neighbour_sum(w, frames))
    if not scale:
        return grad, None
    abs_wf = np.abs(wf)
    # the whole sequence's neighbours are its own rows: their magnitudes are abs_wf
    neighbours = _neighbour_sum(abs_wf, None) if whole else _neighbour_sum(w, frames, np.abs)
    magnitude = abs_wf @ np.abs(G) + np.abs(cf) + lam * (deg * abs_wf + neighbours)
    return grad, magnitude


def _neighbour_sum(w, frames, values=None):
    """Sum over each frame of ``frames`` (sorted; all when None) of the rows of ``w``
    (T, n) of its neighbours in the path, each through ``values`` when given: (F, n).

    The previous frame's row first, then the next one's, whichever way the frames come:
    the same sums to the bit.
    """
    if frames is None:          # the rows before and after, by slices
        out = np.zeros_like(w)
        out[1:] += w[:-1]
        out[:-1] += w[1:]
        return out
    out = np.zeros((len(frames), w.shape[1]))
    for there in (frames - 1, frames + 1):
        rows = (there >= 0) & (there < len(w))
        picked = w[there[rows]]
        out[rows] += picked if values is None else values(picked)
    return out


class _Band:
    """The reduced Hessian of runs of frames in a state, as the band of its free weights.

    A bound weight's row and column hold only the fill on the diagonal: the band keeps
    the free weights alone (:meth:`matrix`), a system of their own.
    """

    def __init__(self, G, lam, ridge):
        n = len(G)
        self.G, self.lam, self.n, self.ridge = G, lam, n, ridge
        self.g_diag = np.diag(G).copy()
        self.G_rows = np.ascontiguousarray(G.T)     # row i: column i of G, contiguous
        self.fill = float(np.mean(self.g_diag)) or 1.0

    def bandwidth(self, free, link) -> int:
        """kd, the bands above the diagonal that the matrix of the free weights of `free`
        (F, n) needs (:meth:`matrix`; ``link`` (F − 1,) as there), at most n: the
        farthest of a frame's first and last free weight, and of a free weight and itself
        in the next, linked frame, in the order of the free weights."""
        counts = free.sum(axis=1)
        within = int(counts.max(initial=0)) - 1
        before = np.cumsum(free, axis=1) - free     # free weights before each, in its frame
        # a weight's column less its column in the frame before: the free weights from it
        # on in that frame and those before it in its own
        tied = free[1:] & free[:-1] & np.asarray(link, dtype=bool)[:, None]
        apart = (counts[:-1, None] - before[:-1]) + before[1:]
        return max(within, int(apart[tied].max(initial=0)), 0)

    def matrix(self, free, deg, link, out=None):
        """The reduced Hessian of the free weights of frames with free mask ``free`` (F, n),
        degrees ``deg`` (F,), ``link`` (F − 1,) True where a frame is coupled to the next:
        a row and column per free weight, frame by frame, in LAPACK's upper band storage
        (kd + 1, N) of the fewest bands that hold it (:meth:`bandwidth`), Fortran-ordered
        (LAPACK factors it in place).

        Without the bound weights' rows (the fill on the diagonal alone), the band is
        about (N / F·n)·(kd / n)² of the work to factor (8,000 frames of the ICT take, 33
        of 53 weights free, kd 50: 160 → 107 ms). Written by the compiled loop of
        :mod:`fit.solve._band_kernel` when numba is there, else by NumPy (the same
        values, bit for bit); into the first (kd + 1)·N floats of the flat array `out`
        when given.
        """
        free = np.ascontiguousarray(free, dtype=bool)
        n_free, kd = int(np.count_nonzero(free)), self.bandwidth(free, link)
        size = (kd + 1) * n_free
        if out is not None and (out.ndim != 1 or out.dtype != np.float64 or len(out) < size):
            raise ValueError(f"out must be a flat float64 array of at least {size} floats")
        ab = (np.empty(size) if out is None else out[:size]).reshape((kd + 1, n_free),
                                                                      order="F")
        if not n_free:
            return ab
        kernel = _compiled_band()
        if kernel is not None:
            kernel(self.G_rows, self.g_diag, self.ridge, self.lam, free,
                   np.asarray(deg, dtype=float), np.asarray(link, dtype=bool), ab)
            return ab
        n = self.n
        at = np.flatnonzero(free.ravel())
        frame, weight = np.divmod(at, n)
        # column c holds, d rows above its diagonal, G's entry of the weight d columns back
        # where that weight is of its frame (d ≤ its place among the frame's free weights):
        # the columns of each place at once, each column's entries contiguous in the
        # C-ordered transpose
        rank = (np.cumsum(free, axis=1, dtype=np.min_scalar_type(n)) - free)[free]
        order = np.argsort(rank, kind="stable")
        ends = np.cumsum(np.bincount(rank, minlength=kd + 1))
        columns = ab.T
        ab.fill(0.0)
        flat_G = self.G.ravel()
        for place in range(1, kd + 1):
            cols = order[ends[place - 1]:ends[place]]
            back = weight[cols[:, None] + np.arange(-place, 0)]
            columns[cols, kd - place:kd] = flat_G[back * n + weight[cols, None]]
        columns[:, kd] = (self.g_diag[weight] + self.ridge) + self.lam * np.asarray(deg)[frame]
        column = np.full(free.size, -1)
        column[at] = np.arange(n_free)
        earlier = column[np.maximum(at - n, 0)]
        tied = (frame > 0) & (earlier >= 0)
        tied[tied] &= np.asarray(link, dtype=bool)[frame[tied] - 1]
        coupled = np.flatnonzero(tied)
        ab[kd - (coupled - earlier[coupled]), coupled] = -self.lam
        return ab


@functools.cache
def _compiled_band():
    """:func:`fit.solve._band_kernel.band_matrix`, or None (NumPy forms the banded matrix):
    :func:`mocap.util.optional.compiled`."""
    return compiled("fit.solve._band_kernel", "band_matrix", what="banded matrix",
                    fallback="NumPy forms it, four to five times slower")


def _reduced(qp: BoxQP, band: _Band, c, state, w, frames=None,
             whole: "_WholeFactor | None" = None):
    """Weights of ``frames`` (sorted) for their state, the other frames held at ``w``;
    with ``frames`` None, of the whole sequence, through the factor ``whole`` keeps.

    Bound weights sit at their bound, free ones are stationary: one banded
    solve over the frames. Returns (F, n).
    """
    sub = state if frames is None else state[frames]
    free = sub == 0
    fixed_part = qp.bound_values(sub)
    if frames is None:
        held = fixed_part
    else:
        held = w.copy()
        held[frames] = fixed_part
    rhs = np.where(free, -gradient(qp.G, c, band.lam, held, frames, scale=False)[0],
                   0.0).ravel()
    if frames is None:
        step = whole.solve(sub, rhs)
    else:
        step = np.zeros_like(rhs)
        at = np.flatnonzero(free)
        if at.size:
            ab = band.matrix(free, degree(len(c))[frames], np.diff(frames) == 1)
            step[at] = scipy.linalg.solveh_banded(ab, rhs[at], overwrite_ab=True,
                                                  check_finite=False)
    return fixed_part + np.where(free, step.reshape(free.shape), 0.0)


#: Variables whose freedom may differ from the factored state's for a global solve to go
#: through that factor by a low-rank correction (one band solve per variable, kept with
#: the factor) instead of factoring the whole sequence anew (~15 band solves' time).
_LOW_RANK_MAX = 12
#: Largest relative residual accepted from a low-rank solve (direct ones: 2e-15 to 1.4e-14
#: on the ICT take); above it the whole sequence is factored anew.
_LOW_RANK_RESIDUAL = 1e-11


class _WholeFactor:
    """Upper banded Cholesky factor M₀ of the whole sequence's reduced Hessian in one
    state, and the solves of nearby states through it.

    The factor is the one of the free weights' matrix (:meth:`_Band.matrix`); the
    bound weights' rows of the reduced Hessian are the fill on its diagonal, solved as
    such.

    A state whose free set F differs from the factored one's F₀ in a few variables is
    solved by bordering: with the newly bound variables B (free in F₀) and the newly
    freed ones P (bound in F₀), ``x = M₀⁻¹(b̂ − E_B μ − W_P x_P)``, where the columns
    ``W_P`` are those of the full Hessian A at P on the rows of F₀, and μ, x_P solve
    the small system that makes ``x_B = 0`` and the rows P hold (``W_Pᵀx + A_PP x_P =
    b_P``). Each variable's ``M₀⁻¹ e_j`` or ``M₀⁻¹ W_j`` is one band solve, kept while
    the factor is; the result's residual is checked. Other states get a factor of their
    own (in one buffer of (n + 1)·T·n floats, the most any state's takes, rewritten in
    place).
    """

    def __init__(self, band: _Band, n_frames: int):
        self.band, self.n_frames = band, n_frames
        self.free, self.factor, self.columns = None, None, {}
        self.buffer = self.at = None    # the factors' memory; the free weights, flat ids
        self._pending = None

    def reserve(self) -> None:
        """Allocate the factors' buffer and touch its pages on another thread, beside
        the caller's work until :meth:`prepare`, :meth:`solve` or :meth:`wait`: the first
        touch of (n + 1)·T·n floats is page faults (90 MB for 3,870 frames of 53 shapes),
        which a virtual machine can make ten times slower than writing the bytes."""
        self.wait()

        def touched():
            self.buffer = self._new_buffer()
            self.buffer.fill(0.0)           # (np.zeros would leave the pages untouched)
        self._run(touched)

    def _new_buffer(self) -> np.ndarray:
        return np.empty((self.band.n + 1) * self.n_frames * self.band.n)

    def _run(self, work) -> None:
        """Start `work` on a thread kept for the process (:meth:`wait` waits for it)."""
        self._pending = run_beside(work)

    def prepare(self, state) -> None:
        """Start what the solve of ``state`` (T, n) will need on another thread: a
        factorization of its own, or, for a state a few variables from the factored one,
        the columns that border the kept factor (:meth:`_column`) that are not kept yet.
        Both run without the GIL (:mod:`fit.solve._banded_cholesky`), beside the caller's
        work until :meth:`solve` or :meth:`wait`."""
        self.wait()
        free = (state == 0).ravel()
        if self.free is None:
            work = functools.partial(self._factor, free)
        else:
            changed = np.flatnonzero(free != self.free)
            if not changed.size:
                return
            work = functools.partial(self._factor, free) if changed.size > _LOW_RANK_MAX \
                else functools.partial(self._columns, changed)
        self._run(work)

    def wait(self) -> None:
        """Wait for the work :meth:`reserve` or :meth:`prepare` started, if any (its error
        raised)."""
        pending, self._pending = self._pending, None
        if pending is not None:
            pending.result()

    def solve(self, state, rhs):
        """``M⁻¹ rhs`` (T·n,) for the reduced Hessian M of ``state`` (T, n); ``rhs`` is 0
        on the bound variables."""
        self.wait()
        free = (state == 0).ravel()
        if self.free is not None:
            changed = np.flatnonzero(free != self.free)
            if not changed.size:
                return self._solve(rhs)
            if changed.size <= _LOW_RANK_MAX:
                x = self._bordered(free, changed, rhs)
                if x is not None:
                    return x
        self._factor(free)
        return self._solve(rhs)

    def _factor(self, free):
        """Factor the state with the flat free mask ``free`` (T·n,), in the kept buffer."""
        self.free, self.columns = None, {}  # the buffer is about to hold another factor
        if self.buffer is None:
            self.buffer = self._new_buffer()
        ab = self.band.matrix(free.reshape(self.n_frames, -1), degree(self.n_frames),
                              np.ones(max(self.n_frames - 1, 0), bool), out=self.buffer)
        self.factor = cholesky_banded_upper(ab) if ab.size else ab
        self.free, self.at = free, np.flatnonzero(free)

    def _solve(self, rhs):
        """``M₀⁻¹ rhs`` (T·n,): the free weights' through the factor, the bound ones' rows
        the fill on the diagonal."""
        x = rhs / self.band.fill
        if self.at.size:
            x[self.at] = cho_solve_banded_upper(self.factor, rhs[self.at])
        return x

    def _hessian_column(self, j):
        """Rows and values of column j of the full Hessian A = I ⊗ (G + ridge I) + λ L ⊗ I."""
        band, T = self.band, self.n_frames
        n = band.n
        t, i = divmod(int(j), n)
        rows = [t * n + np.arange(n)]
        values = [band.G[:, i].copy()]
        values[0][i] += band.ridge + band.lam * degree(T)[t]
        for other in (t - 1, t + 1):
            if 0 <= other < T:
                rows.append(np.array([other * n + i]))
                values.append(np.array([-band.lam]))
        return np.concatenate(rows), np.concatenate(values)

    def _columns(self, variables) -> None:
        """:meth:`_column` of each of `variables`, kept."""
        for j in variables:
            self._column(j)

    def _column(self, j):
        """``M₀⁻¹ e_j`` (j free in F₀) or ``M₀⁻¹ W_j`` (j bound in F₀), kept."""
        j = int(j)
        if j not in self.columns:
            u = np.zeros(self.free.size)
            if self.free[j]:
                u[j] = 1.0
            else:
                rows, values = self._hessian_column(j)
                u[rows] = values * self.free[rows]
            self.columns[j] = self._solve(u)
        return self.columns[j]

    def _bordered(self, free, changed, rhs):
        """The solve of the state with free set ``free`` through the factor of F₀, or
        None when its residual is too large."""
        bound = changed[self.free[changed]]              # B: free in F₀, bound now
        freed = changed[~self.free[changed]]             # P: bound in F₀, free now
        b = rhs.copy()
        b[freed] = 0.0
        y = self._solve(b)
        order = np.r_[bound, freed]
        Z = np.column_stack([self._column(j) for j in order])            # (N, k)
        # Uᵀ Z and Uᵀ y, U = [E_B, W_P] (W_P sparse: its rows and values)
        small = np.empty((len(order), len(order)))
        target = np.empty(len(order))
        small[:len(bound)], target[:len(bound)] = Z[bound], y[bound]
        a_pp = np.zeros((len(freed), len(freed)))
        for k, p in enumerate(freed):
            rows, values = self._hessian_column(p)
            on = self.free[rows]
            small[len(bound) + k] = values[on] @ Z[rows[on]]
            target[len(bound) + k] = values[on] @ y[rows[on]] - rhs[p]
            a_pp[k] = values @ (rows[:, None] == freed[None, :])
        small[len(bound):, len(bound):] -= a_pp
        try:
            coef = np.linalg.solve(small, target)
        except np.linalg.LinAlgError:
            return None
        y -= Z @ coef
        y[freed] = coef[len(bound):]
        y[~free] = 0.0
        return y if self._residual(free, y, rhs) <= _LOW_RANK_RESIDUAL else None

    def _residual(self, free, x, rhs):
        """Largest residual of ``M x = rhs`` on the free variables, relative to its terms."""
        band, T = self.band, self.n_frames
        G = band.G + band.ridge * np.eye(band.n) if band.ridge else band.G
        grad, scale = gradient(G, rhs.reshape(T, -1), band.lam, x.reshape(T, -1))
        rel = np.abs(grad).ravel()[free] / np.maximum(scale.ravel()[free], np.finfo(float).tiny)
        return rel.max(initial=0.0)


def _step(qp: BoxQP, state, w, grad):
    """Next primal-dual state: bind free weights outside the box, free wrong-signed bound ones."""
    free = state == 0
    new = state.copy()
    new[free & (w < qp.lo)] = -1
    new[free & (w > qp.hi)] = 1
    new[((state == -1) & (grad < 0)) | ((state == 1) & (grad > 0))] = 0
    new[:, qp.fixed] = -1
    return new


def _near(changed, width):
    """Frames within ``width`` frames of a True of ``changed`` (T,), as a bool mask."""
    edges = np.zeros(len(changed) + 1, np.int64)
    idx = np.flatnonzero(changed)
    np.add.at(edges, np.maximum(idx - width, 0), 1)
    np.add.at(edges, np.minimum(idx + width + 1, len(changed)), -1)
    return np.cumsum(edges[:-1]) > 0


def _settle(qp, band, c, state, w, changed, n_iter):
    """Local phase: iterate the windows around ``changed`` frames (``state`` in place).

    Each step solves the windows' reduced system with the frames outside held
    at ``w`` and moves the windows' state one primal-dual step; the windows
    shrink to the frames still changing. Stops when no state changes, after
    ``_LOCAL_ITER`` steps, or when the windows would cover too much of the take.
    """
    w = w.copy()
    for _ in range(_LOCAL_ITER):
        near = _near(changed, _WINDOW)
        if not changed.any() or near.sum() > _LOCAL_SHARE * len(c):
            return
        frames = np.flatnonzero(near)
        w[frames] = _reduced(qp, band, c, state, w, frames)
        n_iter[frames] += 1
        grad = gradient(qp.G, c, band.lam, w, frames, scale=False)[0]
        new = _step(qp, state[frames], w[frames], grad)
        changed = np.zeros(len(c), bool)
        changed[frames] = (new != state[frames]).any(axis=1)
        state[frames] = new


#: Linear terms for the next global step, from the weights of the last one and
#: whether they are optimal; None to stop (see :func:`bounded`).
Follow = Callable[[np.ndarray, bool], "np.ndarray | None"]


def bounded(qp: BoxQP, spectrum: Spectrum, c, lam, tol, max_iter, start=None,
            follow: Follow | None = None):
    """Exact minimizer of the sequence problem in the box.

    Returns w (T, n), n_iter (T,) and the linear terms (T, n) w solves: `c`,
    or the last ones `follow` returned.

    The first state is the active set of `start` (T, n) when given (weights
    at or beyond a bound are bound), else of :func:`rough`.

    ``n_iter`` counts the reduced solves (global and local) each frame took
    part in. When the global state repeats (a cycle), the local phase is
    turned off (it proposes states the plain iteration would not visit); when
    the plain iteration cycles too, or ``max_iter`` global steps pass, the
    last iterate is returned clipped to the box (the caller's KKT check
    reports it unconverged).

    ``follow(w, optimal)``, when given, is called after every global solve
    with its weights and whether every frame meets the KKT conditions, and
    returns the linear terms of the next one (the problem moves; the same
    terms hold it) or None to stop: the iteration then ends where `follow`
    says, optimal or not (w always solves the last terms it returned). A
    cycle of the plain iteration while the terms move holds them until the
    state is optimal again (the iteration of a fixed problem, which stops on
    a second cycle).
    """
    T, n = c.shape
    ridge = RANK_RTOL * spectrum.eig[-1] if qp.singular else 0.0
    band = _Band(qp.G, lam, ridge)
    whole = _WholeFactor(band, T)
    whole.reserve()                     # its pages touched beside the start's work
    if start is None:
        start = rough(spectrum, spectrum.transform(c), lam, qp.lo, qp.hi, _ADMM_ITER)
    state = qp.state_of(start)
    n_iter = np.zeros(T, np.int64)
    w = np.zeros_like(c)
    seen = {state.tobytes()}
    local, hold = True, False
    for iteration in range(max_iter):
        w = _reduced(qp, band, c, state, w, whole=whole)
        n_iter += 1
        grad, scale = gradient(qp.G, c, lam, w)
        optimal = bool((kkt_residual(w, grad, scale, qp.lo, qp.hi) <= tol).all())
        if not optimal:
            new = _step(qp, state, w, grad)
            if local:
                _settle(qp, band, c, new, w, (new != state).any(axis=1), n_iter)
            key = new.tobytes()
            if key in seen:
                if not local and (follow is None or hold):
                    break
                # a cycle: plain primal-dual steps from here on, of a held problem
                # if it cycles again
                hold, local, seen = not local, False, set()
            seen.add(key)
            state = new
        if follow is None or (hold and not optimal):
            if optimal:
                break
            continue
        if iteration == max_iter - 1:
            break                       # (the last terms are the ones w solves)
        # the next state's factor forms while follow works (on the state, not on the terms)
        whole.prepare(state)
        try:
            following = follow(w, optimal)
        finally:
            whole.wait()
        if following is None:
            break
        c = following
        if optimal:                     # a new problem from an optimal state
            hold, local, seen = False, True, {state.tobytes()}
    return np.clip(w, qp.lo, qp.hi), n_iter, c
