"""A helper process of :class:`fit.report.figure_queue.FigureQueue`.

Reads pickled figures on stdin, one at a time, draws each and answers on stdout (a helper
forked by :mod:`fit.report.forked_helpers`: on two pipes of its own):
``("ok", [(message, category), ...])`` with the figure's warnings, or
``("error", exception, traceback text)``, or ``(UNSENT,)`` when the answer does not
pickle. Each answer goes as one pickled ``bytes``, so that the caller reads it whole even
when it cannot load what it holds. Anything the figures print goes to stderr, so that it
cannot break the answers. Ends at EOF, at once: every figure is written and answered by
then, and the interpreter's teardown (matplotlib's objects, 0.2 s) would only keep the
caller waiting for the exit code.
"""

from __future__ import annotations

import gc
import os
import pickle
import sys
import traceback
import warnings

import matplotlib

import fit.report  # noqa: F401  (the report's modules, imported before the first figure)
from fit.report.figure_queue import READY, UNSENT


def _draw(task: bytes) -> tuple:
    try:
        function, args, kwargs, rc = pickle.loads(task)
        with warnings.catch_warnings(record=True) as caught, matplotlib.rc_context(rc):
            warnings.simplefilter("always")
            function(*args, **kwargs)
    except Exception as error:
        return ("error", error, traceback.format_exc())
    return ("ok", [(str(w.message), w.category) for w in caught])


def _send(outbox, outcome) -> None:
    """Write `outcome` as one pickled bytes; ``(UNSENT,)`` when it does not pickle."""
    try:
        answer = pickle.dumps(outcome, protocol=pickle.HIGHEST_PROTOCOL)
    except Exception:
        answer = pickle.dumps((UNSENT,))
    pickle.dump(answer, outbox, protocol=pickle.HIGHEST_PROTOCOL)
    outbox.flush()


def main() -> None:
    """A fresh interpreter's helper: the figures come on stdin, the answers go on stdout."""
    serve(sys.stdin.buffer, os.fdopen(os.dup(sys.stdout.fileno()), "wb"))


def serve(inbox, outbox) -> None:
    """Answer each figure read from the binary file `inbox` on `outbox` until `inbox`
    ends, then end the process (a fresh interpreter's or one forked by
    :mod:`fit.report.forked_helpers`)."""
    # the objects of the imports live as long as the helper: made with the collector off
    # (a fresh interpreter's boot turned it off), its full passes while it draws skip them
    # (see fit.cli.main.console)
    gc.freeze()
    gc.enable()
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())   # what a figure prints: stderr
    _send(outbox, READY)
    while True:
        try:
            task = pickle.load(inbox)
        except EOFError:
            sys.stderr.flush()
            os._exit(0)
        _send(outbox, _draw(task))
