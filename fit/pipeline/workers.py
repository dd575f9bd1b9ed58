"""Worker processes that die with the run that started them.

A worker of a killed run must not go on writing into the output directory.
:func:`die_with_parent`, called first in each local worker
(:class:`fit.pipeline.executors.LocalExecutor`), asks the kernel to kill the
worker when its parent dies (Linux ``PR_SET_PDEATHSIG``; on other systems a
thread of the worker watches the parent). The executor itself kills its
running workers on every other exit path (an exception, Ctrl-C).
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time

__all__ = ["die_with_parent"]

_PR_SET_PDEATHSIG = 1
_POLL_S = 0.5


def _watch(parent_pid: int) -> None:
    while os.getppid() == parent_pid:
        time.sleep(_POLL_S)
    os._exit(1)


def die_with_parent(parent_pid: int) -> None:
    """Make the calling (worker) process end when process `parent_pid` ends.

    Called first in a worker process: on Linux the kernel sends the
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
