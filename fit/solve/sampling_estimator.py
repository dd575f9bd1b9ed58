"""The gestures paper's approximate weight estimator: random samples and a kd-tree.

Ju & Lee draw random weight vectors within the bounds, image them through the
basis, and estimate a frame's weights as the inverse-distance-weighted mean of
the weights of its k nearest images. It is kept to compare with the exact
solver (:func:`fit.solve.weights.solve_weights`): its weights are feasible (a convex
combination of feasible samples), so its error is never below the exact one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from fit.solve._problem import as_bounds, as_problem
from mocap.errors import InputError
from mocap.util.validation import as_int

__all__ = ["SamplingEstimate", "estimate_weights_by_sampling"]


@dataclass(frozen=True)
class SamplingEstimate:
    """Weights estimated by sampling.

    Attributes
    ----------
    weights : ndarray, shape (n_frames, n_shapes)
        Within the bounds.
    cost : ndarray, shape (n_frames,)
        ½‖B w_t − d_t‖², data units squared (same convention as ``WeightSolution``).
    distance : ndarray, shape (n_frames,)
        Distance from each frame to its nearest sample image, data units.
    status : int
        Always 0 (the estimate has no convergence to fail).
    message : str
    """

    weights: np.ndarray
    cost: np.ndarray
    distance: np.ndarray
    status: int
    message: str

    @property
    def smoothness(self) -> float:
        """Always 0: frames are estimated one by one (as ``WeightSolution.smoothness``)."""
        return 0.0


def estimate_weights_by_sampling(basis, data, *, lower=0.0, upper=1.0,
                                 n_samples: int = 1000, n_neighbors: int = 60,
                                 seed=0) -> SamplingEstimate:
    """Estimate weights from the k nearest of random samples (Ju & Lee, sec. 4.1).

    Parameters
    ----------
    basis, data : array_like
        As in :func:`fit.solve.weights.solve_weights` (either layout); no NaN.
    lower, upper : float or array_like of shape (n_shapes,)
        Finite bounds; samples are uniform in the box (paper: -ε and 1 + ε).
    n_samples : int, default 1000
        Random weight samples (paper: 1000).
    n_neighbors : int, default 60
        Nearest sample images averaged (paper: 60), at most `n_samples`.
    seed : int or numpy.random.Generator, default 0
        Seed of the samples; the result is deterministic for a given seed.

    Returns
    -------
    SamplingEstimate

    Raises
    ------
    InputError
        Infinite bounds, NaN in data, n_neighbors > n_samples.

    Notes
    -----
    With the k nearest images F_k of frame d at distances r_k, the estimate is
    Σ_k a_k c_k with a_k ∝ 1 / r_k, Σ a_k = 1 (a frame that coincides with a
    sample takes that sample's weights). The kd-tree query is exact
    (scipy.spatial.cKDTree), where the paper used approximate search (ANN).
    """
    B, D, _ = as_problem(basis, data, None)
    n = B.shape[1]
    lo, hi = as_bounds(lower, upper, n)
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        raise InputError("the sampling estimator needs finite lower and upper bounds "
                         "to draw samples from")
    n_samples = as_int(n_samples, "n_samples", minimum=1)
    n_neighbors = as_int(n_neighbors, "n_neighbors", minimum=1)
    if n_neighbors > n_samples:
        raise InputError(f"n_neighbors ({n_neighbors}) must not exceed n_samples ({n_samples})")
    rng = np.random.default_rng(seed)
    samples = lo + (hi - lo) * rng.random((n_samples, n))
    tree = cKDTree(samples @ B.T)
    dist, idx = tree.query(D, k=n_neighbors)
    dist, idx = dist.reshape(len(D), -1), idx.reshape(len(D), -1)
    exact = dist[:, :1] == 0.0
    with np.errstate(divide="ignore"):
        inv = np.where(exact, (dist == 0.0).astype(float), 1.0 / dist)
    share = inv / inv.sum(axis=1, keepdims=True)
    weights = np.clip(np.einsum("tk,tkn->tn", share, samples[idx]), lo, hi)
    cost = 0.5 * np.sum((weights @ B.T - D) ** 2, axis=1)
    return SamplingEstimate(weights=weights, cost=cost, distance=dist[:, 0], status=0,
                            message=f"{n_neighbors} nearest of {n_samples} samples")
