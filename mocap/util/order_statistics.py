"""Medians and percentiles by one selection each: NumPy's values, at a fraction of its cost.

NumPy asks ``np.partition`` for every order statistic its answer reads at once: both
middle values of an even count (``np.nanmedian``), or both neighbours of a percentile's
virtual index plus the smallest and the largest value (``np.percentile``). Two adjacent
order statistics cost it several times one. Here each answer costs one selection of the
pair of neighbours. In a long row (a marker's track, a take's errors) the selection is
Floyd and Rivest's: an evenly spaced sample of the row brackets the pair between two of
its values, one pass counts the values below the bracket and gathers those inside it
(a tenth of a take's track, less of longer rows), and only those are partitioned; a row
whose sample misled the bracket is partitioned whole, so the answer is always exact.
Medians average the two middle values as ``np.nanmedian`` does; percentiles interpolate
by ``np.percentile``'s own formula (its ``"linear"`` method): the values are NumPy's, to
the bit. Tables are read a few columns at a time, each copied contiguously.
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
    # a NaN makes NumPy's every percentile NaN: the partition (NaN last) reads it
    sampled = len(flat) >= _SAMPLED_FROM and not np.isnan(flat).any()
    # ascending: each partition reorders only the values above the last one
    ordered = 0                     # flat[:ordered] lie below every value after them
    for i in np.argsort(quantiles, axis=None, kind="stable"):
        below, gamma = _neighbour(len(flat), float(quantiles.flat[i]))
        if sampled:
            low, high = (float(v[0]) for v in _pairs(flat[None], len(flat), below))
        else:
            if below >= ordered:
                flat[ordered:].partition(below - ordered)
                ordered = below + 1
            low = flat[below]
            high = flat[below + 1:].min() if below + 1 < len(flat) else low
        out.flat[i] = _lerp(low, high, gamma)
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
    """The percentile at `quantile` of the `n` non-NaN entries of each row of `part` (R, T)
    (which may be reordered)."""
    below, gamma = _neighbour(n, quantile)
    return _lerp(*_pairs(part, n, below), gamma)


def _middle(part: np.ndarray, n: int) -> np.ndarray:
    """The median of the `n` non-NaN entries of each row of `part` (R, T) (which may be
    reordered)."""
    if n % 2:
        return _pairs(part, n, n // 2)[0]
    low, high = _pairs(part, n, n // 2 - 1)
    return (low + high) / 2


#: Values a row holds at least for its order statistics to be found from a sample of it
#: (with fewer, one partition of the row costs less than the sample and its passes).
_SAMPLED_FROM = 4096


def _pairs(rows: np.ndarray, n: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The order statistics k and k + 1 (from 0; k again when k = n − 1) of the `n` non-NaN
    values of each row of `rows` (R, T), (R,) each; `rows` may be reordered.

    With many values, those between a bracket of the pair made from a sample of the row
    (:func:`_bracket`) are gathered in one pass, and only they are partitioned; a row whose
    bracket misses the pair is partitioned whole.
    """
    if n < _SAMPLED_FROM:
        return _partitioned(rows, n, k)
    upper = min(k + 1, n - 1)
    low, high = _bracket(rows, n, k, upper)
    below = np.count_nonzero(rows < low[:, None], axis=1)
    inside = (rows >= low[:, None]) & (rows <= high[:, None])       # a NaN is neither
    counts = np.count_nonzero(inside, axis=1)
    gathered, ends = rows[inside], np.cumsum(counts)                # row after row
    first, second = np.empty(len(rows)), np.empty(len(rows))
    for row in range(len(rows)):
        if below[row] <= k and upper < below[row] + counts[row]:
            part = gathered[ends[row] - counts[row]:ends[row]][None]
            pair = _partitioned(part, counts[row], k - below[row])
        else:                                       # the sample misled the bracket
            pair = _partitioned(rows[row:row + 1], n, k)
        first[row], second[row] = pair[0][0], pair[1][0]
    return first, second


def _partitioned(rows: np.ndarray, n: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_pairs` by partitioning each row of `rows` whole (in place)."""
    rows.partition(k, axis=1)                       # NaN last: the n values come first
    first = rows[:, k]
    return first, (rows[:, k + 1:n].min(axis=1) if k + 1 < n else first)


def _bracket(rows: np.ndarray, n: int, k: int, upper: int) -> tuple[np.ndarray, np.ndarray]:
    """Values of each row of `rows` (R, T) between which its order statistics k to `upper`
    of `n` most likely lie, (R,) each (−∞ or ∞ where the sample cannot tell).

    From every j-th value of the row, about T^(2/3) of its T (as Floyd and Rivest's sample:
    the sort of a larger one, or the partition of the values of a wider bracket, would cost
    more): the statistic of rank r sits near rank r m / n of the sample's m values, off by a
    binomial count whose standard deviation is at most √m / 2; the bracket reaches three of
    them further, and two values more.
    """
    step = max(1, round(rows.shape[1] ** (1 / 3)))
    sample = np.sort(rows[:, ::step], axis=1)                                   # NaN last
    m = sample.shape[1] - np.count_nonzero(np.isnan(sample), axis=1)
    margin = 1.5 * np.sqrt(m) + 2
    lowest = np.floor(k / n * m - margin).astype(np.intp)
    highest = np.ceil((upper + 1) / n * m + margin).astype(np.intp)
    every = np.arange(len(rows))
    low = sample[every, np.clip(lowest, 0, sample.shape[1] - 1)]
    high = sample[every, np.clip(highest, 0, sample.shape[1] - 1)]
    return np.where(lowest >= 0, low, -np.inf), np.where(highest < m, high, np.inf)


#: Bytes of a table's transposed columns partitioned at a time.
_BLOCK_BYTES = 1 << 21


def _by_count(rows: np.ndarray, select: Callable[[np.ndarray, int], np.ndarray]) -> np.ndarray:
    """``select(part, n)`` of the rows of `rows` (R, T) with `n` non-NaN entries, for each
    count n, into (R,) (NaN for a row without one); `rows` may be reordered.

    np.partition orders NaN last: a row's n values are its first n entries after it.
    """
    out = np.full(len(rows), np.nan)
    counts = rows.shape[1] - np.count_nonzero(np.isnan(rows), axis=1)
    for n in np.unique(counts[counts > 0]):
        which = np.flatnonzero(counts == n)
        part = rows if len(which) == len(rows) else rows[which]
        out[which] = select(part, int(n))
    return out
