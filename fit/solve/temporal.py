"""Temporal filtering of a take: moving average, and temporally smooth weights.

:func:`moving_average` is the gestures paper's centred 41-frame average of the
markers before the weights are solved. :func:`solve_smooth` (used by
``solve_weights(..., smoothness=λ)``) couples the frames' weight problems with
a penalty on frame-to-frame changes and solves the whole sequence exactly.

References
----------
Ju & Lee, "Facial gestures from motion capture", sec. 4.1 (window 2k + 1 = 41).
"""

from __future__ import annotations

import numpy as np

from fit.solve._active_set import BoxQP, kkt_residual
from fit.solve._smooth import Follow, Spectrum, bounded, gradient, unbounded
from mocap.errors import InputError
from mocap.util.validation import as_choice, as_float_array, as_int

__all__ = ["moving_average", "solve_smooth", "EDGE_MODES"]

#: How :func:`moving_average` treats the frames beyond either end of the take:
#: ``"shrink"`` averages over the part of the window inside the take,
#: ``"nearest"`` repeats the first (last) frame beyond the start (end).
EDGE_MODES = ("shrink", "nearest")


def moving_average(data, *, window: int = 41, edge: str = "shrink") -> np.ndarray:
    """Centred moving average along the frame axis, ignoring NaN.

    Parameters
    ----------
    data : array_like, shape (n_frames, ...)
        Any per-frame data, e.g. markers (n_frames, n_markers, 3) in mm.
    window : int, default 41
        Odd number of frames averaged (the paper's 2k + 1 = 41).
    edge : {"shrink", "nearest"}
        See :data:`EDGE_MODES`.

    Returns
    -------
    ndarray, same shape as `data`
        Frame t holds the mean of the non-NaN samples of frames t - k .. t + k.
        NaN policy: NaN samples are left out of the mean; the output is NaN
        only where the whole window is NaN.

    Examples
    --------
    >>> moving_average([1.0, 2.0, float("nan"), 4.0], window=3).tolist()
    [1.5, 1.5, 3.0, 4.0]
    """
    data = as_float_array(data, "data")
    window = as_int(window, "window", minimum=1)
    edge = as_choice(edge, "edge", EDGE_MODES)
    if window % 2 == 0:
        raise InputError(f"window must be an odd number of frames, got {window}")
    if data.ndim == 0 or data.shape[0] == 0:
        raise InputError(f"data must have at least one frame, got shape {data.shape}")
    half = window // 2
    pad = [(half, half)] + [(0, 0)] * (data.ndim - 1)
    padded = (np.pad(data, pad, mode="edge") if edge == "nearest"
              else np.pad(data, pad, constant_values=np.nan))
    valid = ~np.isnan(padded)
    sums = _window_sums(np.where(valid, padded, 0.0), window)
    counts = _window_sums(valid.astype(np.float64), window)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(counts > 0, sums / counts, np.nan)


def _window_sums(values: np.ndarray, window: int) -> np.ndarray:
    """Sums of `window` consecutive frames (axis 0), len(values) - window + 1 of them."""
    cum = np.cumsum(values, axis=0)
    cum = np.concatenate([np.zeros_like(cum[:1]), cum])
    return cum[window:] - cum[:-window]


def solve_smooth(qp: BoxQP, c: np.ndarray, smoothness: float, *, tol: float,
                 max_iter: int, start: np.ndarray | None = None,
                 follow: Follow | None = None):
    """Minimize Σ_t ½ w_tᵀG w_t − c_tᵀw_t + ½ λ Σ_t ‖w_t − w_{t−1}‖² in the box.

    Parameters
    ----------
    qp : BoxQP
        G (n, n) and the bounds.
    c : ndarray, shape (T, n)
        Linear terms Bᵀd_t.
    smoothness : float
        λ > 0.
    tol, max_iter :
        KKT tolerance and limit of global iterations (bounded case).
    start : ndarray, shape (T, n), optional
        Weights whose active set starts the bounded iteration (e.g. the
        solution of a nearby problem); default: a rough ADMM solution.
    follow : callable, optional
        ``follow(w, optimal) -> c or None``: after every global solve, the
        linear terms of the next one, from its weights (T, n) and whether every
        frame meets the KKT conditions; None stops. The problem moves while it
        is solved (the chord steps of the exact marker-centre fit), see
        :func:`fit.solve._smooth.bounded`. Without bounds every solve is optimal.

    Returns
    -------
    weights (T, n), n_iter (T,), kkt (T,), converged (T,)
        ``n_iter`` counts the reduced solves each frame took part in; ``kkt``
        and ``converged`` are of the last linear terms (`c`, or the last ones
        `follow` returned).

    Notes
    -----
    The Hessian is I_T ⊗ G + λ L ⊗ I_n, with L the path-graph Laplacian.
    Unbounded: L = Q diag(μ) Qᵀ with Q the orthonormal DCT-II and
    μ_k = 4 sin²(πk / 2T), and G = V Λ Vᵀ, so the system diagonalizes exactly:
    W = Q [(Qᵀ C V)_kj / (Λ_j + λ μ_k)] Vᵀ (a pseudo-inverse where the
    denominator vanishes, i.e. for a rank-deficient G). Bounded: a primal-dual
    active-set iteration on the whole sequence from the active set of
    `start` or a rough ADMM solution, each global step one banded (bandwidth n)
    positive-definite solve of the reduced system, with state changes
    settled in windows around them between global steps
    (:mod:`fit.solve._smooth`); stopped when every frame meets the KKT conditions,
    or reported unconverged when the active set cycles or `max_iter` is
    reached. The banded matrix holds (n + 1) · T · n floats. A rank-deficient
    G gets a ridge of ``RANK_RTOL · λ_max(G)`` in this case only (the solve
    needs a definite system).
    """
    spectrum = Spectrum.build(qp.G, len(c))
    if not (np.isfinite(qp.lo).any() or np.isfinite(qp.hi).any()):
        n_iter = np.zeros(len(c), np.int64)
        for iteration in range(max_iter):
            w = unbounded(spectrum, spectrum.transform(c), smoothness)
            n_iter += 1
            following = None if follow is None or iteration == max_iter - 1 \
                else follow(w, True)
            if following is None:
                break
            c = following
    else:
        w, n_iter, c = bounded(qp, spectrum, c, smoothness, tol, max_iter, start, follow)
    g, scale = gradient(qp.G, c, smoothness, w)
    kkt = kkt_residual(w, g, scale, qp.lo, qp.hi)
    return w, n_iter, kkt, kkt <= tol
