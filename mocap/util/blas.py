"""The BLAS's threads: how many it has, and one for the hot paths of many small products.

A batched solve of 53-wide systems or a cache-sized tile of the RBF product is too small
for a threaded BLAS to split: its threads meet at each of thousands of small calls,
which on a loaded 2-core machine made such paths several times slower than on one
thread. They run on one BLAS thread (and share their work among Python threads where
they can, as the RBF tiles do); large single products keep the BLAS's threads.
"""

from __future__ import annotations

import functools

import scipy.linalg  # noqa: F401  (scipy's own BLAS is loaded before the controller looks)
import threadpoolctl

__all__ = ["blas_threads", "on_one_blas_thread", "one_blas_thread"]


@functools.cache
def _blas() -> threadpoolctl.ThreadpoolController:
    return threadpoolctl.ThreadpoolController().select(user_api="blas")


def blas_threads() -> int:
    """Threads the BLAS runs a product on now (at least 1)."""
    return max([1, *(lib["num_threads"] for lib in _blas().info())])


def one_blas_thread():
    """Context manager: the BLAS on one thread inside, its thread count restored after."""
    return _blas().limit(limits=1)


def on_one_blas_thread(function):
    """Decorator: run `function` inside :func:`one_blas_thread`."""
    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        with one_blas_thread():
            return function(*args, **kwargs)
    return wrapper
