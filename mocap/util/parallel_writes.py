"""A file's parts made and written by worker threads, each part at its own offset.

A file whose bytes are computed (floats converted, scaled, gathered) costs the making
plus the writing when one thread does both. Here each worker thread makes a share of the
parts and writes each at its offset in the file (``os.pwrite``), so that the threads need
not wait for one another: compiled kernels, NumPy's large loops and the writes release the
GIL, and the making of one part runs beside the writing of another. (Handing each part
from a making thread to a writing one costs two thread wake-ups a part, which on a virtual
machine cost a good part of the making.) Each thread makes its parts in one buffer used
again and again: memory a process touches for the first time costs page faults, and
unmapping it a flush of every thread's address translations.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import wait

import numpy as np

from mocap.util.blas import finished, shared_pool

__all__ = ["write_parts", "positional_writer"]


def write_parts(write_at: Callable[[int, memoryview], None], parts: Sequence, *,
                workers: int, part_bytes: int) -> int:
    """Write `parts` one after another from offset 0 by ``write_at(offset, data)``.

    Parameters
    ----------
    write_at : callable
        Writes a bytes-like `data` at `offset` (:func:`positional_writer`); called from
        the worker threads.
    parts : sequence of (int, object)
        Each part's size in bytes and its bytes: a bytes-like object, or a callable
        ``part(out)`` that makes them in `out` (a uint8 array of `part_bytes`) and returns
        them (a bytes-like view of `out`, of the part's size; or, bytes it need not
        make, a view of their own memory).
    workers : int
        Threads that make and write the parts, part i on thread ``i % workers``: this
        one and ``workers - 1`` of :func:`mocap.util.blas.shared_pool`.
    part_bytes : int
        The most bytes a callable part makes.

    Returns
    -------
    int
        The bytes written.

    Raises
    ------
    Exception
        The first error of a part's making or of a write, once every thread has stopped
        (the others stop at their next part; the parts before it may be written or not).
    """
    offsets = np.concatenate([[0], np.cumsum([size for size, _ in parts], dtype=np.int64)])
    workers = max(1, min(workers, len(parts)))
    failed = threading.Event()          # a thread's error: the others stop at their next part

    def share(first: int) -> None:
        out = None
        try:
            for i in range(first, len(parts), workers):
                if failed.is_set():
                    return
                size, part = parts[i]
                if callable(part):
                    if out is None:
                        out = np.empty(part_bytes, np.uint8)
                    part = part(out)
                if memoryview(part).nbytes != size:
                    raise ValueError(f"part {i} made {memoryview(part).nbytes} bytes, "
                                     f"not {size}")
                write_at(int(offsets[i]), part)
        except BaseException:
            failed.set()
            raise

    helpers = [shared_pool(workers - 1).submit(share, first) for first in range(1, workers)]
    try:
        share(0)
    except BaseException:
        wait(helpers)                   # nothing of this file is written behind the error
        raise
    finished(helpers)
    return int(offsets[-1])


def positional_writer(fh, start: int) -> Callable[[int, memoryview], None]:
    """``write_at(offset, data)`` for :func:`write_parts`: `data` at ``start + offset`` of
    the open binary file `fh` (flushed first), by ``os.pwrite`` (the file's own position is
    left where it was); where there is no ``os.pwrite`` (Windows), by a seek and a write,
    one thread at a time (the file's position is then left after the last part written).
    """
    fh.flush()
    if not hasattr(os, "pwrite"):
        lock = threading.Lock()

        def write_at(offset: int, data) -> None:
            with lock:
                fh.seek(start + offset)
                fh.write(data)
        return write_at
    fd = fh.fileno()

    def write_at(offset: int, data) -> None:
        view, position = memoryview(data).cast("B"), start + offset
        while len(view):                # a write may take fewer bytes than it is given
            written = os.pwrite(fd, view, position)
            view, position = view[written:], position + written
    return write_at
