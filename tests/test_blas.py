"""One BLAS thread for the hot paths of small products, and the thread count restored."""

from __future__ import annotations

import numpy as np
import threadpoolctl

from fit.solve.weights import solve_weights
from mocap.util.blas import blas_threads, on_one_blas_thread, one_blas_thread


def _two_threads():
    """The BLAS on two threads (the OpenBLAS of numpy's wheels can always be given two)."""
    limits = threadpoolctl.threadpool_limits(2, user_api="blas")
    assert blas_threads() == 2, "the BLAS did not take a limit of two threads"
    return limits


def test_one_thread_inside_and_restored_after():
    with _two_threads():
        assert blas_threads() == 2
        with one_blas_thread():
            assert blas_threads() == 1
        assert blas_threads() == 2
        inside = on_one_blas_thread(blas_threads)
        assert inside() == 1 and blas_threads() == 2


def test_solve_weights_is_the_same_whatever_the_blas_threads():
    rng = np.random.default_rng(3)
    basis = rng.normal(size=(60, 12))
    data = rng.uniform(0, 1, (500, 12)) @ basis.T + 0.05 * rng.normal(size=(500, 60))
    with threadpoolctl.threadpool_limits(1, user_api="blas"):
        one = solve_weights(basis, data, lower=0, upper=1)
    with _two_threads():
        two = solve_weights(basis, data, lower=0, upper=1)
        assert blas_threads() == 2
    np.testing.assert_array_equal(two.weights, one.weights)
