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
import scipy.fft
import scipy.linalg

from mocap._validation import as_choice, as_float_array, as_int
from mocap.errors import InputError

from ._active_set import RANK_RTOL, BoxQP, kkt_residual

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
                 max_iter: int, start: np.ndarray):
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
        KKT tolerance and iteration limit (bounded case).
    start : ndarray, shape (T, n)
        Per-frame solution whose active set starts the bounded iteration.

    Returns
    -------
    weights (T, n), n_iter (T,), kkt (T,), converged (T,)

    Notes
    -----
    The Hessian is I_T ⊗ G + λ L ⊗ I_n, with L the path-graph Laplacian.
    Unbounded: L = Q diag(μ) Qᵀ with Q the orthonormal DCT-II and
    μ_k = 4 sin²(πk / 2T), and G = V Λ Vᵀ, so the system diagonalizes exactly:
    W = Q [(Qᵀ C V)_kj / (Λ_j + λ μ_k)] Vᵀ (a pseudo-inverse where the
    denominator vanishes, i.e. for a rank-deficient G). Bounded: a primal-dual
    active-set iteration on the whole sequence, each step one banded
    (bandwidth n) positive-definite solve of the reduced system, stopped when
    every frame meets the KKT conditions, or reported unconverged when the
    active set cycles or `max_iter` is reached. The banded matrix holds
    (n + 1) · T · n floats. A rank-deficient G gets a ridge of
    ``RANK_RTOL · λ_max(G)`` in this case only (the solve needs a definite system).
    """
    T, n = c.shape
    if not (np.isfinite(qp.lo).any() or np.isfinite(qp.hi).any()):
        w = _unbounded(qp, c, smoothness)
        n_iter = np.ones(T, np.int64)
    else:
        w, n_iter = _bounded(qp, c, smoothness, tol, max_iter, start)
    g, scale = _gradient(qp.G, c, smoothness, w)
    kkt = kkt_residual(w, g, scale, qp.lo, qp.hi)
    return w, n_iter, kkt, kkt <= tol


def _laplacian(w: np.ndarray) -> np.ndarray:
    """L w over frames (axis 0): deg_t w_t − w_{t−1} − w_{t+1}."""
    out = np.zeros_like(w)
    diff = np.diff(w, axis=0)
    out[:-1] -= diff
    out[1:] += diff
    return out


def _gradient(G, c, lam, w):
    """Gradient of the sequence objective and the magnitude of its terms, (T, n) each."""
    grad = w @ G - c + lam * _laplacian(w)
    a = np.abs(w)
    near = np.zeros_like(a)
    near[1:] += a[:-1]
    near[:-1] += a[1:]
    deg = np.full((len(w), 1), 2.0)
    deg[[0, -1]] = 1.0 if len(w) > 1 else 0.0
    scale = a @ np.abs(G) + np.abs(c) + lam * (deg * a + near)
    return grad, scale


def _unbounded(qp: BoxQP, c, lam):
    T = len(c)
    eig, vec = np.linalg.eigh(qp.G)
    mu = 4.0 * np.sin(np.pi * np.arange(T) / (2 * T)) ** 2
    denom = eig[None, :] + lam * mu[:, None]
    floor = RANK_RTOL * max(eig[-1], np.finfo(float).tiny)
    safe = np.where(denom > floor, denom, 1.0)
    spectral = scipy.fft.dct(c @ vec, type=2, norm="ortho", axis=0)
    spectral = np.where(denom > floor, spectral / safe, 0.0)
    return scipy.fft.idct(spectral, type=2, norm="ortho", axis=0) @ vec.T


def _banded(G, lam, free, ridge):
    """Upper banded storage (n + 1, T·n) of the reduced sequence Hessian."""
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


def _bounded(qp: BoxQP, c, lam, tol, max_iter, start):
    T, n = c.shape
    ridge = RANK_RTOL * np.linalg.eigvalsh(qp.G)[-1] if qp.singular else 0.0
    state = np.where(start <= qp.lo, -1, np.where(start >= qp.hi, 1, 0)).astype(np.int8)
    state[:, qp.fixed] = -1
    seen = {state.tobytes()}
    for it in range(1, max_iter + 1):
        free = state == 0
        fixed_part = qp.bound_values(state)
        grad_fixed = fixed_part @ qp.G + lam * _laplacian(fixed_part)
        rhs = np.where(free, c - grad_fixed, 0.0).ravel()
        step = scipy.linalg.solveh_banded(_banded(qp.G, lam, free, ridge), rhs)
        w = fixed_part + np.where(free, step.reshape(T, n), 0.0)
        g, scale = _gradient(qp.G, c, lam, w)
        if (kkt_residual(w, g, scale, qp.lo, qp.hi) <= tol).all():
            break
        new = state.copy()
        new[free & (w < qp.lo)] = -1
        new[free & (w > qp.hi)] = 1
        new[((state == -1) & (g < 0)) | ((state == 1) & (g > 0))] = 0
        new[:, qp.fixed] = -1
        key = new.tobytes()
        if key in seen:
            break
        seen.add(key)
        state = new
    return np.clip(w, qp.lo, qp.hi), np.full(T, it, np.int64)
