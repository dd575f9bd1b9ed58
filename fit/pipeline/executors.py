"""Where the takes of a session run: a local process pool, a Dask cluster, or any executor.

:func:`open_executor` turns what the user asked for into a
:class:`SessionExecutor`, whose :meth:`~SessionExecutor.map_unordered` runs
``task(job, shared)`` for every job and yields a :class:`TaskOutcome` as each
one ends, in completion order. Whatever ends a job is an outcome, never an
exception in the driver: the task raised, the worker process died (signal,
out of memory), Dask gave up on it (``KilledWorker``), or it ran past the
per-job timeout. The others go on.

- ``"local"``: one fresh process per job, at most `workers` at a time
  (``workers=1`` without a timeout: in this process). A job past its timeout is
  killed with its process; a process that dies is reported with its signal;
  every process exits when the driver does, even when the driver is killed.
- ``"dask"``: one task per job on a :class:`distributed.Client`, connected
  to the scheduler at `scheduler`, or to a :class:`distributed.LocalCluster`
  of `workers` single-threaded worker processes started here and stopped on
  :meth:`~SessionExecutor.close`. `shared` is sent once, as the result of a
  task of its own that every job depends on (fetched once per worker, and
  recomputed if the workers holding it die).
  Results are waited for with Dask's own ``as_completed`` (Dask futures do not
  work with the standard library's, dask/distributed#3695). A job past its
  timeout is cancelled and the worker running it restarted (Dask cannot stop
  a running task otherwise); Dask reschedules the other tasks that worker held.
- any object with ``submit(fn, *args) -> future`` (a
  :class:`concurrent.futures.ProcessPoolExecutor`, a Dask client's
  ``get_executor()``, submitit's ``AutoExecutor``): used as it is, never shut
  down here. A job past its timeout is cancelled where the executor can and
  reported; the executor may still finish it in the background.

Jobs are handed out as workers free up (never more in flight than the
executor has slots). A job's timeout counts from when it starts running (the
local worker and the Dask task say so), not from when the session started; a
caller's executor cannot say, so there it counts from the submission.
"""

from __future__ import annotations

import gc
import importlib.util
import os
import time
import traceback
from collections import deque
from concurrent import futures as std_futures

from fit.pipeline._executor_base import (
    SessionExecutor,
    TaskOutcome,
    raised,
    timed_out,
    timeout_seconds,
)
from fit.pipeline._local_executor import LocalExecutor
from mocap.errors import InputError
from mocap.util.validation import as_choice, as_int

__all__ = ["EXECUTORS", "DASK_MISSING", "DASK_WORKER_CONFIG", "TaskOutcome", "SessionExecutor",
           "LocalExecutor", "FuturesExecutor", "DaskExecutor", "open_executor"]

#: The executors :func:`open_executor` builds from a name.
EXECUTORS = ("local", "dask")
#: The one line said when ``executor="dask"`` is asked for without Dask installed.
DASK_MISSING = ("executor 'dask' needs dask.distributed: pip install 'mocap2mesh[dask]' "
                "(or: pip install 'dask[distributed]')")
#: Dask configuration of the workers of the LocalCluster a run starts. Without the nanny's
#: ``MALLOC_TRIM_THRESHOLD_`` (None unsets it), which also fixes glibc's mmap threshold,
#: glibc reuses the memory of a take's large arrays instead of mapping each afresh (a take
#: ran about 30% slower with it); without the profiler, which samples the task's thread
#: every 10 ms, the report's figures (Python-heavy matplotlib) keep the GIL (a take's
#: report ran 20% slower with it). Workers of your own take the same from a Dask
#: configuration file.
DASK_WORKER_CONFIG = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
                      "distributed.worker.profile.enabled": False}
_POLL = 0.05            # s between looks at Dask futures while timeouts run
_RECHECK = 0.25         # s between looks for jobs that started, while timeouts run


def _from_dask(obj) -> bool:
    """True for Dask's objects (futures, clients), told without importing Dask."""
    return type(obj).__module__.split(".")[0] == "distributed"


class _StandardWaiter:
    """Completion of standard-library futures."""

    def __init__(self):
        self.pending = set()

    def add(self, future) -> None:
        self.pending.add(future)

    def done(self, timeout: float | None) -> list:
        done, self.pending = std_futures.wait(self.pending, timeout,
                                              return_when=std_futures.FIRST_COMPLETED)
        return list(done)

    def discard(self, future) -> None:
        self.pending.discard(future)


class _DaskWaiter:
    """Completion of Dask futures, through :class:`distributed.as_completed`."""

    def __init__(self):
        from distributed import as_completed
        self.completed = as_completed()
        self.dropped = set()

    def add(self, future) -> None:
        self.completed.add(future)

    def done(self, timeout: float | None) -> list:
        if timeout is None:
            batch = self.completed.next_batch(block=True)
        else:
            deadline = time.monotonic() + timeout
            while not self.completed.has_ready() and time.monotonic() < deadline:
                time.sleep(_POLL)
            batch = self.completed.next_batch(block=False)
        kept = [f for f in batch if f.key not in self.dropped]
        self.dropped.difference_update(f.key for f in batch)
        return kept

    def discard(self, future) -> None:
        self.dropped.add(future.key)


class FuturesExecutor(SessionExecutor):
    """Jobs submitted to an executor the caller owns (``submit(fn, *args) -> future``).

    Parameters
    ----------
    executor : object
        A :class:`concurrent.futures.Executor`, a Dask ``Client`` or its
        ``get_executor()``, submitit's executors... It is not shut down here.
    slots : int, optional
        Jobs in flight at once (default: the executor's ``_max_workers`` or
        the Dask cluster's threads, else 1), so that a job's timeout counts
        from its start.

    Examples
    --------
    >>> from concurrent.futures import ThreadPoolExecutor
    >>> with ThreadPoolExecutor(2) as pool:
    ...     sorted(o.result for o in FuturesExecutor(pool).map_unordered(pow, [2, 3], shared=2))
    [4, 9]
    """

    def __init__(self, executor, *, slots: int | None = None):
        if not callable(getattr(executor, "submit", None)):
            raise InputError(f"executor must have a submit(fn, *args) method (a "
                             f"concurrent.futures.Executor, a Dask client...), got "
                             f"{type(executor).__name__}")
        self.executor = executor
        self._slots = None if slots is None else as_int(slots, "slots", minimum=1)

    def slots(self) -> int:
        """Jobs to keep in flight."""
        if self._slots is not None:
            return self._slots
        return max(1, int(getattr(self.executor, "_max_workers", 1) or 1))

    def _share(self, shared):
        return shared

    def _submit(self, task, job, shared):
        return self.executor.submit(task, job, shared)

    def _abandon(self, future) -> None:
        future.cancel()

    def _started(self, future, submitted: float) -> float | None:
        """When `future`'s job started running (monotonic s), None if not yet."""
        return submitted

    def map_unordered(self, task, jobs, *, shared=None, timeout=None):
        timeout = timeout_seconds(timeout)
        shared = self._share(shared)
        queue = deque(jobs)
        in_flight: dict = {}               # future -> (job, submitted)
        waiter = None
        try:
            while queue or in_flight:
                while queue and len(in_flight) < self.slots():
                    job = queue.popleft()
                    future = self._submit(task, job, shared)
                    if waiter is None:
                        waiter = _DaskWaiter() if _from_dask(future) else _StandardWaiter()
                    waiter.add(future)
                    in_flight[future] = (job, time.monotonic())
                starts = {f: self._started(f, t) for f, (_, t) in in_flight.items()}
                waits = []
                if timeout is not None:
                    deadlines = [t + timeout for t in starts.values() if t is not None]
                    if deadlines:
                        waits.append(max(0.0, min(deadlines) - time.monotonic()))
                    if len(deadlines) < len(starts):    # look again for jobs that started
                        waits.append(_RECHECK)
                wait = min(waits) if waits else None
                for future in waiter.done(wait):
                    job, submitted = in_flight.pop(future)
                    start = self._started(future, submitted) or submitted
                    yield _future_outcome(future, job, time.monotonic() - start)
                for future, (job, _) in list(in_flight.items()):
                    start = starts.get(future)
                    if timeout is None or start is None or future.done():
                        continue
                    if time.monotonic() - start >= timeout:
                        del in_flight[future]
                        waiter.discard(future)
                        self._abandon(future)
                        yield TaskOutcome(job, None, timed_out(timeout), None,
                                          time.monotonic() - start)
        finally:
            for future in in_flight:
                future.cancel()


def _identity(value):
    return value


def _announced(task, job, shared, topic: str):
    """A Dask task: tell the driver it started (its timeout counts from here), run the job.

    While the job runs, what the worker held before it (its imports, its own objects) is
    frozen out of the collector's full passes, as a local worker's imports are; unfrozen
    after, so that the worker's next tasks find its garbage collected as before."""
    from distributed import get_worker
    worker = get_worker()
    worker.log_event(topic, worker.get_current_task())
    gc.freeze()
    try:
        return task(job, shared)
    finally:
        gc.unfreeze()


def _future_outcome(future, job, seconds: float) -> TaskOutcome:
    try:
        result = future.result()
    except BaseException as exc:  # noqa: BLE001 - a raising task, a dead worker, a cancel
        trace = None
        tb = getattr(exc, "__traceback__", None)
        if tb is not None and type(exc).__name__ not in ("KilledWorker", "BrokenProcessPool"):
            trace = "".join(traceback.format_exception(type(exc), exc, tb))
        reason = raised(exc)
        if type(exc).__name__ == "KilledWorker":
            reason = f"every worker that ran it died: {reason}"
        elif type(exc).__name__ == "BrokenProcessPool":
            reason = f"worker process died: {reason}"
        return TaskOutcome(job, None, reason, trace, seconds)
    return TaskOutcome(job, result, None, None, seconds)


class DaskExecutor(FuturesExecutor):
    """Jobs as tasks of a Dask cluster: the scheduler at `scheduler`, or a LocalCluster.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running scheduler (``tcp://host:8786``). Without it, a
        :class:`distributed.LocalCluster` of `workers` processes with one
        thread each is started, and stopped by :meth:`close`.
    workers : int, optional
        Worker processes of the LocalCluster (default: its own choice); not
        used with `scheduler` (the cluster has the workers it has).
    client : distributed.Client, optional
        A client of the caller's to use instead (left open by :meth:`close`).

    Raises
    ------
    InputError
        Dask is not installed (:data:`DASK_MISSING`), or the scheduler
        cannot be reached.
    """

    def __init__(self, *, scheduler: str | None = None, workers: int | None = None,
                 client=None):
        if importlib.util.find_spec("distributed") is None:
            raise InputError(DASK_MISSING)
        self.cluster = None
        self.owns_client = client is None
        if client is None:
            client = self._connect(scheduler, workers)
        self.client = client
        super().__init__(client)
        self._starts: dict = {}            # task key -> when a worker started it
        self._topic = f"mocap2mesh-start-{os.urandom(4).hex()}"
        client.subscribe_topic(self._topic, self._on_start)
        if importlib.util.find_spec("bokeh") is not None:
            self.dashboard_link = client.dashboard_link

    def _connect(self, scheduler, workers):
        from distributed import Client, LocalCluster
        if scheduler is not None:
            try:
                return Client(scheduler, timeout="10s")
            except (OSError, TimeoutError) as exc:
                raise InputError(f"cannot reach the Dask scheduler at {scheduler}: "
                                 f"{exc}") from None
        import dask
        workers = None if workers is None else as_int(workers, "workers", minimum=1)
        with dask.config.set(DASK_WORKER_CONFIG):     # the workers' glibc and GIL to the takes
            self.cluster = LocalCluster(n_workers=workers, threads_per_worker=1,
                                        processes=True, dashboard_address=":0")
        return Client(self.cluster)

    def slots(self) -> int:
        return max(1, sum(self.client.nthreads().values()))

    def _share(self, shared):
        # A task's result rather than scattered data: the scheduler recomputes it when
        # the workers holding it die, where scattered data would be lost with them.
        return None if shared is None else self.client.submit(
            _identity, shared, pure=False, key=f"shared-{os.urandom(4).hex()}")

    def _on_start(self, event) -> None:
        self._starts[event[1]] = time.monotonic()

    def _started(self, future, submitted):
        return self._starts.get(future.key)

    def _submit(self, task, job, shared):
        name = getattr(job, "stem", None) or str(job)
        return self.client.submit(_announced, task, job, shared, self._topic, pure=False,
                                  key=f"take-{name}-{os.urandom(4).hex()}")

    def _abandon(self, future) -> None:
        where = [w for w, keys in self.client.processing().items() if future.key in keys]
        future.cancel()
        if where:       # a running task cannot be stopped but with its worker
            self.client.restart_workers(where, raise_for_error=False)

    def close(self) -> None:
        if self._topic is None:
            return
        self.client.unsubscribe_topic(self._topic)
        self._topic = None
        if self.owns_client:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def open_executor(executor="local", *, workers: int | None = None,
                  scheduler: str | None = None) -> SessionExecutor:
    """The :class:`SessionExecutor` for a name or an executor object.

    Parameters
    ----------
    executor : {"local", "dask"} or executor object
        A name of :data:`EXECUTORS`, a :class:`SessionExecutor`, a
        :class:`distributed.Client` (wrapped in :class:`DaskExecutor`, left
        open), or any object with ``submit`` (wrapped in :class:`FuturesExecutor`).
    workers : int, optional
        Parallel jobs of ``"local"`` (default 1), LocalCluster workers of ``"dask"``.
    scheduler : str, optional
        Dask scheduler address (``"dask"`` only).

    Examples
    --------
    >>> type(open_executor("local", workers=2)).__name__
    'LocalExecutor'
    """
    if isinstance(executor, SessionExecutor):
        return executor
    if type(executor).__name__ == "Client" and _from_dask(executor):
        return DaskExecutor(client=executor)
    if not isinstance(executor, str):
        return FuturesExecutor(executor)
    as_choice(executor, "executor", EXECUTORS)
    if scheduler is not None and executor != "dask":
        raise InputError(f"a scheduler address ({scheduler}) needs executor 'dask', "
                         f"not {executor!r}")
    if executor == "dask":
        return DaskExecutor(scheduler=scheduler, workers=workers)
    return LocalExecutor(1 if workers is None else workers)
