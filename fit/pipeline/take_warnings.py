"""The warnings of a take's run: caught while it runs, printed on stderr, recorded.

``mocap2mesh run`` runs takes in worker processes, where a warning printed
would be lost or interleaved; each take's warnings (binding distances,
unconverged frames, what gap filling did and left, ...) are caught instead
(:func:`capture_warnings`), written into its report and manifest record, and
printed by the parent as the take completes (:func:`print_warnings`), in the
``mocap2mesh: warning: ...`` form of the other commands.
"""

from __future__ import annotations

import sys
import warnings
from contextlib import contextmanager

from tqdm import tqdm

__all__ = ["capture_warnings", "print_warnings", "recorded_warnings", "replay_warnings",
           "warn_unconverged"]


@contextmanager
def capture_warnings(*, reemit: bool = True):
    """Catch every warning raised inside; yields the list of their messages.

    The list is filled when the block ends: each distinct message once, in
    the order first raised. When the block raises and `reemit` is true, the
    messages are warned again (same category) before the exception goes on,
    so that an enclosing catch still sees why a take failed; the outermost
    catch, which records them, passes ``reemit=False``.

    Examples
    --------
    >>> with capture_warnings() as caught:
    ...     warnings.warn("marker far from the skin")
    ...     warnings.warn("marker far from the skin")
    >>> caught
    ['marker far from the skin']
    """
    messages, seen = [], {}
    failed = False
    try:
        with warnings.catch_warnings(record=True) as caught:
            _catch_all()
            try:
                yield messages
            except BaseException:
                failed = True
                raise
            finally:
                for w in caught:
                    seen.setdefault(str(w.message), w.category)
                messages.extend(seen)
    finally:
        if failed and reemit:
            for message, category in seen.items():
                warnings.warn(message, category, stacklevel=3)


@contextmanager
def recorded_warnings():
    """Catch every warning raised inside; yields a list of ``(message, category)``, filled
    when the block ends: work done once for several takes raises them again in each
    (:func:`replay_warnings`)."""
    pairs = []
    with warnings.catch_warnings(record=True) as caught:
        _catch_all()
        try:
            yield pairs
        finally:
            pairs.extend((str(w.message), w.category) for w in caught)


def _catch_all() -> None:
    """Every warning raised in the block, each time, except ResourceWarning: the garbage
    collector runs other objects' finalizers at any allocation, so an unclosed file of
    some earlier work could warn inside a take's block; it says nothing of the take
    (and Python's own filters hide it by default)."""
    warnings.simplefilter("always")
    warnings.simplefilter("ignore", ResourceWarning)


def replay_warnings(pairs) -> None:
    """Warn ``(message, category)`` pairs again, in order (:func:`recorded_warnings`)."""
    for message, category in pairs:
        warnings.warn(message, category, stacklevel=2)


def print_warnings(take: str, messages) -> None:
    """Print a take's warnings on stderr, one line each, above any progress bar."""
    for message in messages:
        tqdm.write(f"mocap2mesh: warning: take {take}: {message}", file=sys.stderr)


def warn_unconverged(solutions, *, first_frame: int = 0) -> None:
    """Warn about each basis whose weights did not converge in every frame.

    Parameters
    ----------
    solutions : mapping of basis name to a solution with ``status`` and ``message``
        (:attr:`fit.pipeline.stages.FitResult.solutions`); status 0 is converged.
    first_frame : int
        The take's first frame number (the solver's messages count frames from 0).
    """
    for name, solution in solutions.items():
        if solution.status != 0:
            warnings.warn(f"fit of basis {name}: {solution.message} (frames counted from 0 at "
                          f"frame number {first_frame})", UserWarning, stacklevel=2)
