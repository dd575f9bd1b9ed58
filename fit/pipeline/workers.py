"""Worker processes that die with the run that started them.

A worker of a killed run must not go on writing into the output directory.
Each local worker (:class:`fit.pipeline.executors.LocalExecutor`) gets the
read end of a pipe of its own, a lifeline (:func:`lifeline`), whose write end
only the driver holds: a thread of the worker (:func:`die_with_driver`) waits
on it and ends the worker the moment it reads end-of-file, which the system
delivers as soon as the driver is gone, however it ended (even SIGKILL). This
holds whoever the worker's parent is (workers are forked by a fork server,
which lives on while any worker does, so the parent's death is not the
signal). The executor itself kills its running workers on every other exit
path (an exception, Ctrl-C).
"""

from __future__ import annotations

import os
import threading

__all__ = ["lifeline", "die_with_driver"]


def lifeline(context) -> tuple:
    """A new lifeline: ``(worker_end, driver_end)`` connections of `context`.

    The driver passes ``worker_end`` to the worker process, closes its own
    copy of it once the worker has started, and keeps ``driver_end`` open
    (writing nothing) for as long as the worker may run.
    """
    worker_end, driver_end = context.Pipe(duplex=False)
    return worker_end, driver_end


def die_with_driver(worker_end) -> None:
    """End this (worker) process as soon as the driver's end of its lifeline closes."""
    def watch():
        try:
            worker_end.recv_bytes()         # the driver never writes: this returns at EOF
        except (EOFError, OSError):
            pass
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="die-with-driver").start()
