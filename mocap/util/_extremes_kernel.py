"""Smallest and largest value of each column in one compiled pass (numba, the ``speed``
extra).

:func:`mocap.util.extremes.column_extremes` in NumPy halves the rows twice (once for the
minima, once for the maxima): about two passes over the array each. This reads it once,
the min and the max of every value together, without the GIL: a third of the time.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["column_extremes_of_rows"]

#: Values compared side by side: as many whole rows as fit in 64 (one row if it is wider).
_LANES = 64


@numba.njit(cache=True, nogil=True, inline="always")
def _least(x, y):  # pragma: no cover - compiled
    """The lesser of `x` and `y`, NaN if `x` is (a NaN met stays)."""
    return x if x < y or x != x else y


@numba.njit(cache=True, nogil=True, inline="always")
def _greatest(x, y):  # pragma: no cover - compiled
    """The greater of `x` and `y`, NaN if `x` is (a NaN met stays)."""
    return x if x > y or x != x else y


@numba.njit(cache=True, nogil=True)
def column_extremes_of_rows(flat, columns, low, high):  # pragma: no cover - compiled
    """The min and max over the rows of each table of `flat` (B, R·C), its rows of
    `columns` (C) values one after another, into `low` and `high` (B, C).

    A NaN makes its column's min and max NaN, as NumPy's ``minimum`` does. Each table's
    values are read a group of whole rows (:data:`_LANES` values or one row) at a time,
    each lane keeping its running min and max (no reduction in the inner loop, so that it
    runs on the vector units); the lanes of a column are reduced at the end, then the rows
    after the last whole group are taken.
    """
    n = flat.shape[1]
    lanes = columns * max(1, _LANES // columns)
    lane_low = np.empty(lanes, flat.dtype)
    lane_high = np.empty(lanes, flat.dtype)
    whole = n // lanes * lanes
    for b in range(flat.shape[0]):
        values = flat[b]
        for j in range(columns):
            low[b, j] = high[b, j] = values[j]
        if whole:
            lane_low[:] = values[:lanes]
            lane_high[:] = values[:lanes]
            for start in range(lanes, whole, lanes):
                for i in range(lanes):
                    lane_low[i] = _least(values[start + i], lane_low[i])
                    lane_high[i] = _greatest(values[start + i], lane_high[i])
            for i in range(lanes):
                low[b, i % columns] = _least(lane_low[i], low[b, i % columns])
                high[b, i % columns] = _greatest(lane_high[i], high[b, i % columns])
        for i in range(whole, n):
            low[b, i % columns] = _least(values[i], low[b, i % columns])
            high[b, i % columns] = _greatest(values[i], high[b, i % columns])
