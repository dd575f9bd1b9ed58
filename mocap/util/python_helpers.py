"""Fresh Python interpreters started as helper processes of this one (``python -c``).

A helper started from code on its command line imports what the code names and never the
caller's ``__main__`` (a script without a main guard would run again in it). Its BLAS and
OpenMP run on one thread: the caller's process has the threads. Its code reads the
caller's import path first on its stdin (:func:`send_import_path`): as PYTHONPATH the
path would come before the standard library, which a script's folder holding a "re.py"
would then shadow.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys

__all__ = ["can_start_python", "send_import_path", "start_python"]


def can_start_python() -> bool:
    """Whether this process can start a fresh interpreter (not a frozen application)."""
    return not getattr(sys, "frozen", False) and bool(sys.executable)


def start_python(code: str, **environment: str) -> subprocess.Popen:
    """``python -c code`` with pipes to its stdin and stdout, its BLAS on one thread and
    `environment` added to this process's environment.

    Raises
    ------
    OSError
        The process could not be started.
    """
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1", **environment}
    return subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, env=env)


def send_import_path(process) -> None:
    """Write this process's ``sys.path`` as it is now to `process`'s stdin (not flushed)."""
    pickle.dump(sys.path, process.stdin)
