"""The BLAS's threads: how many it has, and one for the hot paths of many small products.

A batched solve of 53-wide systems or a cache-sized tile of the RBF product is too small
for a threaded BLAS to split: its threads meet at each of thousands of small calls,
which on a loaded 2-core machine made such paths several times slower than on one
thread. They run on one BLAS thread and share their work among as many Python threads
as the BLAS had (:func:`map_on_blas_threads`; numpy releases the GIL in its products and
loops); large single products keep the BLAS's threads. What a second thread gains
depends on how big the calls are: the RBF tiles and the marker-centre evaluation (big
products and passes) share well, the batched box-QP solve hardly at all (its calls are
small enough that taking and handing back the GIL is much of their time; separate
processes would share it).

Where processes of ours keep cores busy beside this one (the report's figure helpers, the
other workers of a local pool), the BLAS leaves those cores to them (:class:`CoresTaken`):
a BLAS thread that has to wait for a busy core holds up every product it shares, and on a
2-core machine with one helper drawing, the report's fits took two to seven times longer
on two BLAS threads than on one.

The Python threads are kept for the process (:func:`shared_pool`): starting a thread and
waiting for it to run cost 0.2-0.7 ms on a virtual machine, which a fit that shares a few
milliseconds of work many times over paid at every call.
"""

from __future__ import annotations

import collections
import functools
import os
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import Future, ThreadPoolExecutor, wait
from contextlib import contextmanager

import scipy.linalg  # noqa: F401  (scipy's own BLAS is loaded before the controller looks)
import threadpoolctl

__all__ = ["CoresTaken", "blas_threads", "finished", "map_on_blas_threads",
           "on_one_blas_thread", "one_blas_thread", "run_beside", "shared_pool",
           "TasksBeside", "worker_threads"]

#: Per thread: the BLAS's threads outside this thread's outermost :func:`one_blas_thread`.
_outside = threading.local()


@functools.cache
def _blas() -> threadpoolctl.ThreadpoolController:
    return threadpoolctl.ThreadpoolController().select(user_api="blas")


def blas_threads() -> int:
    """Threads the BLAS runs a product on now (at least 1)."""
    return max([1, *(lib["num_threads"] for lib in _blas().info())])


def worker_threads() -> int:
    """Python threads that work of many small products may share (at least 1).

    The BLAS's threads, as they were outside the calling thread's outermost
    :func:`one_blas_thread`; 1 in a thread of :func:`shared_pool` (its work is
    already shared, and waiting there for the pool's other threads could wait forever).
    """
    if getattr(_outside, "pooled", False):
        return 1
    threads = getattr(_outside, "threads", None)
    return threads if threads is not None else blas_threads()


@contextmanager
def one_blas_thread():
    """Context manager: the BLAS on one thread inside, its thread count restored after."""
    if getattr(_outside, "threads", None) is not None:     # nested: already on one thread
        yield
        return
    _outside.threads = blas_threads()
    try:
        with _blas().limit(limits=1):
            yield
    finally:
        _outside.threads = None


def map_on_blas_threads(function: Callable, items: Iterable) -> list:
    """``[function(item) for item in items]``, the items shared among :func:`worker_threads`
    Python threads, each product on one BLAS thread.

    For independent pieces of work made of small products (a few thousand frames of a
    batched solve each): split in pieces that do not depend on the thread count, the
    results are the same, bit for bit, on any number of threads. The first error raised
    by `function` (in the order of `items`) is raised here, once every item is done.
    """
    items = list(items)
    workers = min(worker_threads(), len(items))
    with one_blas_thread():
        if workers <= 1:
            return [function(item) for item in items]
        return finished([shared_pool(workers).submit(function, item) for item in items])


def finished(futures: list) -> list:
    """The results of `futures`, once all are done; the first error (in their order) raised.

    Waiting for all before raising keeps work of a failed call from running on behind it.
    """
    wait(futures)
    return [future.result() for future in futures]


def shared_pool(workers: int) -> ThreadPoolExecutor:
    """A pool of `workers` Python threads kept for the process (one per count asked for).

    Its threads see one :func:`worker_threads` (work they are given is not shared again).
    """
    return _kept_pool(workers, "shared")


def _kept_pool(workers: int, use: str) -> ThreadPoolExecutor:
    """The pool of `workers` threads kept for the process for `use`."""
    with _pools_lock:
        pool = _pools.get((workers, use))
        if pool is None:
            pool = _pools[workers, use] = ThreadPoolExecutor(
                workers, thread_name_prefix=f"mocap2mesh-{use}-{workers}", initializer=_pooled)
    return pool


def run_beside(function: Callable, /, *args, **kwargs) -> Future:
    """Start ``function(*args, **kwargs)`` on the process's background thread, beside the
    caller's work (a factorization, a file's text), and return its future.

    A thread kept for the process apart from :func:`shared_pool`'s: work of the pools is
    shared out and waited for (:func:`map_on_blas_threads`, the parts of a file), and a
    long job queued on one of their threads would hold up every call that waits for it.
    Jobs given here run one after another, in order; the thread sees one
    :func:`worker_threads`.
    """
    return _kept_pool(1, "beside").submit(function, *args, **kwargs)


class TasksBeside:
    """Tasks shared between the process's background thread and the caller: the thread
    takes them one by one, in order, while the caller does other work, and
    :meth:`finish` has the caller take the ones still waiting (so that both end about
    together, whichever work was the longer).

    Parameters
    ----------
    tasks : iterable of callable
        Called with no arguments, each once, on either thread; the longest first shares
        best.
    """

    def __init__(self, tasks: Iterable[Callable]):
        self._waiting = collections.deque(tasks)
        self._beside = run_beside(self._take)

    def _take(self) -> None:
        """Run waiting tasks until none is left; after an error, none are run."""
        while True:
            try:
                task = self._waiting.popleft()      # one thread gets each task
            except IndexError:
                return
            try:
                task()
            except BaseException:
                self._waiting.clear()
                raise

    def finish(self) -> None:
        """Run the tasks still waiting here, then wait for the background thread's; the
        first error raised (this thread's, else the background thread's)."""
        try:
            self._take()
        finally:
            self._beside.exception()            # nothing runs on behind an error
        self._beside.result()

    def cancel(self) -> None:
        """Drop the tasks still waiting and wait for the one the background thread runs
        (its error dropped)."""
        self._waiting.clear()
        self._beside.exception()


def _pooled() -> None:
    _outside.pooled = True


#: The pools of :func:`shared_pool` and :func:`run_beside`, by thread count and use; a forked
#: child starts without them (their threads are not in it).
_pools: dict = {}
_pools_lock = threading.Lock()


def _forget_pools() -> None:
    global _pools_lock
    _pools.clear()
    _pools_lock = threading.Lock()


os.register_at_fork(after_in_child=_forget_pools)


def on_one_blas_thread(function):
    """Decorator: run `function` inside :func:`one_blas_thread`."""
    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        with one_blas_thread():
            return function(*args, **kwargs)
    return wrapper


class CoresTaken:
    """While open, the BLAS runs on the threads that `count` cores kept busy elsewhere
    leave (at least one), and so does :func:`map_on_blas_threads`; :meth:`close` gives
    them back. For processes of ours that work beside this one (figure helpers, the other
    workers of a local pool).

    Parameters
    ----------
    count : int
        Cores the other processes keep busy.
    """

    def __init__(self, count: int):
        threads = blas_threads()
        self._limiter = _blas().limit(limits=max(1, threads - count)) \
            if count > 0 and threads > 1 else None

    def close(self) -> None:
        """Give the BLAS back the threads it had (again: nothing)."""
        if self._limiter is not None:
            self._limiter.restore_original_limits()
            self._limiter = None
