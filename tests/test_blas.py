"""One BLAS thread for the hot paths of small products, and the thread count restored."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import threadpoolctl

import fit.solve._active_set
from fit.report.figure_queue import FigureQueue
from fit.solve.weights import solve_weights
from mocap.util.blas import (
    CoresTaken,
    blas_threads,
    map_on_blas_threads,
    on_one_blas_thread,
    one_blas_thread,
    worker_threads,
)


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


def test_work_is_shared_among_python_threads_each_on_one_blas_thread():
    """With a BLAS of two threads, two items run at once (a barrier of two is passed), each
    with the BLAS on one thread and no further sharing inside; results in order."""
    meeting = threading.Barrier(2, timeout=30)
    seen = []

    def item(k):
        meeting.wait()                  # raises BrokenBarrierError unless two run at once
        seen.append((threading.get_ident(), blas_threads(), worker_threads()))
        return k * k

    with _two_threads():
        assert worker_threads() == 2
        assert map_on_blas_threads(item, range(4)) == [0, 1, 4, 9]
        assert blas_threads() == 2
    assert len({ident for ident, _, _ in seen}) == 2
    assert all(blas == 1 and workers == 1 for _, blas, workers in seen)


def test_one_blas_thread_runs_the_work_in_the_calling_thread():
    caller = threading.get_ident()
    with threadpoolctl.threadpool_limits(1, user_api="blas"):
        assert map_on_blas_threads(lambda k: (k, threading.get_ident()), range(3)) == \
            [(k, caller) for k in range(3)]


def test_an_error_of_the_work_is_raised_and_the_threads_restored():
    def item(k):
        if k == 2:
            raise ValueError("item 2")
        return k

    with _two_threads():
        with pytest.raises(ValueError, match="item 2"):
            map_on_blas_threads(item, range(4))
        assert blas_threads() == 2 and worker_threads() == 2


def test_many_blocks_of_frames_solve_to_the_same_bits_on_any_threads(monkeypatch):
    """The solver's blocks of frames are shared among threads: the same weights as on one."""
    monkeypatch.setattr(fit.solve._active_set, "_BLOCK", 64)              # 8 blocks
    rng = np.random.default_rng(4)
    basis = rng.normal(size=(60, 12))
    data = rng.uniform(-0.2, 1.2, (500, 12)) @ basis.T + 0.05 * rng.normal(size=(500, 60))
    with threadpoolctl.threadpool_limits(1, user_api="blas"):
        one = solve_weights(basis, data, lower=0, upper=1)
    with _two_threads():
        two = solve_weights(basis, data, lower=0, upper=1)
    assert one.status == 0, one.message
    np.testing.assert_array_equal(two.weights, one.weights)
    np.testing.assert_array_equal(two.n_iter, one.n_iter)


def test_cores_taken_by_other_processes_are_left_to_them():
    """With cores busy elsewhere the BLAS and the work shared among Python threads use the
    rest, never fewer than one; closing gives them back, once."""
    with threadpoolctl.threadpool_limits(4, user_api="blas"):
        assert blas_threads() == 4, "the BLAS did not take a limit of four threads"
        taken = CoresTaken(1)
        assert blas_threads() == 3 and worker_threads() == 3
        taken.close()
        assert blas_threads() == 4
        taken.close()
        assert blas_threads() == 4
        taken = CoresTaken(9)
        assert blas_threads() == 1 and worker_threads() == 1
        assert map_on_blas_threads(lambda k: threading.get_ident(), range(3)) == \
            [threading.get_ident()] * 3
        taken.close()
        CoresTaken(0)
        assert blas_threads() == 4


def test_a_figure_queue_leaves_its_helpers_cores_to_them():
    with _two_threads():
        with FigureQueue(helpers=1) as figures:
            assert blas_threads() == 2 - figures.helpers
        assert blas_threads() == 2
        with FigureQueue(helpers=0):
            assert blas_threads() == 2
