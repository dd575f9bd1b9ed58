"""Median of each column of a table, skipping NaN, by one selection a column.

``np.nanmedian(a, axis=0)`` of a long (T, C) table copies and partitions one
strided column at a time, and a median of an even count asks ``np.partition``
for two order statistics, which it does several times slower than one. Here
the columns are copied contiguously, a few at a time, and each is partitioned at
its upper middle only; the lower middle is the largest value below it.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["nan_column_medians"]


def nan_column_medians(values) -> np.ndarray:
    """Median over the rows of `values` (T, ...) of its non-NaN entries, shape (...).

    The values of ``np.nanmedian(values, axis=0)`` (the mean of the two middle
    values of an even count), NaN where there is no value, and no warning for
    it. E.g. the per-marker median pose (M, 3) of positions (T, M, 3).

    Examples
    --------
    >>> nan_column_medians([[1.0, np.nan], [4.0, np.nan], [2.0, np.nan], [3.0, 5.0]]).tolist()
    [2.5, 5.0]
    """
    values = np.asarray(values, dtype=float)
    if values.ndim < 2:
        raise ValueError(f"nan_column_medians needs rows of values, got shape {values.shape}")
    table = values.reshape(len(values), math.prod(values.shape[1:]))
    out = np.full(table.shape[1], np.nan)
    # a few columns at a time: the transposed copy of a block stays in the cache
    width = max(1, _BLOCK_BYTES // (8 * max(len(table), 1)))
    for first in range(0, table.shape[1], width):
        block = slice(first, first + width)
        out[block] = _medians_of_rows(np.ascontiguousarray(table[:, block].T))
    return out.reshape(values.shape[1:])


#: Bytes of the transposed columns partitioned at a time.
_BLOCK_BYTES = 1 << 21


def _medians_of_rows(rows: np.ndarray) -> np.ndarray:
    """Median of each row of `rows` (C, T) over its non-NaN entries (NaN if none), (C,);
    `rows` is partitioned in place."""
    out = np.full(len(rows), np.nan)
    # np.partition orders NaN last: a row's n values are its first n entries after it
    counts = rows.shape[1] - np.count_nonzero(np.isnan(rows), axis=1)
    for n in np.unique(counts[counts > 0]):
        which = np.flatnonzero(counts == n)
        part = rows if len(which) == len(rows) else rows[which]
        upper = n // 2
        part.partition(upper, axis=1)
        high = part[:, upper]
        out[which] = high if n % 2 else (part[:, :upper].max(axis=1) + high) / 2
    return out
