"""Tasks for the executor tests, in a module of their own that imports next to nothing,
so that a fresh worker process starts it at once."""

from __future__ import annotations

import os
import signal
import time


def square(job, shared):
    """``job ** shared``, or what the job asks for: raise, kill its own worker, hang
    (``("hang", file)``: after writing its process id to `file`)."""
    if job == "raise":
        raise ValueError("take 'raise' is broken")
    if job == "die":
        os.kill(os.getpid(), signal.SIGKILL)
    if job == "hang" or isinstance(job, tuple):
        if isinstance(job, tuple):
            with open(job[1], "w") as fh:
                fh.write(str(os.getpid()))
        time.sleep(60)
    return job ** shared


def blas_share(job, shared):
    """The BLAS threads and the Python worker threads the job's process runs on."""
    from mocap.util.blas import blas_threads, worker_threads

    return blas_threads(), worker_threads()


def worker_settings(job, shared):
    """What the job's process runs with: glibc's trim threshold from the environment, Dask's
    profiler switch, the BLAS threads."""
    import dask

    from mocap.util.blas import blas_threads

    return (os.environ.get("MALLOC_TRIM_THRESHOLD_"),
            dask.config.get("distributed.worker.profile.enabled"), blas_threads())


def process_id(job, shared):
    """The process the job runs in."""
    return os.getpid()
