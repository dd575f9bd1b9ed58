"""Heat-method fields of many sources shared with helper processes.

libigl's solve holds the GIL, so another thread of this process cannot use a spare core;
another process can. Each helper is a fresh interpreter (:mod:`mocap.util.python_helpers`:
it imports this module, never the caller's ``__main__``) that factorizes the mesh once,
says it is ready, and then answers chunks of sources with their fields. This process takes
chunks from the front of the same queue meanwhile and the helpers from its back, so that
all end about together; a chunk a helper could not answer is solved here. A helper that is
still starting when the work is done is stopped: it never holds this process up.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import threading
from collections import deque

import numpy as np

from mocap.util.python_helpers import can_start_python, send_import_path, start_python

__all__ = ["solve_shared", "main"]

#: Sources a helper or this process solves at a time.
SOURCES_PER_CHUNK = 4
#: What a helper sends once the mesh is factorized.
READY = "ready"
#: A helper's program: the caller's ``sys.path`` comes first on its stdin.
_BOOT = ("import pickle, sys; sys.path[:] = pickle.load(sys.stdin.buffer); "
         "from mocap.mesh._geodesic_helpers import main; main()")


def solve_shared(solve, mesh: tuple, sources: np.ndarray, out: np.ndarray,
                 helpers: int) -> None:
    """Write the fields of `sources` (S,) into the rows of `out` (S, N), chunks of them
    solved by ``solve(ids)`` here and by up to `helpers` helper processes.

    Parameters
    ----------
    solve : callable
        ``solve(ids) -> (len(ids), N)`` fields, in this process.
    mesh : tuple
        ``(vertices, faces, time_factor, intrinsic_delaunay)``: what a helper builds its
        :class:`mocap.mesh.geodesic.HeatGeodesics` from (the same fields, bit for bit).
    """
    if not can_start_python():
        helpers = 0
    chunks = deque(slice(first, first + SOURCES_PER_CHUNK)
                   for first in range(0, len(sources), SOURCES_PER_CHUNK))
    returned: list = []                 # chunks a helper took but could not answer
    started = []
    for _ in range(helpers):
        try:
            started.append(_Helper(mesh))
        except OSError:                 # no process to be had: fewer helpers
            break
    feeders = [threading.Thread(target=_feed, args=(helper, chunks, sources, out, returned),
                                daemon=True) for helper in started]
    for feeder in feeders:
        feeder.start()
    try:
        while True:
            try:
                rows = chunks.popleft()
            except IndexError:
                break
            out[rows] = solve(sources[rows])
    finally:
        chunks.clear()
        for helper in started:
            if not helper.ready:        # still starting: no use waiting for it
                helper.process.kill()
        for feeder in feeders:
            feeder.join()
    for rows in returned:
        out[rows] = solve(sources[rows])


def _feed(helper: "_Helper", chunks: deque, sources, out, returned: list) -> None:
    """Have `helper` solve chunks from the back of `chunks` once it is ready, until none
    is left; the chunks it could not answer go to `returned`.

    Two chunks are in the helper's hands at a time: this thread, which waits for the GIL
    while the caller's solve holds it, then never keeps the helper waiting for the next.
    """
    asked: deque = deque()
    try:
        if not helper.wait_ready():
            return
        while True:
            while len(asked) < _CHUNKS_ASKED:
                try:
                    rows = chunks.pop()
                except IndexError:
                    break
                asked.append(rows)
                helper.ask(sources[rows])
            if not asked:
                return
            out[asked[0]] = helper.answer()
            asked.popleft()
    except (EOFError, OSError, ValueError, pickle.UnpicklingError):
        returned.extend(asked)
    finally:
        helper.stop()


#: Chunks a helper holds at a time.
_CHUNKS_ASKED = 2


class _Helper:
    """One helper process, sent the mesh at its start, then chunks of sources."""

    def __init__(self, mesh: tuple):
        self.ready = False
        self.process = start_python(_BOOT)
        try:
            send_import_path(self.process)
            pickle.dump(mesh, self.process.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            self.process.stdin.flush()
        except OSError:
            self.stop()
            raise

    def wait_ready(self) -> bool:
        """Block until the helper has factorized the mesh; False if it failed or died."""
        try:
            self.ready = pickle.load(self.process.stdout) == READY
        except (EOFError, OSError, ValueError, pickle.UnpicklingError):
            return False
        return self.ready

    def ask(self, ids: np.ndarray) -> None:
        """Ask for the fields of the source vertices `ids` (answered in order)."""
        pickle.dump(ids, self.process.stdin, protocol=pickle.HIGHEST_PROTOCOL)
        self.process.stdin.flush()

    def answer(self) -> np.ndarray:
        """The fields of the first chunk asked and not answered, (len(ids), N).

        Raises ValueError for the helper's error, EOFError or OSError when it died."""
        answer = pickle.load(self.process.stdout)
        if not isinstance(answer, np.ndarray):
            raise ValueError(f"geodesic helper: {answer}")
        return answer

    def stop(self) -> None:
        """End the helper (it exits when its input ends) and wait for it."""
        try:
            self.process.stdin.close()
        except OSError:
            pass
        try:
            self.process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        self.process.stdout.close()


def main() -> None:
    """A helper: the mesh, then chunks of source ids on stdin; READY, then each chunk's
    fields (or its error's text) on stdout, each one pickle. Ends when stdin ends."""
    from mocap.mesh.geodesic import HeatGeodesics

    inbox, outbox = sys.stdin.buffer, os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())      # what the solves print: stderr

    def send(answer) -> None:
        pickle.dump(answer, outbox, protocol=pickle.HIGHEST_PROTOCOL)
        outbox.flush()
    vertices, faces, time_factor, intrinsic_delaunay = pickle.load(inbox)
    try:
        geodesics = HeatGeodesics(vertices, faces, time_factor=time_factor,
                                  intrinsic_delaunay=intrinsic_delaunay)
    except Exception as error:  # noqa: BLE001 - said to the caller, which solves alone
        send(f"{type(error).__name__}: {error}")
        os._exit(0)
    send(READY)
    while True:
        try:
            ids = pickle.load(inbox)
        except EOFError:
            os._exit(0)
        try:
            send(geodesics.from_vertices(ids, processes=0))
        except Exception as error:  # noqa: BLE001 - said to the caller, which solves it
            send(f"{type(error).__name__}: {error}")
