"""The local executor: at most N jobs at a time, each in a fresh process of its own.

Re-exported by :mod:`fit.pipeline.executors`.
"""

from __future__ import annotations

import gc
import multiprocessing
import signal
import sys
import time
import traceback
from collections import deque
from dataclasses import dataclass
from multiprocessing import connection
from typing import Any

from fit.pipeline._executor_base import (
    SessionExecutor,
    TaskOutcome,
    raised,
    timed_out,
    timeout_seconds,
)
from fit.pipeline.workers import die_with_driver, lifeline
from mocap.util.blas import CoresTaken, blas_threads
from mocap.util.validation import as_int

__all__ = ["LocalExecutor"]

_STARTED = "started"    # a worker's first message: the job's clock starts


def _child(conn, alive, task, job, shared, workers) -> None:
    """A local worker process among `workers`: say it started, run one job on its share of
    the BLAS's threads, send ``(ok, result or reason, traceback)``."""
    die_with_driver(alive)              # no orphan when the driver is killed
    # the objects of the worker's imports live as long as it: the collector's full passes
    # during the job skip them (see fit.cli.main.console)
    gc.freeze()
    # the other workers keep the rest of the cores busy (threads waiting for a busy core
    # made a pool of 2 on 2 cores 1.7 times slower)
    threads = blas_threads()
    CoresTaken(threads - max(1, threads // workers))
    conn.send(_STARTED)
    try:
        message = (True, task(job, shared), None)
    except BaseException as exc:  # noqa: BLE001 - everything goes back to the driver
        message = (False, raised(exc), traceback.format_exc())
    try:
        conn.send(message)
    except Exception as exc:  # noqa: BLE001 - e.g. a result that cannot be pickled
        conn.send((False, f"the result could not be sent back: {raised(exc)}", None))
    conn.close()


def _death(exitcode: int | None) -> str:
    if exitcode is not None and exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f"signal {-exitcode}"
        hint = " (out of memory?)" if -exitcode == signal.SIGKILL else ""
        return f"worker process died ({name}){hint} before the take finished"
    return f"worker process exited with code {exitcode} before the take finished"


@dataclass
class _Running:
    process: Any
    conn: Any
    alive: Any                      # the driver's end of the worker's lifeline
    job: Any
    start: float | None = None      # when the job started running (monotonic s)

    def close(self) -> None:
        """Join the ended process and close both pipes."""
        self.process.join()
        self.conn.close()
        self.alive.close()


class LocalExecutor(SessionExecutor):
    """At most `workers` jobs at a time, each in a fresh process of its own.

    A fresh process per job returns all of a job's memory to the system when it
    ends and lets a job past its timeout be killed without touching the
    others; each runs on its share of the BLAS's threads (at least one).
    Processes start from a fork server that has imported the task's module,
    so a start costs milliseconds, not an import of the chain.

    Parameters
    ----------
    workers : int
        Jobs run at once. With 1 and no timeout, jobs run in this process.

    Examples
    --------
    >>> with LocalExecutor(1) as pool:
    ...     [o.result for o in pool.map_unordered(lambda job, _: -job, [1, 2])]
    [-1, -2]
    """

    def __init__(self, workers: int):
        self.workers = as_int(workers, "workers", minimum=1)

    def slots(self) -> int:
        return self.workers

    def runs_here(self, timeout=None) -> bool:
        return self.workers == 1 and timeout_seconds(timeout) is None

    def map_unordered(self, task, jobs, *, shared=None, timeout=None):
        timeout = timeout_seconds(timeout)
        if self.runs_here(timeout):
            yield from _in_process(task, jobs, shared)
            return
        context = _process_context(task)
        queue = deque(jobs)
        running: list[_Running] = []
        try:
            while queue or running:
                while queue and len(running) < self.workers:
                    running.append(_start(context, task, queue.popleft(), shared,
                                          self.workers))
                deadlines = [r.start + timeout for r in running
                             if timeout is not None and r.start is not None]
                wait = max(0.0, min(deadlines) - time.monotonic()) if deadlines else None
                connection.wait([r.conn for r in running] + [r.process.sentinel
                                                             for r in running], wait)
                for run in list(running):
                    outcome = _finished(run, timeout)
                    if outcome is not None:
                        running.remove(run)
                        yield outcome
        finally:
            for run in running:          # the driver stopped early: no process outlives it
                run.process.kill()
                run.close()


def _in_process(task, jobs, shared):
    for job in jobs:
        start = time.monotonic()
        try:
            result = task(job, shared)
        except Exception as exc:  # noqa: BLE001 - one job's failure must not stop the others
            yield TaskOutcome(job, None, raised(exc), traceback.format_exc(),
                              time.monotonic() - start)
        else:
            yield TaskOutcome(job, result, None, None, time.monotonic() - start)


def _process_context(task):
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    context = multiprocessing.get_context("forkserver")
    # the fork server imports these once; each worker forked from it starts warm
    preload = [__name__]
    module = getattr(task, "__module__", None)
    if module and module != "__main__" and module in sys.modules:
        preload.append(module)
    context.set_forkserver_preload(preload)
    return context


def _start(context, task, job, shared, workers) -> _Running:
    receive, send = context.Pipe(duplex=False)
    worker_end, driver_end = lifeline(context)
    process = context.Process(target=_child, args=(send, worker_end, task, job, shared,
                                                   workers),
                              daemon=True, name="mocap2mesh-take")
    process.start()
    send.close()
    worker_end.close()
    return _Running(process, receive, driver_end, job)


def _message(run: _Running):
    """The job's final message if it has come (noting its start on the way), else None."""
    while run.conn.poll():
        try:
            message = run.conn.recv()
        except (EOFError, OSError):          # died while sending
            return None
        if message != _STARTED:
            return message
        run.start = time.monotonic()
    return None


def _finished(run: _Running, timeout: float | None) -> TaskOutcome | None:
    """The outcome of `run` if it has ended (or is stopped now for its timeout), else None."""
    message = _message(run)
    seconds = 0.0 if run.start is None else time.monotonic() - run.start
    if message is not None:
        ok, value, trace = message
    elif not run.process.is_alive():
        run.process.join()
        ok, value, trace = False, _death(run.process.exitcode), None
    elif timeout is not None and run.start is not None and seconds >= timeout:
        run.process.kill()
        ok, value, trace = False, timed_out(timeout), None
    else:
        return None
    run.close()
    return TaskOutcome(run.job, value if ok else None, None if ok else value, trace, seconds)
