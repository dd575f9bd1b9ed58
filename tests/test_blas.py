"""One BLAS thread for the hot paths of small products, and the thread count restored."""

from __future__ import annotations

import functools
import multiprocessing
import threading

import numpy as np
import pytest
import threadpoolctl
from tolerances import SOLVE_OBJECTIVE_REL, SOLVE_SAME_MINIMIZER

import fit.solve._active_set
import fit.solve.weights
from fit.report.figure_queue import FigureQueue
from fit.solve.weights import solve_weights
from mocap.util.blas import (
    CoresTaken,
    TasksBeside,
    blas_threads,
    map_on_blas_threads,
    on_one_blas_thread,
    one_blas_thread,
    run_beside,
    shared_pool,
    worker_threads,
)
from mocap.util.parallel_writes import write_parts


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


def test_unbounded_solve_shares_its_products_among_threads_with_the_same_bits(monkeypatch):
    """Without bounds the right-hand sides, the product with G⁻¹ and its check, and the costs
    go by blocks of frames on the threads (blocks made small here, so that there are many):
    the same bits on one BLAS thread or two, each frame's least squares (numpy's lstsq) and
    its cost."""
    monkeypatch.setattr(fit.solve._active_set, "_BLOCK", 64)
    monkeypatch.setattr(fit.solve.weights, "_ROWS", 16)
    rng = np.random.default_rng(4)
    basis = rng.normal(size=(45, 9))
    data = rng.normal(size=(700, 45))
    with threadpoolctl.threadpool_limits(1, user_api="blas"):
        one = solve_weights(basis, data)
    with _two_threads():
        two = solve_weights(basis, data)
    for field in ("weights", "cost", "kkt_residual"):
        np.testing.assert_array_equal(getattr(two, field), getattr(one, field))
    assert one.status == 0, one.message
    expected = np.linalg.lstsq(basis, data.T, rcond=None)[0].T
    np.testing.assert_allclose(one.weights, expected, rtol=0, atol=SOLVE_SAME_MINIMIZER)
    residual = data - expected @ basis.T
    np.testing.assert_allclose(one.cost, 0.5 * np.einsum("ij,ij->i", residual, residual),
                               rtol=SOLVE_OBJECTIVE_REL)


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


def test_the_threads_are_kept_and_never_share_again():
    """The same threads serve every call (none is started again); work given to them that
    would share itself again runs in its thread (no wait on a pool whose threads are all
    busy waiting)."""
    meeting = threading.Barrier(2, timeout=30)

    def met(k):
        meeting.wait()                  # both threads of the pool run
        return threading.get_ident()

    with _two_threads():
        first = set(map_on_blas_threads(met, range(2)))
        count = threading.active_count()
        for _ in range(5):
            assert set(map_on_blas_threads(met, range(2))) == first
        assert len(first) == 2 and threading.active_count() == count
        assert shared_pool(2) is shared_pool(2)
        inner = map_on_blas_threads(
            lambda k: (worker_threads(), map_on_blas_threads(lambda j: threading.get_ident(),
                                                             range(3))), range(2))
    for workers, idents in inner:
        assert workers == 1 and len(set(idents)) == 1


def test_work_beside_holds_up_no_shared_work():
    """A long job started beside the caller (a factorization, a file's text) runs on a
    thread of its own: the shared pools' work (a file's parts on two threads, the products
    shared among them) goes on meanwhile and ends first; jobs beside run in order, each
    seeing one worker thread."""
    release = threading.Event()
    order = []

    def long_job():
        assert release.wait(timeout=30), "the shared work waited for the job beside"
        order.append("long")
        return worker_threads()

    with _two_threads():
        job = run_beside(long_job)
        after = run_beside(order.append, "after")
        written = {}
        parts = [(4, bytes([k]) * 4) for k in range(6)]
        assert write_parts(lambda at, data: written.update({at: bytes(data)}), parts,
                           workers=2, part_bytes=4) == 24
        assert b"".join(written[at] for at in sorted(written)) == b"".join(p for _, p in parts)
        assert map_on_blas_threads(lambda k: k * k, range(4)) == [0, 1, 4, 9]
        assert not job.done()
        release.set()
        assert job.result(timeout=30) == 1
        after.result(timeout=30)
    assert order == ["long", "after"]


def test_tasks_beside_are_shared_with_the_caller_once_its_work_is_done():
    """The background thread takes the tasks in order while the caller works; the caller
    then takes those still waiting; each runs once."""
    started, release, ran = threading.Event(), threading.Event(), []

    def first():
        started.set()
        assert release.wait(timeout=30), "the caller did not take the waiting tasks"
        ran.append((0, threading.get_ident()))

    def later(k):
        ran.append((k, threading.get_ident()))
        if k == 3:
            release.set()           # the caller runs the rest while the thread is held

    tasks = TasksBeside([first, *(functools.partial(later, k) for k in range(1, 4))])
    assert started.wait(timeout=30)
    caller = threading.get_ident()
    tasks.finish()
    assert sorted(k for k, _ in ran) == [0, 1, 2, 3]
    assert [k for k, who in ran if who == caller] == [1, 2, 3]
    assert dict(ran)[0] != caller


def test_tasks_beside_stop_at_the_first_error():
    """An error of a task is raised by finish, and no task waiting then runs; cancel drops
    the waiting tasks."""
    ran = []

    def failing():
        raise ValueError("task 1 failed")
    tasks = TasksBeside([failing, functools.partial(ran.append, 2)])
    with pytest.raises(ValueError, match="task 1 failed"):
        tasks.finish()
    assert ran == []
    held, release = threading.Event(), threading.Event()

    def hold():
        held.set()
        assert release.wait(timeout=30)
        ran.append("held")
    tasks = TasksBeside([hold, functools.partial(ran.append, "dropped")])
    assert held.wait(timeout=30)
    threading.Timer(0.05, release.set).start()
    tasks.cancel()
    assert ran == ["held"]


def test_a_forked_child_makes_its_own_threads():
    """A child forked after the threads were started (they are not in it) starts its own."""
    context = multiprocessing.get_context("fork")
    with _two_threads():
        map_on_blas_threads(abs, range(4))
        with context.Pool(1) as pool:
            assert pool.apply(_shared_squares, (6,)) == [k * k for k in range(6)]


def _shared_squares(n):
    with threadpoolctl.threadpool_limits(2, user_api="blas"):
        return map_on_blas_threads(lambda k: k * k, range(n))


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

    done = []

    def first_fails(k):
        if k == 0:
            raise ValueError("item 0")
        threading.Event().wait(0.02)
        done.append(k)

    with _two_threads(), pytest.raises(ValueError, match="item 0"):
        map_on_blas_threads(first_fails, range(6))
    assert sorted(done) == [1, 2, 3, 4, 5]          # every item done before the error


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
