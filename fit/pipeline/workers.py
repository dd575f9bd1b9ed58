"""Worker processes that die with the run that started them.

A pool worker of a killed run must not go on writing into the output
directory. :func:`local_pool` makes a process pool whose workers ask the
kernel to kill them when their parent dies (Linux ``PR_SET_PDEATHSIG``; on
other systems a thread of the worker watches the parent), and
:func:`stop_pool` ends a pool at once on every other exit path (an exception,
Ctrl-C), cancelling queued takes and killing running ones.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor

__all__ = ["die_with_parent", "local_pool", "stop_pool"]

_PR_SET_PDEATHSIG = 1
_POLL_S = 0.5


def _watch(parent_pid: int) -> None:
    while os.getppid() == parent_pid:
        time.sleep(_POLL_S)
    os._exit(1)


def die_with_parent(parent_pid: int) -> None:
    """Make the calling (worker) process end when process `parent_pid` ends.

    Meant as the ``initializer`` of a pool: on Linux the kernel sends the
    worker SIGKILL when its parent exits, however it exits (even SIGKILL);
    elsewhere a daemon thread polls the parent and exits the worker.
    """
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG) failed")
    else:  # pragma: no cover - macOS and BSDs
        threading.Thread(target=_watch, args=(parent_pid,), daemon=True).start()
    if os.getppid() != parent_pid:      # the parent died before the request took effect
        os._exit(1)


def local_pool(workers: int) -> ProcessPoolExecutor:
    """A process pool of `workers` processes that die with this process."""
    return ProcessPoolExecutor(max_workers=workers, initializer=die_with_parent,
                               initargs=(os.getpid(),))


def stop_pool(pool: ProcessPoolExecutor) -> None:
    """Cancel the queued work of `pool` and kill its running workers now."""
    # the stdlib gives no public handle on the workers (3.14 adds kill_workers)
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        if process.is_alive():
            process.kill()
    for process in processes:
        process.join(timeout=5)
