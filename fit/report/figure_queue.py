"""Figures drawn side by side: by the caller and by helper processes.

Matplotlib draws under the GIL, so threads cannot share out a report's figures; they do
not depend on each other, so processes can. The caller and each helper take the next
figure that nobody has taken yet. A helper (:mod:`fit.report._figure_helper`) is not a
fork of the caller: a fork of a process running BLAS and other threads can deadlock, and a
multiprocessing child would run the caller's script again when it has no ``__main__``
guard. Where the command forked a server before it started any thread (the
``mocap2mesh`` command does: :mod:`fit.report.forked_helpers`), the server forks the
helpers, which have its imports at once. Else a helper is a fresh interpreter that imports
the report's modules as it starts (about a second of a core), so a queue made before
other work (the exports) has its helpers ready when the figures come; a helper still
starting when the figures are done is stopped.

A figure is a call ``function(*args, **kwargs)`` that writes its file and returns
nothing (the exports' weights CSVs go the same way:
:meth:`fit.pipeline.reconstruction.ReconstructionResult.save`). It reaches a helper by
pickle: give it what it shows (the frames of a view), not the whole take. A call that does
not pickle is drawn by the caller, and so is one whose outcome (its error, its warnings)
does not come back from the helper intact. The caller's rcParams go with every figure, so
a figure is the same bytes whoever draws it.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import threading
import warnings
from dataclasses import dataclass
from typing import Callable

import matplotlib

from fit.report.forked_helpers import forked_helper
from mocap.util.blas import CoresTaken
from mocap.util.python_helpers import can_start_python, send_import_path, start_python

__all__ = ["FigureQueue", "MAX_HELPERS", "default_helpers"]

#: Most helpers by default: a report has about a dozen figures, and each helper costs an
#: interpreter start (about a second of a core) and its memory (about 150 MB).
MAX_HELPERS = 3
#: What a helper sends once its imports are done.
READY = "ready"
#: A helper's answer that did not pickle (the figure is drawn again by the caller).
UNSENT = "unsent"
#: A helper's program: the caller's ``sys.path`` comes first on its stdin. The collector
#: is off during its imports (:func:`fit.report._figure_helper.main` turns it back on).
_BOOT = ("import gc, pickle, sys; gc.disable(); sys.path[:] = pickle.load(sys.stdin.buffer); "
         "from fit.report._figure_helper import main; main()")
#: rcParams that are the process's, not the figure's.
_PROCESS_RC = ("backend", "backend_fallback", "interactive")


def _usable_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:                      # macOS, Windows
        return os.cpu_count() or 1


def default_helpers() -> int:
    """One helper per usable core beyond the caller's, at most :data:`MAX_HELPERS`; none
    when this interpreter cannot start another (a frozen application)."""
    if not can_start_python():
        return 0
    return max(0, min(MAX_HELPERS, _usable_cores() - 1))


@dataclass
class _Figure:
    function: Callable
    args: tuple
    kwargs: dict
    rc: dict            # the caller's rcParams when it was submitted

    @property
    def name(self) -> str:
        return getattr(self.function, "__qualname__", repr(self.function))


class _Helper:
    """One helper process, fed pickles on its stdin, answering on its stdout: forked by
    this process's server when it has one (:mod:`fit.report.forked_helpers`), else a
    fresh interpreter."""

    def __init__(self):
        self.ready = False
        self.process = forked_helper()
        if self.process is None:
            self.process = start_python(_BOOT, MPLBACKEND="Agg")
        # the caller's import path as it is now (not as it was at a fork server's fork)
        send_import_path(self.process)
        self.process.stdin.flush()

    def wait_ready(self) -> bool:
        """Block until the helper has started; False if it died or was stopped first."""
        if not self.ready:
            try:
                self.ready = pickle.loads(self._read()) == READY
            except (EOFError, OSError, ValueError, pickle.UnpicklingError):
                return False
        return self.ready

    def draw(self, task: bytes):
        """Send one pickled figure and return the helper's outcome (see `_figure_helper`),
        None when it does not load here (an error whose constructor unpickling cannot call).

        Raises EOFError or OSError when the helper dies."""
        pickle.dump(task, self.process.stdin)
        self.process.stdin.flush()
        answer = self._read()
        try:
            outcome = pickle.loads(answer)
        except Exception:
            return None
        return None if outcome[0] == UNSENT else outcome

    def _read(self) -> bytes:
        """The helper's next answer, read whole (one pickled bytes), not yet loaded."""
        return pickle.load(self.process.stdout)

    def exit_code(self):
        try:
            return self.process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            return None

    def stop(self) -> None:
        """End the helper: at once when it is still starting, else when it reads EOF."""
        if not self.ready:
            self.process.kill()
        try:
            self.process.stdin.close()
        except OSError:
            pass
        if self.exit_code() is None:
            self.process.kill()
            self.process.wait()
        self.process.stdout.close()


class FigureQueue:
    """Figures to draw, shared by this process and `helpers` helper processes.

    A ready helper starts on a figure as soon as it is submitted; :meth:`run` has this
    process draw the figures nobody has taken and waits for the others. Until the queue
    closes, this process's BLAS leaves the helpers' cores to them
    (:class:`mocap.util.blas.CoresTaken`).

    Parameters
    ----------
    helpers : int, optional
        Helper processes, started at once (default :func:`default_helpers`); 0 draws
        everything in this process, in order, in :meth:`run`.

    Examples
    --------
    >>> with FigureQueue(helpers=0) as figures:    # doctest: +SKIP
    ...     figures.submit(plot_alpha, results, "alpha.png")
    ...     figures.run()
    """

    def __init__(self, helpers: int | None = None):
        count = default_helpers() if helpers is None else int(helpers)
        if count < 0:
            raise ValueError(f"helpers must be 0 or more, got {helpers}")
        self._figures: list[_Figure] = []
        self._outcomes: dict = {}
        self._taken = 0
        self._for_caller: list[int] = []        # figures a helper could not draw
        self._lost: list = []                   # (figure, pid, exit code) of dead helpers
        self._closing = False
        self._changed = threading.Condition()
        self._helpers = _start_helpers(count)
        self._cores = CoresTaken(len(self._helpers))
        self._feeders = [threading.Thread(target=self._feed, args=(helper,), daemon=True)
                         for helper in self._helpers]
        for feeder in self._feeders:
            feeder.start()

    @property
    def helpers(self) -> int:
        """Helper processes the queue started."""
        return len(self._helpers)

    @property
    def pids(self) -> tuple:
        """Process ids of the helpers (to watch their memory, say)."""
        return tuple(helper.process.pid for helper in self._helpers)

    def submit(self, function: Callable, /, *args, **kwargs) -> None:
        """Queue ``function(*args, **kwargs)``; a ready helper starts on it at once."""
        with self._changed:
            self._figures.append(_Figure(function, args, kwargs, _figure_rc()))
            self._changed.notify_all()

    def run(self) -> None:
        """Draw every queued figure and return when all are written.

        Warnings of the figures drawn by helpers are warned here; the first error in the
        order the figures were queued is raised (with the helper's traceback as a note),
        after every other figure was drawn.
        """
        while (index := self._next(for_caller=True)) is not None:
            self._done(index, _draw_here(self._figures[index]))
        with self._changed:
            figures, outcomes, lost = self._figures, self._outcomes, self._lost
            self._figures, self._outcomes, self._taken, self._lost = [], {}, 0, []
        for figure, pid, code in lost:
            ended = "ended" if code is None else f"exited with code {code}"
            warnings.warn(f"figure helper (pid {pid}) {ended} while drawing {figure.name}; "
                          "drawn in this process instead", RuntimeWarning, stacklevel=2)
        errors = []
        for index in range(len(figures)):
            outcome = outcomes[index]
            if outcome[0] == "ok":
                for message, category in outcome[1]:
                    warnings.warn(message, category, stacklevel=2)
            else:
                errors.append(outcome[1])
        if errors:
            raise errors[0]

    def _next(self, *, for_caller: bool = False):
        """Index of the next figure to draw, None when there is none. The caller also takes
        what helpers gave back, and waits until every figure is drawn; a helper waits for
        the next submission, and gets None once the queue closes."""
        with self._changed:
            while True:
                if for_caller and self._for_caller:
                    return self._for_caller.pop(0)
                if self._closing:
                    return None
                if self._taken < len(self._figures):
                    self._taken += 1
                    return self._taken - 1
                if for_caller and len(self._outcomes) == len(self._figures):
                    return None
                self._changed.wait()

    def _done(self, index: int, outcome: tuple) -> None:
        with self._changed:
            self._outcomes[index] = outcome
            self._changed.notify_all()

    def _feed(self, helper: _Helper) -> None:
        """Give `helper` the next figures until the queue closes or the helper dies."""
        if not helper.wait_ready():
            return
        while (index := self._next()) is not None:
            figure = self._figures[index]
            try:
                task = pickle.dumps((figure.function, figure.args, figure.kwargs, figure.rc),
                                    protocol=pickle.HIGHEST_PROTOCOL)
            except Exception:                       # a lambda, an open file: drawn here
                self._give_back(index)
                continue
            try:
                outcome = helper.draw(task)
            except (EOFError, OSError, ValueError, pickle.UnpicklingError):
                self._lost.append((figure, helper.process.pid, helper.exit_code()))
                self._give_back(index)
                return
            if outcome is None:                     # an answer that does not load here
                self._give_back(index)
                continue
            if outcome[0] == "error":
                error, trace = outcome[1], outcome[2]
                error.add_note(f"raised in figure helper pid {helper.process.pid} drawing "
                               f"{figure.name}:\n{trace}")
                outcome = ("error", error)
            self._done(index, outcome)

    def _give_back(self, index: int) -> None:
        with self._changed:
            self._for_caller.append(index)
            self._changed.notify_all()

    def close(self) -> None:
        """Stop the helpers; figures still queued are dropped."""
        with self._changed:
            self._closing = True
            self._changed.notify_all()
        for helper in self._helpers:
            if not helper.ready:                    # still starting: no use waiting
                helper.process.kill()
        for feeder in self._feeders:
            feeder.join()
        for helper in self._helpers:
            helper.stop()
        self._helpers, self._feeders = [], []
        self._cores.close()

    def __enter__(self) -> FigureQueue:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        for helper in getattr(self, "_helpers", ()):
            if helper.process.poll() is None:
                helper.process.kill()


def _start_helpers(count: int) -> list:
    """Up to `count` helpers: fewer when the system refuses a process (they are a speed-up)."""
    helpers = []
    for _ in range(count):
        try:
            helpers.append(_Helper())
        except OSError:
            break
    return helpers


def _figure_rc() -> dict:
    """The caller's rcParams that shape a figure."""
    return {key: value for key, value in dict.items(matplotlib.rcParams)
            if key not in _PROCESS_RC}


def _draw_here(figure: _Figure) -> tuple:
    """Draw `figure` in this process (its warnings go out as they come)."""
    try:
        figure.function(*figure.args, **figure.kwargs)
    except Exception as error:
        return ("error", error)
    return ("ok", [])
