"""Filling the samples of a performance where tracking was lost, when the user asks.

A Live Link Face export keeps the rows where the phone lost the face (every
weight empty; :func:`mocap.synth.performance.read_performance` reads them as
NaN and reports them). Nothing fills them on its own: a caller that needs
weights everywhere says how, with :func:`fill_tracking_gaps`.
"""

from __future__ import annotations

import numpy as np

from mocap.errors import InputError
from mocap.synth.performance import Performance
from mocap.util.validation import as_choice, as_positive_float

__all__ = ["TRACKING_FILLS", "fill_tracking_gaps"]

#: How :func:`fill_tracking_gaps` fills a run of lost samples: each weight
#: interpolated in time between the tracked samples around it (held at the
#: nearest one when the run starts or ends the performance), or the neutral
#: face (every weight 0).
TRACKING_FILLS = ("linear", "neutral")


def fill_tracking_gaps(performance: Performance, method: str, *,
                       max_duration: float | None = None) -> Performance:
    """The performance with its lost samples filled by `method`.

    Parameters
    ----------
    performance : Performance
    method : {"linear", "neutral"}
        See :data:`TRACKING_FILLS`.
    max_duration : float, optional, s
        Runs longer than this (:attr:`mocap.synth.performance.TrackingGap.duration`)
        stay lost; default: fill every run.

    Returns
    -------
    Performance
        Same times and names; the filled samples hold numbers.

    Raises
    ------
    InputError
        Not a Performance, an unknown method, a `max_duration` that is not positive.

    Examples
    --------
    >>> w = np.array([[0.2], [np.nan], [np.nan], [0.8]])
    >>> p = Performance(("JawOpen",), [0.0, 1.0, 2.0, 3.0], w, 1.0)
    >>> fill_tracking_gaps(p, "linear").weights.ravel().round(3).tolist()
    [0.2, 0.4, 0.6, 0.8]
    >>> fill_tracking_gaps(p, "neutral").weights.ravel().tolist()
    [0.2, 0.0, 0.0, 0.8]
    """
    if not isinstance(performance, Performance):
        raise InputError(f"performance must be a Performance, got {type(performance).__name__}")
    method = as_choice(method, "method", TRACKING_FILLS)
    if max_duration is not None:
        max_duration = as_positive_float(max_duration, "max_duration")
    fill = np.zeros(performance.n_frames, dtype=bool)
    for gap in performance.gaps():
        if max_duration is None or gap.duration <= max_duration:
            fill[gap.start:gap.stop] = True
    weights = np.array(performance.weights)
    if method == "neutral":
        weights[fill] = 0.0
    else:
        tracked = ~performance.lost
        times = performance.times
        for j in range(weights.shape[1]):          # shapes, not frames: one np.interp each
            weights[fill, j] = np.interp(times[fill], times[tracked], weights[tracked, j])
    return Performance(performance.names, performance.times, weights, performance.rate,
                       ignored=performance.ignored, path=performance.path)
