"""Radial kernels and polynomial tails for :mod:`mocap.retarget.rbf`.

Every kernel is a vectorized function of the scaled distance ``r = epsilon *
distance``. The global kernels follow the sign conventions of
``scipy.interpolate.RBFInterpolator`` so that each is (conditionally)
positive definite of the order its minimum polynomial degree implies. The
compact kernels vanish for ``r >= 1``: their support radius is ``1/epsilon``.
"""

from __future__ import annotations

from itertools import combinations_with_replacement

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

__all__ = ["KERNELS", "SCALE_INVARIANT", "COMPACT_KERNELS", "MIN_DEGREE",
           "evaluate", "monomial_powers", "polynomial_matrix",
           "compact_kernel_matrix"]

#: Every kernel name :func:`mocap.retarget.rbf.build_rbf_operator` accepts.
KERNELS = ("linear", "thin_plate_spline", "cubic", "quintic", "multiquadric",
           "inverse_multiquadric", "inverse_quadratic", "gaussian",
           "wendland_c2", "bspline_bell")

#: Kernels whose shape parameter only rescales the smoothing (epsilon defaults to 1).
SCALE_INVARIANT = ("linear", "thin_plate_spline", "cubic", "quintic")

#: Kernels with compact support ``r < 1``, used without a polynomial term.
COMPACT_KERNELS = ("wendland_c2", "bspline_bell")

#: Minimum polynomial degree of the conditionally positive definite kernels
#: (Fasshauer, *Meshfree Approximation Methods with MATLAB*, ch. 8; as scipy).
MIN_DEGREE = {"multiquadric": 0, "linear": 0, "thin_plate_spline": 1,
              "cubic": 1, "quintic": 2}


def _thin_plate_spline(r):
    return r ** 2 * np.log(np.where(r == 0.0, 1.0, r))


def _wendland_c2(r):
    # Wendland's phi_{3,1}: positive definite in up to 3 dimensions.
    s = np.clip(1.0 - r, 0.0, None)
    return s ** 4 * (4.0 * r + 1.0)


def _bspline_bell(r):
    # Cubic B-spline on [-2, 2] evaluated at u = 2 r, scaled so that phi(0) = 1.
    u = 2.0 * r
    inner = 1.0 - 1.5 * u ** 2 + 0.75 * u ** 3
    outer = 0.25 * np.clip(2.0 - u, 0.0, None) ** 3
    return np.where(u < 1.0, inner, outer)


_FUNCTIONS = {
    "linear": lambda r: -r,
    "thin_plate_spline": _thin_plate_spline,
    "cubic": lambda r: r ** 3,
    "quintic": lambda r: -r ** 5,
    "multiquadric": lambda r: -np.sqrt(r ** 2 + 1.0),
    "inverse_multiquadric": lambda r: 1.0 / np.sqrt(r ** 2 + 1.0),
    "inverse_quadratic": lambda r: 1.0 / (r ** 2 + 1.0),
    "gaussian": lambda r: np.exp(-r ** 2),
    "wendland_c2": _wendland_c2,
    "bspline_bell": _bspline_bell,
}


def evaluate(kernel: str, r) -> np.ndarray:
    """Kernel `kernel` at scaled distances `r` (any shape, ``r >= 0``)."""
    return _FUNCTIONS[kernel](np.asarray(r, dtype=np.float64))


def monomial_powers(ndim: int, degree: int) -> np.ndarray:
    """Exponents (n_monomials, ndim) of every monomial of total degree <= `degree`."""
    rows = []
    for deg in range(degree + 1):
        for combo in combinations_with_replacement(range(ndim), deg):
            rows.append(np.bincount(np.asarray(combo, dtype=np.int64), minlength=ndim))
    return np.asarray(rows, dtype=np.int64).reshape(len(rows), ndim)


def polynomial_matrix(x: np.ndarray, powers: np.ndarray) -> np.ndarray:
    """Monomials with exponents `powers` (R, ndim) at points `x` (P, ndim) -> (P, R)."""
    return np.prod(x[:, None, :] ** powers[None, :, :], axis=-1)


def compact_kernel_matrix(kernel: str, x: np.ndarray, y: np.ndarray,
                          epsilon: float) -> sp.csr_array:
    """Sparse (len(x), len(y)) matrix of a compact kernel, pairs found with a k-d tree.

    Only pairs closer than the support radius ``1/epsilon`` are stored
    (coincident points included: the kernel is 1 there).
    """
    radius = 1.0 / epsilon
    neighbours = cKDTree(y).query_ball_point(x, radius, return_sorted=False)
    counts = np.fromiter((len(n) for n in neighbours), dtype=np.int64, count=len(x))
    rows = np.repeat(np.arange(len(x)), counts)
    cols = (np.concatenate([np.asarray(n, dtype=np.int64) for n in neighbours])
            if counts.sum() else np.zeros(0, dtype=np.int64))
    values = evaluate(kernel, epsilon * np.linalg.norm(x[rows] - y[cols], axis=1))
    keep = values != 0.0
    return sp.csr_array((values[keep], (rows[keep], cols[keep])), shape=(len(x), len(y)))
