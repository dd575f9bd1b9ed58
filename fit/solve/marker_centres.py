"""Weights under the exact marker-centre model: markers off the skin turn with it.

A marker's centre sits a skin offset h off the surface, along the normal:
``c(w) = s(w) + h n(w)``, with the skin point s linear in the weights and the
unit normal n not. The marker-space basis B of :func:`fit.solve.marker_basis.marker_basis`
is the tangent of c at the neutral, so ``B w`` misses the part
``r(w) = c(w) − c(0) − B w`` that comes from the normals turning (eyes wide,
lids, brows: up to 0.25 in weight at full expressions on the ICT face with
2 mm markers, without noise).

:func:`solve_at_marker_centres` removes it by the chord method: every step
solves the exact bounded problem of :func:`fit.solve.weights.solve_weights` with the
same B (one BᵀB, all frames batched) against the data less the current
``r(x_k)``, ``F(x_k) = argmin ½‖B w − (d − r(x_k))‖²``; the next iterate
mixes the last two steps (Anderson acceleration with one memory, clipped to
the bounds), and frames whose step has settled (``max |F(x) − x| ≤ tol``)
leave with ``F(x)``. With temporal smoothness the frames are one problem: its
chord steps ride on the smooth solve's active-set iteration (every global solve
of it moves the data to the current iterate), so that the steps and the active
set converge together. The fixed point fits the exact model: ``c(w) − c(0) = d``
where the data allow it (noise-free data are recovered exactly); with noise
its residual is orthogonal to B instead of to the Jacobian of c, which
differs from the least-squares fit of c by the second order of the offset.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from fit.solve._active_set import BoxQP, solve_box_qp
from fit.solve._problem import as_bounds
from fit.solve.gcv import SMOOTHNESS_RULES, gcv_smoothness
from fit.solve.weights import (
    DEFAULT_TOL,
    WeightSolution,
    as_smoothness,
    default_max_iter,
    solve_weights,
    warn_rank_deficient,
)
from mocap.errors import InputError
from mocap.mesh.layout import MarkerLayout, PlacementUnderWeights
from mocap.util.blas import map_on_blas_threads
from mocap.util.validation import as_float_array, as_int, as_positive_float

__all__ = ["MarkerCentreFit", "solve_at_marker_centres"]


@dataclass(frozen=True, eq=False)
class MarkerCentreFit:
    """Result of :func:`solve_at_marker_centres`.

    Attributes
    ----------
    solution : WeightSolution
        The weights of the last step; ``cost`` is ½‖c(w) − c(0) − d‖² of the
        exact model; ``converged`` needs the last step's KKT conditions and a
        settled frame; ``status`` and ``message`` say both.
    displacements : ndarray of shape (T, M, 3), data units
        ``c(w) − c(0)``: the marker centres the weights reconstruct.
    n_steps : ndarray of int, shape (T,)
        Chord steps each frame took (1: the linear model's solve only; with
        smoothness, the same for every frame).
    step : ndarray of shape (T,)
        Largest weight change of each frame's last step, dimensionless.
    tol : float
        The step below which a frame has settled.
    """

    solution: WeightSolution
    displacements: np.ndarray
    n_steps: np.ndarray
    step: np.ndarray
    tol: float

    @property
    def settled(self) -> np.ndarray:
        """Frames whose last step changed no weight by more than `tol`, (T,) bool."""
        return self.step <= self.tol


def solve_at_marker_centres(layout: MarkerLayout, neutral, displacements, basis, data, *,
                            lower=-np.inf, upper=np.inf, smoothness: float | str = 0.0,
                            tol: float = 1e-6, max_steps: int = 50) -> MarkerCentreFit:
    """Fit weights to marker-centre displacements with the exact, nonlinear centre model.

    Parameters
    ----------
    layout : MarkerLayout
        The M markers on the mesh, with their offsets (mesh units): e.g.
        :meth:`mocap.bind.Binding.centre_layout`, restricted to the fitted markers.
    neutral : array_like of shape (N, 3), mesh units
        The neutral mesh's vertices.
    displacements : array_like of shape (n, N, 3), mesh units
        The shapes e_i.
    basis : array_like of shape (n, M, 3), mesh units
        The tangent of the centres at the neutral (:func:`fit.solve.marker_basis.marker_basis`).
    data : array_like of shape (T, M, 3), mesh units
        Marker-centre displacements from the rest pose, no NaN.
    lower, upper, smoothness
        As in :func:`fit.solve.weights.solve_weights`; ``smoothness="gcv"`` chooses λ
        once, by generalized cross-validation of the linear (tangent) model
        (:func:`fit.solve.gcv.gcv_smoothness` on `basis` and `data`), and every
        chord step solves with that λ (the result's ``smoothness``).
    tol : float, default 1e-6
        A frame has settled when its step changes no weight by more than this.
    max_steps : int, default 50
        Most chord steps (each one solve; the first one, from zero weights, is
        the linear model's). With `smoothness`, every global solve of the
        smooth active-set iteration is a step, the first one from the frames'
        linear optima; after the last step the iteration still finishes the
        active set of its data, so the weights always solve the data of their
        last step exactly.

    Returns
    -------
    MarkerCentreFit

    Raises
    ------
    InputError
        Shapes that do not match, NaN in the data, bad bounds or options.
    """
    basis = as_float_array(basis, "basis", ndim=3, allow_nan=False)
    data = as_float_array(data, "data", shape=(None,) + basis.shape[1:], allow_nan=False,
                          copy=False)                       # only read
    if basis.shape[1] != layout.n_markers:
        raise InputError(f"basis has {basis.shape[1]} markers, the layout {layout.n_markers}")
    n_shapes = len(np.asarray(displacements))
    if n_shapes != len(basis):
        raise InputError(f"displacements hold {n_shapes} shapes, the basis {len(basis)}")
    tol = as_positive_float(tol, "tol")
    max_steps = as_int(max_steps, "max_steps", minimum=1)

    n, T = len(basis), len(data)
    smoothness = as_smoothness(smoothness)
    if smoothness in SMOOTHNESS_RULES:
        smoothness = gcv_smoothness(basis.reshape(n, -1).T, data.reshape(T, -1))
    placement = layout.under_weights(neutral, displacements)
    model = _CentreModel.build(placement, basis, lower, upper)
    steps = _ChordSteps.empty(T, n, layout.n_markers)
    if smoothness > 0:
        ranks = [_smooth_chord_steps(model, data, smoothness, tol, max_steps, steps)]
    else:
        if model.qp.singular:       # as solve_weights says it (the smooth solve goes through it)
            warn_rank_deficient(model.qp.rank, n)
        # frames are independent: pieces of them step on the BLAS's threads, each writing
        # its rows of the result (no copy of the pieces' results in one thread after)
        def piece(first):
            rows = slice(first, first + _FRAMES_PER_TASK)
            return _chord_steps(model, data[rows], tol, max_steps, steps.rows(rows))
        ranks = map_on_blas_threads(piece, range(0, T, _FRAMES_PER_TASK))
    step, n_steps = steps.step, steps.n_steps
    settled = step <= tol
    ok = steps.converged & settled
    solution = WeightSolution(
        weights=steps.weights, cost=steps.cost, n_iter=steps.n_iter, converged=ok,
        kkt_residual=steps.kkt, rank=min(ranks), status=int(not ok.all()),
        message=_message(ok, settled, step, n_steps, tol), smoothness=smoothness)
    return MarkerCentreFit(solution=solution, displacements=steps.moved, n_steps=n_steps,
                           step=step, tol=tol)


#: Frames that step together in one piece of an independent-frame fit (pieces of a
#: fixed size: the result does not depend on the thread count). Small enough that the
#: pieces share out evenly (35 of a 35,000-frame take: the threads' last round waits for
#: one short piece, not for a ninth of the take), large enough that each piece's batched
#: products stay efficient.
_FRAMES_PER_TASK = 1024


#: Frames of one piece of an evaluation of the centre model shared among threads (pieces
#: of a fixed size: the values do not depend on the thread count).
_FRAMES_PER_EVALUATION = 512


@dataclass(frozen=True)
class _CentreModel:
    """The centres' model: ``centres(w) = c(w) − c(0)``, the bounds, and the linear
    model's box QP (G = BᵀB of the tangent B, the bounds).

    The evaluations share pieces of the frames among the worker threads (one
    thread inside a piece of an independent-frame fit, whose work is already shared).
    """

    placement: PlacementUnderWeights
    basis: np.ndarray
    rest: np.ndarray
    lower: object
    upper: object
    qp: BoxQP

    @classmethod
    def build(cls, placement: PlacementUnderWeights, basis: np.ndarray, lower,
              upper) -> "_CentreModel":
        """The model of `placement` with the tangent `basis` (n, M, 3) and the bounds."""
        n = len(basis)
        flat = basis.reshape(n, -1)
        return cls(placement, basis, placement(np.zeros((1, n)))[0], lower, upper,
                   BoxQP.build(flat @ flat.T, *as_bounds(lower, upper, n)))

    def centres(self, w: np.ndarray) -> np.ndarray:
        """``c(w) − c(0)`` of the weights `w` (T, n), (T, M, 3)."""
        return self._by_pieces(self._centres, w, self.rest.shape)

    def nonlinear(self, w: np.ndarray) -> np.ndarray:
        """``r(w) = c(w) − c(0) − B w`` of the weights `w` (T, n), (T, M, 3)."""
        return self._by_pieces(
            lambda part: self._centres(part) - np.tensordot(part, self.basis, axes=1), w,
            self.rest.shape)

    def projected(self, w: np.ndarray) -> np.ndarray:
        """``Bᵀ(c(w) − c(0))`` of the weights `w` (T, n), (T, n): the centres on the
        tangent's columns, each piece's while its centres are in cache."""
        flat = self.basis.reshape(len(self.basis), -1)
        return self._by_pieces(
            lambda part: self._centres(part).reshape(len(part), -1) @ flat.T, w,
            (len(self.basis),))

    def _centres(self, w: np.ndarray) -> np.ndarray:
        return self.placement(w) - self.rest

    def _by_pieces(self, function, w: np.ndarray, shape: tuple) -> np.ndarray:
        """``function(w)`` (T, *shape), pieces of the frames of `w` (T, n) on the threads."""
        out = np.empty((len(w), *shape))

        def piece(first):
            rows = slice(first, first + _FRAMES_PER_EVALUATION)
            out[rows] = function(w[rows])
        map_on_blas_threads(piece, range(0, len(w), _FRAMES_PER_EVALUATION))
        return out


@dataclass(frozen=True)
class _ChordSteps:
    """Per frame: weights, centres, cost, KKT residual and convergence of the last solve,
    chord steps, solver iterations and the last step (arrays over the same frames)."""

    weights: np.ndarray
    moved: np.ndarray
    cost: np.ndarray
    kkt: np.ndarray
    converged: np.ndarray
    n_steps: np.ndarray
    n_iter: np.ndarray
    step: np.ndarray

    @classmethod
    def empty(cls, n_frames: int, n_shapes: int, n_markers: int) -> "_ChordSteps":
        """Arrays for `n_frames` frames, to be filled by :func:`_chord_steps`."""
        T = n_frames
        return cls(np.empty((T, n_shapes)), np.empty((T, n_markers, 3)), np.empty(T),
                   np.empty(T), np.empty(T, bool), np.empty(T, np.int64),
                   np.empty(T, np.int64), np.empty(T))

    def rows(self, rows: slice) -> "_ChordSteps":
        """Views of the frames `rows`, writing into these arrays."""
        return _ChordSteps(*(getattr(self, f.name)[rows] for f in fields(self)))

    def finish(self, model: _CentreModel, weights: np.ndarray, data) -> None:
        """Write the centres of the final `weights` and their cost against `data`."""
        self.moved[:] = model.centres(weights)
        residual = self.moved - data
        self.cost[:] = 0.5 * np.einsum("tmc,tmc->t", residual, residual)


def _chord_steps(model: _CentreModel, data, tol, max_steps, out: _ChordSteps) -> int:
    """The chord steps of independent frames `data` (T, M, 3) from zero weights (whose
    first step is the linear model's solve), written into `out` (T frames); return the
    basis' rank. A frame's solve starts from the active set of its mixed iterate, which
    extrapolates the last two; a frame leaves once its step has settled.

    Each step solves the box QPs of ``model.qp`` (the linear model's G) with the linear
    terms of the moved data ``d − r(x)``: ``Bᵀ(d − r(x)) = Bᵀd − Bᵀ(c(x) − c(0)) + G x``,
    so that only the centres are evaluated, and the frames' terms Bᵀd are formed once.
    """
    qp, lower, upper = model.qp, model.lower, model.upper
    T, n = len(data), qp.n
    max_iter = default_max_iter(n)
    linear = data.reshape(T, -1) @ model.basis.reshape(n, -1).T             # Bᵀd, (T, n)
    w, kkt, converged, n_steps, n_iter, step = \
        out.weights, out.kkt, out.converged, out.n_steps, out.n_iter, out.step
    n_steps[:], n_iter[:], step[:] = 0, 0, np.inf
    # the frames still stepping, their iterates x and (for Anderson) the previous ones
    # and their chord steps, compacted to those frames
    todo, x = np.arange(T), np.zeros((T, n))
    last_x = last_g = None
    for first in (True, *[False] * (max_steps - 1)):
        if first:                               # r(0) = 0: the linear model's solve
            terms, state = linear, None
        else:
            terms = linear[todo] - model.projected(x)
            terms += x @ qp.G
            state = qp.state_of(x)
        weights, iterations, residual, ok = solve_box_qp(
            qp, terms, tol=DEFAULT_TOL, max_iter=max_iter, warm_start=True, state=state)
        g = weights - x
        moved = np.abs(g).max(axis=1)
        step[todo], w[todo], kkt[todo], converged[todo] = moved, weights, residual, ok
        n_steps[todo] += 1
        n_iter[todo] += iterations
        mixed = weights if last_g is None else _anderson(weights, g, last_x + last_g, last_g,
                                                         lower, upper)
        moving = moved > tol
        if not moving.any():
            break
        todo, x, last_x, last_g = todo[moving], mixed[moving], x[moving], g[moving]
    out.finish(model, w, data)
    return qp.rank


def _smooth_chord_steps(model: _CentreModel, data, smoothness, tol, max_steps,
                        out: _ChordSteps) -> int:
    """The chord steps of `data` (T, M, 3) as one smooth problem, written into `out`;
    return the basis' rank.

    The first iterate is the linear model's unbounded smooth minimizer clipped to the
    bounds (one spectral solve: a bounded solve per frame costs more than the steps it
    saves, and a smooth start takes no more steps). Every global solve of the
    smooth active-set iteration is a chord step (:class:`_SmoothChord`): while the active
    set is still wrong the step is inexact and the next iterate is its weights; once a
    solve is optimal, iterates mix the last two steps as :func:`_chord_steps` does. The
    result solves the data of its own last iterate exactly.
    """
    basis, lower, upper = model.basis, model.lower, model.upper
    start = np.clip(solve_weights(basis, data, smoothness=smoothness).weights, lower, upper)
    chord = _SmoothChord(model, data, start, tol, max_steps, out)
    sol = solve_weights(basis, chord.moved_data, lower=lower, upper=upper,
                        smoothness=smoothness, follow=chord)
    out.weights[:], out.n_iter[:] = sol.weights, sol.n_iter
    out.kkt[:], out.converged[:] = sol.kkt_residual, sol.converged
    out.finish(model, sol.weights, data)
    return sol.rank


#: A frame whose iterate moved by at most this share of the chord's `tol` keeps its
#: last r(x): its data are then those of an iterate at most that far from the current one.
_REEVALUATE_SHARE = 1e-3


class _SmoothChord:
    """The ``follow`` of the smooth solve that makes its global steps chord steps.

    Keeps the iterate x (T, n), ``moved_data`` = d − r(x) and the steps in `out`
    (``n_steps``, ``step``). Frames whose iterate moved by no more than
    ``_REEVALUATE_SHARE · tol`` since r was evaluated keep their r: late steps move
    few frames by more.
    """

    def __init__(self, model: _CentreModel, data, start, tol, max_steps, out: _ChordSteps):
        self.model, self.data, self.tol, self.max_steps, self.out = \
            model, data, tol, max_steps, out
        self.x, self.evaluated = start.copy(), start.copy()
        self.moved_data = data - model.nonlinear(start)
        self.last_x = self.last_g = None
        out.n_steps[:], out.step[:] = 0, np.inf

    def __call__(self, w, optimal):
        out, lower, upper = self.out, self.model.lower, self.model.upper
        g = w - self.x
        out.step[:] = np.abs(g).max(axis=1)
        if out.n_steps[0] < self.max_steps:
            out.n_steps[:] += 1
        if optimal and (out.step.max() <= self.tol or out.n_steps[0] >= self.max_steps):
            return None
        if out.n_steps[0] >= self.max_steps:
            return self.moved_data          # no more steps: the active set finishes the last
        if not optimal:                     # an inexact step: no secant through it
            x, self.last_g = np.clip(w, lower, upper), None
        else:
            x = w if self.last_g is None else _anderson(
                w, g, self.last_x + self.last_g, self.last_g, lower, upper)
            self.last_x, self.last_g = self.x, g
        self.x = x
        rows = np.flatnonzero(np.abs(x - self.evaluated).max(axis=1)
                              > _REEVALUATE_SHARE * self.tol)
        self.evaluated[rows] = x[rows]
        # a new array: the solve keeps the data it was given
        self.moved_data = self.moved_data.copy()
        self.moved_data[rows] = self.data[rows] - self.model.nonlinear(x[rows])
        return self.moved_data


def _anderson(fx, g, last_fx, last_g, lower, upper):
    """Anderson-accelerated iterate (one memory, per frame), clipped to the bounds, (T, n).

    ``x⁺ = F(x) − θ (F(x) − F(x⁻))`` with θ minimizing the mixed step
    ‖g − θ (g − g⁻)‖ (g = F(x) − x): a secant along the last two steps, which
    turns the plain step's slow or cycling approach (strong expressions,
    noise along the basis' weak directions) into a few steps.
    """
    dg = g - last_g
    norm = np.einsum("ti,ti->t", dg, dg)
    theta = np.divide(np.einsum("ti,ti->t", g, dg), norm, out=np.zeros_like(norm),
                      where=norm > 0)
    return np.clip(fx - theta[:, None] * (fx - last_fx), lower, upper)


def _message(ok, settled, step, n_steps, tol) -> str:
    if ok.all():
        return (f"all {len(ok)} frames meet the KKT conditions and settled at the marker "
                f"centres in at most {int(n_steps.max())} steps (step ≤ {tol:g})")
    bad = np.flatnonzero(~settled)
    parts = []
    if bad.size:
        first = ", ".join(str(int(f)) for f in bad[:5]) + (", ..." if bad.size > 5 else "")
        parts.append(f"{bad.size} frames had not settled after {int(n_steps.max())} steps "
                     f"(frames {first}; last step up to {step[bad].max():.3g} > {tol:g})")
    unconverged = int(np.count_nonzero(~ok & settled))
    if unconverged:
        parts.append(f"{unconverged} frames did not meet the KKT conditions")
    return "; ".join(parts) + ": their weights are within the bounds but not a fixed point"
