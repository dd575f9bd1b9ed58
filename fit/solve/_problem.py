"""Validation of a weight-solving problem: the basis and data in either layout, and the bounds.

Shared by :func:`fit.solve.weights.solve_weights` and
:func:`fit.solve.sampling_estimator.estimate_weights_by_sampling`, so that both
take the same arguments and refuse them with the same messages.
"""

from __future__ import annotations

import numpy as np

from mocap.errors import InputError
from mocap.util.validation import as_float_array, surely_finite

__all__ = ["as_problem", "as_bounds"]


def as_problem(basis, data, mask):
    """B (K, n), D (T, K) and the valid rows (T, K) or None, from either layout.

    B and D are only read: a float64 argument is used as it is, not copied.
    """
    basis = as_float_array(basis, "basis", allow_nan=False, copy=False)
    # checked below, NaN by frame (one sum when the data are finite)
    data = as_float_array(data, "data", copy=False, check_finite=False)
    if basis.ndim == 3:
        if basis.shape[2] != 3 or data.ndim != 3 or data.shape[1:] != basis.shape[1:]:
            raise InputError(f"with basis of shape (n_shapes, n_markers, 3) = {basis.shape}, "
                             f"data must be (n_frames, {basis.shape[1]}, 3), got {data.shape}")
        B = basis.reshape(len(basis), -1).T
        D = data.reshape(len(data), -1)
    elif basis.ndim == 2:
        if data.ndim != 2 or data.shape[1] != basis.shape[0]:
            raise InputError(f"with basis of shape (K, n_shapes) = {basis.shape}, data "
                             f"must be (n_frames, {basis.shape[0]}), got {data.shape}")
        B, D = basis, data
    else:
        raise InputError(f"basis must be (K, n_shapes) or (n_shapes, n_markers, 3), "
                         f"got shape {basis.shape}")
    if B.shape[1] == 0 or len(D) == 0:
        raise InputError(f"need at least one shape and one frame, got basis {basis.shape} "
                         f"and data {data.shape}")
    valid = None
    if mask is not None:
        valid = np.array(mask, dtype=bool)
        if valid.shape == data.shape[:2] and data.ndim == 3:
            valid = np.repeat(valid, 3, axis=1)
        if valid.shape != D.shape:
            raise InputError(f"mask must have shape {data.shape[:2]}, got {np.shape(mask)}")
    if surely_finite(D):
        return B, D, valid
    if np.isinf(D).any():
        raise InputError("data contains infinite values")
    bad = np.isnan(D) if valid is None else np.isnan(D) & valid
    if bad.any():
        frame, row = (int(i) for i in np.argwhere(bad)[0])
        raise InputError(f"data is NaN in frame {frame} (row {row}, marker {row // 3}): "
                         "pass mask=False there to leave missing markers out")
    return B, D, valid


def as_bounds(lower, upper, n):
    """Lower and upper bounds as (n,) float arrays, ±inf allowed, lower ≤ upper."""
    bounds = []
    for name, value in (("lower", lower), ("upper", upper)):
        try:
            arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (n,)).copy()
        except (TypeError, ValueError):
            raise InputError(f"{name} must be a number or an array of {n} bounds, "
                             f"got {value!r}") from None
        if np.isnan(arr).any():
            raise InputError(f"{name} contains NaN (shape {int(np.argmax(np.isnan(arr)))})")
        bounds.append(arr)
    lo, hi = bounds
    wrong = np.nonzero((lo > hi) | (lo == np.inf) | (hi == -np.inf))[0]
    if wrong.size:
        i = int(wrong[0])
        raise InputError(f"bounds of shape {i} are empty or infinite on the wrong side: "
                         f"lower {lo[i]} > upper {hi[i]}, or lower = +inf, or upper = -inf")
    return lo, hi
