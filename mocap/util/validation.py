"""Validation helpers used once, at the public boundary of each function.

Each helper takes the argument's name so that the error says which argument
is wrong, converts the value, and returns it for re-binding::

    positions = as_positions(positions, "positions")
"""

from __future__ import annotations

import numbers

import numpy as np

from mocap.errors import InputError

__all__ = ["as_positions", "as_float_array", "surely_finite", "as_positive_float",
           "as_nonnegative_float", "as_int", "as_choice", "as_fraction"]


def surely_finite(arr: np.ndarray) -> bool:
    """True when every value of `arr` is finite, by one sum (no temporary); False when
    one may not be (a NaN, an inf, or finite values whose sum overflows)."""
    with np.errstate(all="ignore"):
        return bool(np.isfinite(np.add.reduce(arr, axis=None)))


def as_float_array(value, name: str, *, ndim: int | None = None,
                   shape: tuple | None = None, allow_nan: bool = True,
                   copy: bool = True, check_finite: bool = True) -> np.ndarray:
    """Convert `value` to a float64 array and check its dimensions.

    ``shape`` may hold ``None`` for axes of any length. With ``copy=False`` a
    float64 array is returned as it is (not copied). Infinite values, and NaN unless
    `allow_nan`, are refused; ``check_finite=False`` leaves the values to a caller
    that checks them as it uses them (one pass over the data instead of two).
    """
    try:
        arr = np.array(value, dtype=np.float64, copy=True if copy else None)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a numeric array: {exc}") from None
    if ndim is not None and arr.ndim != ndim:
        raise InputError(f"{name} must have {ndim} dimensions, got shape {arr.shape}")
    if shape is not None:
        if arr.ndim != len(shape) or any(
                want is not None and got != want for got, want in zip(arr.shape, shape)):
            want = "(" + ", ".join("any" if s is None else str(s) for s in shape) + ")"
            raise InputError(f"{name} must have shape {want}, got {arr.shape}")
    # only an array that may not be finite needs the exact checks, by the extremes (NaN
    # ignored, no temporary the size of arr) and np.isnan
    if not check_finite or surely_finite(arr):
        return arr
    extremes = [np.fmax.reduce(arr, axis=None), np.fmin.reduce(arr, axis=None)] if arr.size else []
    if np.isinf(extremes).any():
        raise InputError(f"{name} contains infinite values")
    if not allow_nan and np.isnan(arr).any():
        idx = tuple(int(i) for i in np.argwhere(np.isnan(arr))[0])
        raise InputError(f"{name} contains NaN (first at index {idx})")
    return arr


def as_positions(value, name: str = "positions", *, copy: bool = True) -> np.ndarray:
    """Marker positions as a float64 array of shape (n_frames, n_markers, 3), NaN allowed
    (a new one unless ``copy=False`` and `value` already is one)."""
    return as_float_array(value, name, shape=(None, None, 3), copy=copy)


def as_positive_float(value, name: str) -> float:
    """A finite, strictly positive float (a rate, a cut-off, a length)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InputError(f"{name} must be a number, got {value!r}")
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise InputError(f"{name} must be positive and finite, got {value}")
    return value


def as_int(value, name: str, *, minimum: int | None = None) -> int:
    """An integer, optionally at least `minimum`."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise InputError(f"{name} must be an integer, got {value!r}")
    value = int(value)
    if minimum is not None and value < minimum:
        raise InputError(f"{name} must be at least {minimum}, got {value}")
    return value


def as_choice(value, name: str, choices) -> str:
    """One of a module-level set of string options."""
    if value not in choices:
        raise InputError(f"{name} must be one of {sorted(choices)}, got {value!r}")
    return value


def as_nonnegative_float(value, name: str) -> float:
    """A finite float >= 0 (an offset, a smoothing weight, a tolerance)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InputError(f"{name} must be a number, got {value!r}")
    value = float(value)
    if not np.isfinite(value) or value < 0:
        raise InputError(f"{name} must be a finite number >= 0, got {value}")
    return value


def as_fraction(value, name: str) -> float:
    """A float in [0, 1] (a share of frames, a coverage)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InputError(f"{name} must be a number in [0, 1], got {value!r}")
    value = float(value)
    if not 0 <= value <= 1:
        raise InputError(f"{name} must be in [0, 1], got {value}")
    return value
