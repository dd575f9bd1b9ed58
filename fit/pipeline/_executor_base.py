"""What every session executor shares: the outcome of a job, and the executor's interface.

:mod:`fit.pipeline.executors` has the executors themselves.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Iterable, Iterator

from mocap.util.validation import as_positive_float

__all__ = ["TaskOutcome", "SessionExecutor", "timeout_seconds", "timed_out", "raised"]


@dataclass(frozen=True)
class TaskOutcome:
    """How one job ended.

    Attributes
    ----------
    job : object
        The job, as given.
    result : object or None
        What the task returned; None when it failed.
    error : str or None
        Why it failed: the exception (``"ValueError: ..."``), ``"timed out
        after 60 s"``, ``"worker process died (SIGKILL)"``, Dask's
        ``KilledWorker``...; None on success.
    traceback : str or None
        The task's traceback when it raised.
    seconds : float
        Wall time from the job's start to its end (as the driver saw it), s.
    """

    job: Any
    result: Any
    error: str | None
    traceback: str | None
    seconds: float

    @property
    def ok(self) -> bool:
        """True when the task returned."""
        return self.error is None


def timeout_seconds(timeout) -> float | None:
    """A per-job timeout (s) checked positive, or None for no limit."""
    return None if timeout is None else as_positive_float(timeout, "timeout")


def timed_out(timeout: float) -> str:
    """The reason recorded for a job stopped at its timeout."""
    return f"timed out after {timeout:g} s (the per-take timeout)"


def raised(exc: BaseException) -> str:
    """The reason recorded for a job that raised `exc`."""
    return f"{type(exc).__name__}: {exc}"


class SessionExecutor:
    """Runs ``task(job, shared)`` for many jobs; a context manager that cleans up after itself.

    Attributes
    ----------
    dashboard_link : str or None
        Where to watch the work (the Dask dashboard), when there is such a page.
    """

    dashboard_link: str | None = None

    def map_unordered(self, task: Callable, jobs: Iterable, *, shared=None,
                      timeout: float | None = None) -> Iterator[TaskOutcome]:
        """Run ``task(job, shared)`` for every job; yield each :class:`TaskOutcome` as it ends.

        Parameters
        ----------
        task : callable
            A module-level function (it is pickled by reference to the workers).
        jobs : iterable
            Picklable arguments, one per task.
        shared : object, optional
            Passed to every call; shipped to each worker once where the
            executor allows (Dask scatters it).
        timeout : float, optional, s
            Longest a job may run; past it, it is stopped and reported as failed.
        """
        raise NotImplementedError

    def slots(self) -> int:
        """Jobs run side by side at most."""
        return 1

    def runs_here(self, timeout: float | None = None) -> bool:
        """Whether :meth:`map_unordered` with this `timeout` runs the jobs in this process."""
        return False

    def close(self) -> None:
        """Release what this executor started (processes, a cluster)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
