"""Medians and percentiles by one selection each: NumPy's values, at a fraction of its cost.

NumPy asks ``np.partition`` for every order statistic its answer reads at once: both
middle values of an even count (``np.nanmedian``), or both neighbours of a percentile's
virtual index plus the smallest and the largest value (``np.percentile``). Two adjacent
order statistics cost it several times one. Here each answer costs one selection: the
lower (median: upper) neighbour is partitioned into place, and the other one is the
largest value below it or the smallest above it, one contiguous pass. Medians average
the two middle values as ``np.nanmedian`` does; percentiles interpolate by
``np.percentile``'s own formula (its ``"linear"`` method): the values are NumPy's, to the
bit. Tables are read a few columns at a time, each copied contiguously.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

__all__ = ["nan_column_medians", "nan_column_percentiles", "percentile"]


def nan_column_medians(values, columns=None) -> np.ndarray:
    """Median over the rows of `values` (T, ...) of its non-NaN entries, shape (...).

    The values of ``np.nanmedian(values, axis=0)`` (the mean of the two middle
    values of an even count), NaN where there is no value, and no warning for
    it. E.g. the per-marker median pose (M, 3) of positions (T, M, 3).

    `columns` (K,), int, optional: only these columns of the rows flattened, ``values.reshape(T,
    -1)[:, columns]``, each gathered as it is read (no copy of the table), shape (K,).

    Examples
    --------
    >>> nan_column_medians([[1.0, np.nan], [4.0, np.nan], [2.0, np.nan], [3.0, 5.0]]).tolist()
    [2.5, 5.0]
    """
    return _per_column(values, _middle, "nan_column_medians", columns)


def nan_column_percentiles(values, q: float) -> np.ndarray:
    """The `q`-th percentile over the rows of `values` (T, ...) of its non-NaN entries,
    shape (...).

    The values of ``np.nanpercentile(values, q, axis=0)`` (method ``"linear"``), NaN
    where there is no value, and no warning for it. E.g. each marker's 95th-percentile
    error (M,) of errors (T, M).

    Examples
    --------
    >>> nan_column_percentiles([[1.0, 5.0], [2.0, np.nan], [3.0, 7.0], [4.0, np.nan]],
    ...                        25).tolist()
    [1.75, 5.5]
    """
    quantile = float(_quantile(q))
    return _per_column(values, lambda part, n: _at_quantile(part, n, quantile),
                       "nan_column_percentiles")


def _per_column(values, select, what: str, columns=None) -> np.ndarray:
    """``select(part, n)`` of each column of `values` (T, ...), (...), or of the `columns`
    of its flattened rows, (K,) (see :func:`_by_count`)."""
    values = np.asarray(values, dtype=float)
    if values.ndim < 2:
        raise ValueError(f"{what} needs rows of values, got shape {values.shape}")
    table = values.reshape(len(values), math.prod(values.shape[1:]))
    picked = None if columns is None else np.asarray(columns, dtype=np.intp).reshape(-1)
    if picked is not None and picked.size and not (
            0 <= picked.min() and picked.max() < table.shape[1]):
        raise ValueError(f"{what}: columns must index the {table.shape[1]} columns, got "
                         f"{picked.min()}..{picked.max()}")
    out = np.full(table.shape[1] if picked is None else len(picked), np.nan)
    # a few columns at a time: the transposed copy of a block stays in the cache
    width = max(1, _BLOCK_BYTES // (8 * max(len(table), 1)))
    for first in range(0, len(out), width):
        block = slice(first, first + width)
        rows = table.T[block] if picked is None else table.T[picked[block]]
        out[block] = _by_count(np.ascontiguousarray(rows), select)
    return out.reshape(values.shape[1:]) if picked is None else out


def percentile(values, q, *, overwrite_input: bool = False):
    """``np.percentile(values, q)`` (method ``"linear"``) of all of `values`.

    Parameters
    ----------
    values : array_like
        Any shape, at least one value. As NumPy's: a NaN makes every percentile NaN, and
        one whose neighbours hold an infinity is what NumPy's interpolation makes of it
        (infinite or NaN).
    q : float or array_like of float
        Percentiles, in [0, 100].
    overwrite_input : bool
        Let the selection reorder `values` in place when it is a contiguous, writeable
        ndarray (no copy).

    Returns
    -------
    float, or ndarray of the shape of `q`

    Examples
    --------
    >>> percentile([4.0, 1.0, 3.0, 2.0], [0, 50, 95]).tolist()
    [1.0, 2.5, 3.8499999999999996]
    """
    values = np.asarray(values, dtype=float)
    if not values.size:
        raise ValueError("percentile of no values")
    in_place = overwrite_input and values.flags.c_contiguous and values.flags.writeable
    flat = values.reshape(-1) if in_place else values.flatten()
    quantiles = np.asarray(_quantile(q), dtype=float)
    out = np.empty(quantiles.shape)
    # ascending: each selection partitions only the values above the last one
    ordered = 0                     # flat[:ordered] lie below every value after them
    for i in np.argsort(quantiles, axis=None, kind="stable"):
        below, gamma = _neighbour(len(flat), float(quantiles.flat[i]))
        if below >= ordered:
            flat[ordered:].partition(below - ordered)
            ordered = below + 1
        upper = flat[below + 1:].min() if below + 1 < len(flat) else flat[below]
        out.flat[i] = _lerp(flat[below], upper, gamma)
    return float(out) if out.ndim == 0 else out


def _quantile(q) -> float | np.ndarray:
    """`q` percent as NumPy's fraction (``q / 100``), checked to be within [0, 1]."""
    quantile = np.true_divide(q, 100)
    if not np.all((quantile >= 0) & (quantile <= 1)):
        raise ValueError(f"percentiles must be in the range [0, 100], got {q!r}")
    return quantile


def _neighbour(n: int, quantile: float) -> tuple[int, float]:
    """The lower neighbour of the virtual index ``(n − 1) q`` of `n` values, and the weight
    of the upper one, as NumPy's ``"linear"`` method takes them (at the last value, both
    neighbours are the last one)."""
    virtual = (n - 1) * quantile
    if virtual >= n - 1:
        return n - 1, 0.0
    below = int(virtual)            # the floor: the index is not negative
    return below, virtual - below


def _lerp(low, high, gamma: float):
    """NumPy's interpolation between neighbours `low` and `high` (scalars or arrays) with
    the weight `gamma` of `high`: from the nearer one, to the bit."""
    with np.errstate(invalid="ignore"):         # infinities give NaN, as NumPy's
        step = high - low
        return high - step * (1 - gamma) if gamma >= 0.5 else low + step * gamma


def _at_quantile(part: np.ndarray, n: int, quantile: float) -> np.ndarray:
    """The percentile at `quantile` of the first `n` entries of each row of `part` (the
    others NaN), partitioned in place."""
    below, gamma = _neighbour(n, quantile)
    part.partition(below, axis=1)
    low = part[:, below]
    high = part[:, below + 1:n].min(axis=1) if below + 1 < n else low
    return _lerp(low, high, gamma)


def _middle(part: np.ndarray, n: int) -> np.ndarray:
    """The median of the first `n` entries of each row of `part` (the others NaN),
    partitioned in place."""
    upper = n // 2
    part.partition(upper, axis=1)
    high = part[:, upper]
    return high if n % 2 else (part[:, :upper].max(axis=1) + high) / 2


#: Bytes of a table's transposed columns partitioned at a time.
_BLOCK_BYTES = 1 << 21


def _by_count(rows: np.ndarray, select: Callable[[np.ndarray, int], np.ndarray]) -> np.ndarray:
    """``select(part, n)`` of the rows of `rows` (R, T) with `n` non-NaN entries, for each
    count n, into (R,) (NaN for a row without one); `rows` is partitioned in place.

    np.partition orders NaN last: a row's n values are its first n entries after it.
    """
    out = np.full(len(rows), np.nan)
    counts = rows.shape[1] - np.count_nonzero(np.isnan(rows), axis=1)
    for n in np.unique(counts[counts > 0]):
        which = np.flatnonzero(counts == n)
        part = rows if len(which) == len(rows) else rows[which]
        out[which] = select(part, int(n))
    return out
