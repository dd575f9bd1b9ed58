"""Per-frame blendshape weights by exact, batched bounded least squares.

For every frame t: ``min_w ½‖B w − d_t‖²`` subject to ``lower ≤ w ≤ upper``
(quasi-eigen paper, eq. 5), all frames solved together from ``G = BᵀB`` and
``C = D B`` (one product), by the active-set method of :mod:`fit.solve._active_set`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from fit.solve._active_set import BoxQP, solve_box_qp
from fit.solve._problem import as_bounds, as_problem
from fit.solve.gcv import SMOOTHNESS_RULES, gcv_smoothness
from fit.solve.temporal import solve_smooth
from mocap.errors import InputError
from mocap.util.blas import map_on_blas_threads, on_one_blas_thread
from mocap.util.validation import as_float_array, as_int

__all__ = ["WeightSolution", "solve_weights", "as_smoothness"]


@dataclass(frozen=True)
class WeightSolution:
    """Weights of every frame and how well they solve their problem.

    Attributes
    ----------
    weights : ndarray, shape (n_frames, n_shapes)
        Within the bounds (clipped), dimensionless.
    cost : ndarray, shape (n_frames,)
        ½‖B w_t − d_t‖² over the frame's valid rows, in data units squared
        (mm² for markers); the smoothness term is not included.
    n_iter : ndarray of int, shape (n_frames,)
        Reduced solves each frame went through, factored or bordered (1 for an
        unbounded problem).
    converged : ndarray of bool, shape (n_frames,)
        True where ``kkt_residual <= tol``.
    kkt_residual : ndarray, shape (n_frames,)
        Worst violation of the KKT conditions, dimensionless: feasibility in
        weight units over max(1, |w|); stationarity of interior weights and
        the multiplier sign of weights at a bound, each over the magnitude of
        the terms of the gradient.
    rank : int
        Numerical rank of BᵀB (the smallest over the mask's row patterns).
    smoothness : float
        The λ the weights were solved with (the one GCV chose for
        ``smoothness="gcv"``; 0: frames independent).
    status : int
        0 when every frame converged, 1 when some did not.
    message : str
        What happened, naming the first frames that did not converge.
    """

    weights: np.ndarray
    cost: np.ndarray
    n_iter: np.ndarray
    converged: np.ndarray
    kkt_residual: np.ndarray
    rank: int
    status: int
    message: str
    smoothness: float = 0.0


#: solve_weights' KKT tolerance unless told otherwise.
DEFAULT_TOL = 1e-9


def default_max_iter(n_shapes: int) -> int:
    """solve_weights' iterations of the monotone phase unless told otherwise."""
    return 20 * n_shapes + 20


def warn_rank_deficient(rank: int, n_shapes: int, where: str = "", *,
                        stacklevel: int = 2) -> None:
    """Warn that the basis has rank `rank` < `n_shapes` (`where`: on which rows), for the
    frame `stacklevel` above the caller."""
    warnings.warn(f"the basis has rank {rank} < {n_shapes} shapes{where}: weights along its "
                  "null space are the minimum-norm reduced solution", RuntimeWarning,
                  stacklevel=stacklevel + 1)


@on_one_blas_thread
def solve_weights(basis, data, *, lower=-np.inf, upper=np.inf, mask=None,
                  warm_start: bool = True, smoothness: float | str = 0.0,
                  tol: float = DEFAULT_TOL, max_iter: int | None = None,
                  start=None, follow=None) -> WeightSolution:
    """Solve ``min ½‖B w − d_t‖²`` with ``lower ≤ w ≤ upper`` for every frame.

    Parameters
    ----------
    basis : array_like, shape (K, n_shapes) or (n_shapes, n_markers, 3)
        The shapes' displacements from the neutral, as columns of B (K rows:
        3 per marker or vertex, x y z interleaved), or one (n_markers, 3)
        array per shape, in mm (or the mesh's units). No NaN.
    data : array_like, shape (n_frames, K) or (n_frames, n_markers, 3)
        Displacements from the neutral, same layout and units as `basis`.
        NaN policy: rejected, unless `mask` marks the sample invalid.
    lower, upper : float or array_like of shape (n_shapes,)
        Bounds, ±inf allowed; e.g. 0 and 1, or -ε and 1 + ε.
    mask : array_like of bool, shape (n_frames, K) or (n_frames, n_markers), optional
        True for the rows each frame fits; the others (e.g. missing markers)
        are left out of that frame's problem exactly (frames are grouped by
        mask pattern, each pattern with its own BᵀB). Not with `smoothness`.
    warm_start : bool, default True
        Start every frame from the active set of its unconstrained minimizer
        clipped to the bounds (one product with (BᵀB)⁻¹; the clipped weights
        whose gradient points inwards are freed), instead of with every
        weight free. Does not change the result, only the work. The frames
        are taken to be in time order: compiled, the first ones of each
        block also try starting from the active set the frame before ended
        in, and the others start from whichever took fewer iterations (it
        takes half as many on a take whose weights rest at 0 in many frames,
        twice as many on independent frames). Frames solved independently
        only: the smooth solve has a start of its own.
    smoothness : float or "gcv", default 0
        λ ≥ 0: minimize Σ_t ½‖B w_t − d_t‖² + ½ λ Σ_t ‖w_t − w_{t−1}‖² over
        the whole sequence instead (see :func:`fit.solve.temporal.solve_smooth`);
        λ in data units² per unit weight change (mm² for markers), so it
        scales with B. ``"gcv"`` (:data:`fit.solve.gcv.SMOOTHNESS_RULES`): λ chosen
        by generalized cross-validation of the unbounded smooth problem
        (:func:`fit.solve.gcv.gcv_smoothness`), then the bounded problem solved at
        that λ; the result's ``smoothness`` says which.
    tol : float, default 1e-9
        Largest accepted KKT residual.
    max_iter : int, optional
        Iterations of the monotone phase; default 20 · n_shapes + 20.
    start : array_like, shape (n_frames, n_shapes), optional
        Weights whose active set (which weights are at a bound) starts the
        solve, e.g. the solution of a nearby problem (the marker-centre fit's
        previous step), instead of `warm_start`'s or, with ``smoothness`` > 0,
        a rough estimate of the solution. Does not change the result, only
        the work.
    follow : callable, optional
        With `smoothness` > 0 only: ``follow(weights, optimal) -> data or
        None``, called after every global step of the smooth solve with its
        weights (n_frames, n_shapes) and whether every frame meets the KKT
        conditions; returns the data of the next step (the layout of `data`,
        no NaN) or None to stop. The problem moves while it is solved (the
        chord steps of :func:`fit.solve.marker_centres.solve_at_marker_centres`);
        the result solves the last data returned (its ``cost`` and
        ``kkt_residual`` are of them).

    Returns
    -------
    WeightSolution

    Raises
    ------
    InputError
        Mismatched shapes, NaN in data outside the mask (naming the frame),
        bounds with lower > upper, a mask with smoothness.

    Warns
    -----
    RuntimeWarning
        When B is rank-deficient (the minimum-norm reduced solution is taken,
        through a pseudo-inverse: the residual stays minimal, the split of the
        weights along the null space is one of many), and when frames do not
        converge.

    Notes
    -----
    With G = BᵀB and c_t = Bᵀd_t each frame is the QP ``½ wᵀGw − c_tᵀw``.
    Frames iterate together (primal-dual active set, then the monotone
    primal active-set method for those left). Every reduced system
    ``G_FF w_F = c_F − G_FA w_A`` is solved through the smaller of the free
    set F and the bound set A: with A small, ``w = G⁻¹(c + λ)`` where λ,
    zero off A, solves the |A| × |A| system ``(G⁻¹)_AA λ_A = w_A − (G⁻¹c)_A``
    (G⁻¹ computed once); frames of about equal size are factored together,
    and the monotone phase borders a factorization with the one variable its
    next iteration changes instead of factoring anew.

    The products are of n-wide batches: the solve runs on one BLAS thread
    (:func:`mocap.util.blas.one_blas_thread`), whatever the BLAS is set to, and its
    blocks of frames (the right-hand sides, the iterations, the costs) are shared among
    as many Python threads as the BLAS had (the same bits on any number of them).

    References
    ----------
    Kim et al., "Quasi-eigen faces", eq. 5.

    Examples
    --------
    >>> B = np.eye(3)
    >>> sol = solve_weights(B, [[0.5, 2.0, -1.0]], lower=0, upper=1)
    >>> sol.weights.tolist(), sol.status
    ([[0.5, 1.0, 0.0]], 0)
    """
    B, D, valid = as_problem(basis, data, mask)
    n = B.shape[1]
    lo, hi = as_bounds(lower, upper, n)
    smoothness = as_smoothness(smoothness)
    if smoothness != 0 and valid is not None:
        raise InputError("smoothness cannot be combined with mask: the smooth "
                         "solve needs one BᵀB for all frames")
    if follow is not None and smoothness == 0:
        raise InputError("follow needs smoothness: independent frames have no global step")
    if not (isinstance(tol, float | int) and np.isfinite(tol) and tol > 0):
        raise InputError(f"tol must be a positive number, got {tol!r}")
    max_iter = default_max_iter(n) if max_iter is None else \
        as_int(max_iter, "max_iter", minimum=1)
    if smoothness in SMOOTHNESS_RULES:
        smoothness = gcv_smoothness(B, D)
    if start is not None:
        start = as_float_array(start, "start", shape=(len(D), n), allow_nan=False)

    patterns, group = (np.ones((1, len(B)), bool), np.zeros(len(D), np.intp)) \
        if valid is None else np.unique(valid, axis=0, return_inverse=True)
    C = _rows_times(D if valid is None else np.where(valid, D, 0.0), B)
    weights = np.empty((len(D), n))
    n_iter = np.zeros(len(D), np.int64)
    kkt = np.empty(len(D))
    ranks = []
    for p, rows in enumerate(patterns):
        frames = np.nonzero(group.ravel() == p)[0]
        qp = BoxQP.build(B[rows].T @ B[rows], lo, hi)
        ranks.append(qp.rank)
        if qp.singular:
            warn_rank_deficient(qp.rank, n, "" if valid is None else
                                f" on the valid rows of frames {_first(frames)}")
        if smoothness > 0:
            moving = None if follow is None else _Moving(follow, B, D)
            w, it, res, _ = solve_smooth(qp, C, smoothness, tol=tol, max_iter=max_iter,
                                         start=start, follow=moving)
            D = D if moving is None else moving.data
        else:
            w, it, res, _ = solve_box_qp(
                qp, C[frames], tol=tol, max_iter=max_iter, warm_start=warm_start,
                state=None if start is None else qp.state_of(start[frames]))
        weights[frames], n_iter[frames], kkt[frames] = w, it, res
    cost = _cost(weights, B, D, valid)
    converged = kkt <= tol
    status, message = _status(converged, kkt, tol)
    if status:
        warnings.warn(message, RuntimeWarning, stacklevel=2)
    return WeightSolution(weights=weights, cost=cost, n_iter=n_iter, converged=converged,
                          kkt_residual=kkt, rank=min(ranks), status=status, message=message,
                          smoothness=smoothness)


class _Moving:
    """A data-space ``follow`` of :func:`solve_weights` as the smooth solve's: new data
    (either layout of the first data D (T, K)) to linear terms D B, keeping the last."""

    def __init__(self, follow, B, D):
        self.follow, self.B, self.data = follow, B, D

    def __call__(self, w, optimal):
        data = self.follow(w, optimal)
        if data is None:
            return None
        data = as_float_array(data, "data returned by follow", allow_nan=False, copy=False)
        if data.size != self.data.size:
            raise InputError(f"follow must return data of shape {self.data.shape} (or the "
                             f"(frames, markers, 3) layout of it), got shape {data.shape}")
        self.data = data.reshape(self.data.shape)
        return self.data @ self.B


def as_smoothness(value, name: str = "smoothness") -> float | str:
    """``value`` as a finite λ ≥ 0 (float) or one of :data:`fit.solve.gcv.SMOOTHNESS_RULES`.

    Raises
    ------
    InputError
        Anything else, naming `name`.
    """
    if isinstance(value, str):
        if value not in SMOOTHNESS_RULES:
            raise InputError(f"{name} must be a number >= 0 or one of "
                             f"{', '.join(map(repr, SMOOTHNESS_RULES))}, got {value!r}")
        return value
    try:
        lam = float(value)
    except (TypeError, ValueError):
        lam = np.nan
    if isinstance(value, bool) or not np.isfinite(lam) or lam < 0:
        raise InputError(f"{name} must be a finite number >= 0 or one of "
                         f"{', '.join(map(repr, SMOOTHNESS_RULES))}, got {value!r}")
    return lam


#: Frames of a slice of :func:`_cost` and :func:`_rows_times`: a slice's (rows, K) residual
#: stays in cache (one (T, K) residual would take three passes through memory: 2.4x slower
#: on 35,000 frames of 198 rows).
_ROWS = 1024
#: Slices of them a task of the worker threads takes.
_SLICES_PER_TASK = 4


def _cost(weights, B, D, valid):
    """½‖B w_t − d_t‖² over each frame's valid rows, (T,), by slices of ``_ROWS`` frames
    shared among the worker threads."""
    cost = np.empty(len(D))

    def task(first):
        for start in range(first, min(first + _ROWS * _SLICES_PER_TASK, len(D)), _ROWS):
            part = slice(start, start + _ROWS)
            resid = weights[part] @ B.T
            resid -= D[part]
            if valid is not None:
                resid = np.where(valid[part], resid, 0.0)  # NaN where invalid: no product
            cost[part] = 0.5 * np.einsum("ij,ij->i", resid, resid)
    map_on_blas_threads(task, range(0, len(D), _ROWS * _SLICES_PER_TASK))
    return cost


def _rows_times(a, b):
    """``a @ b`` for (T, K) ``a``, one product of ``_ROWS · _SLICES_PER_TASK`` rows a task
    of the worker threads (the same products whatever their number)."""
    out = np.empty((len(a), b.shape[1]))

    def task(first):
        rows = slice(first, first + _ROWS * _SLICES_PER_TASK)
        np.matmul(a[rows], b, out=out[rows])
    map_on_blas_threads(task, range(0, len(a), _ROWS * _SLICES_PER_TASK))
    return out


def _first(frames, count: int = 5) -> str:
    head = ", ".join(str(int(f)) for f in frames[:count])
    return head + (", ..." if len(frames) > count else "")


def _status(converged, kkt, tol):
    bad = np.nonzero(~converged)[0]
    if not bad.size:
        return 0, f"all {len(converged)} frames meet the KKT conditions to {tol:g}"
    return 1, (f"{bad.size} of {len(converged)} frames did not converge (frames "
               f"{_first(bad)}; KKT residual up to {kkt[bad].max():.3g} > tol {tol:g}): "
               "their weights are within the bounds but not optimal")
