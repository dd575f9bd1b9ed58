"""Medians and percentiles by one selection each, against NumPy's own (the oracle), to the bit."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from mocap.util.order_statistics import nan_column_medians, nan_column_percentiles, percentile

#: Percentiles that reach every branch: the ends, a neighbour weight of exactly 0.5 for
#: an odd count, weights on either side of it, and the report's.
QS = (0.0, 1e-9, 12.5, 49.99, 50.0, 95.0, 99.5, 100 - 1e-12, 100.0)


def _with_ties_and_gaps(rng, n_rows: int, n_columns: int = 9) -> np.ndarray:
    """A table whose columns have ties, gaps of every share and one with no value."""
    values = rng.normal(size=(n_rows, n_columns))
    values[:, 7] = np.round(values[:, 7])                       # ties
    for column in range(1, 6):                                  # 0 .. all of it missing
        values[rng.random(n_rows) < column / 5, column] = np.nan
    values[:, 8] = np.nan
    return values


@pytest.mark.parametrize("n_rows", [1, 2, 3, 4, 7, 600, 601, 35_000])
def test_nan_column_medians_are_numpys(n_rows):
    """Odd and even counts, columns with gaps of every length, all-NaN columns, ties."""
    values = _with_ties_and_gaps(np.random.default_rng(n_rows), n_rows)
    before = values.copy()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)         # numpy's all-NaN warning
        expected = np.nanmedian(values, axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")                          # ours warns of nothing
        medians = nan_column_medians(values[:, ::-1])[::-1]     # a strided view
    np.testing.assert_array_equal(medians, expected)
    np.testing.assert_array_equal(values, before)


def test_nan_column_medians_of_positions_are_a_pose():
    rng = np.random.default_rng(5)
    positions = rng.normal(size=(40, 6, 3))
    positions[rng.random((40, 6)) < 0.3] = np.nan               # missing samples
    np.testing.assert_array_equal(nan_column_medians(positions),
                                  np.nanmedian(positions, axis=0))


@pytest.mark.parametrize("n_rows", [5, 35_000])
def test_nan_column_medians_of_picked_columns_are_numpys_of_those_columns(n_rows):
    """Columns picked in any order, some twice, across several blocks of the table."""
    values = _with_ties_and_gaps(np.random.default_rng(n_rows + 1), n_rows)
    positions = np.concatenate([values, values[:, ::-1]], axis=1)[:, :18].reshape(n_rows, 6, 3)
    columns = np.array([17, 3, 4, 5, 0, 8, 8, 12, 1, 16, 2])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)         # numpy's all-NaN warning
        expected = np.nanmedian(positions.reshape(n_rows, -1)[:, columns], axis=0)
    np.testing.assert_array_equal(nan_column_medians(positions, columns), expected)
    with pytest.raises(ValueError, match="columns must index the 18 columns, got 0..18"):
        nan_column_medians(positions, [0, 18])


def test_nan_column_medians_need_rows():
    with pytest.raises(ValueError, match="rows"):
        nan_column_medians(np.zeros(3))
    assert np.isnan(nan_column_medians(np.zeros((0, 2)))).all()   # no rows, no median


@pytest.mark.parametrize("n_rows", [1, 2, 3, 4, 7, 600, 601, 35_000])
@pytest.mark.parametrize("q", QS)
def test_nan_column_percentiles_are_numpys(n_rows, q):
    """Every count of values a column can have (gaps), ties, all-NaN columns, a view."""
    values = _with_ties_and_gaps(np.random.default_rng(n_rows), n_rows)
    before = values.copy()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        expected = np.nanpercentile(values, q, axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ours = nan_column_percentiles(values[:, ::-1], q)[::-1]
    np.testing.assert_array_equal(ours, expected)
    np.testing.assert_array_equal(values, before)


def test_nan_column_percentiles_of_errors_per_marker():
    """The metrics' use: each marker's 95th percentile over frames (T, M), of a take
    without a gap (NumPy's plain percentile) and over the frames that count."""
    rng = np.random.default_rng(3)
    errors = np.abs(rng.normal(0.0, 0.3, (3_870, 66)))
    np.testing.assert_array_equal(nan_column_percentiles(errors, 95),
                                  np.percentile(errors, 95, axis=0))
    errors[rng.random(errors.shape) < 0.05] = np.nan
    np.testing.assert_array_equal(nan_column_percentiles(errors.reshape(-1, 22, 3), 95),
                                  np.nanpercentile(errors, 95, axis=0).reshape(22, 3))


@pytest.mark.parametrize("n", [1, 2, 3, 10, 11, 1000, 100_001])
def test_percentile_is_numpys(n):
    """Scalars and arrays of q in any order (repeated ones too), ties, any shape."""
    rng = np.random.default_rng(n)
    values = rng.normal(size=(n, 1))                            # a 2-D input
    values[::3] = np.round(values[::3])
    for q in QS:
        assert percentile(values, q) == np.percentile(values, q)
        assert isinstance(percentile(values, q), float)
    qs = np.array([[95.0, 0.0, 50.0], [50.0, 99.5, 12.5]])
    np.testing.assert_array_equal(percentile(values, qs), np.percentile(values, qs))
    np.testing.assert_array_equal(percentile(values.ravel(), list(QS)),
                                  np.percentile(values, QS))


def test_percentile_overwrites_only_when_asked_and_able():
    rng = np.random.default_rng(0)
    values = rng.normal(size=1001)
    before = values.copy()
    expected = np.percentile(values, 95)
    assert percentile(values, 95) == expected
    np.testing.assert_array_equal(values, before)               # a copy was partitioned
    assert percentile(values, 95, overwrite_input=True) == expected
    assert not np.array_equal(values, before)                   # partitioned in place
    np.testing.assert_array_equal(np.sort(values), np.sort(before))
    frozen = before.copy()
    frozen.flags.writeable = False
    assert percentile(frozen, 95, overwrite_input=True) == expected   # read-only: a copy
    assert percentile(before[::2], 95, overwrite_input=True) == np.percentile(before[::2], 95)


def test_percentile_of_nan_or_infinity_is_numpys():
    """A NaN makes NumPy's percentiles NaN; next to an infinity its interpolation gives an
    infinity or NaN: ours the same."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for values in ([1.0, 2.0, np.nan], [np.nan], [1.0, np.inf], [-np.inf, 1.0, 2.0],
                       [1.0, 2.0, np.inf]):
            for q in (0.0, 50.0, 60.0, 100.0):
                assert np.isnan(percentile(values, q)) == np.isnan(np.percentile(values, q))
                assert np.array_equal(percentile(values, q), np.percentile(values, q),
                                      equal_nan=True)


def test_percentiles_outside_the_range_or_of_nothing_are_refused():
    with pytest.raises(ValueError, match="range"):
        percentile([1.0, 2.0], 101)
    with pytest.raises(ValueError, match="range"):
        nan_column_percentiles([[1.0], [2.0]], -1)
    with pytest.raises(ValueError, match="no values"):
        percentile([], 50)
    with pytest.raises(ValueError, match="rows"):
        nan_column_percentiles(np.zeros(3), 50)


def _sampling_adversaries(rng, n_rows: int = 35_000) -> np.ndarray:
    """Long columns that a sample can mislead, or that hold what a bracket must handle:
    sorted and reversed, heavy ties, infinities, every sampled value an outlier, counts of
    values about where sampling starts (4,096), and a column of one value."""
    columns = [np.sort(rng.normal(size=n_rows)), np.sort(rng.normal(size=n_rows))[::-1],
               rng.integers(0, 4, n_rows).astype(float), rng.normal(size=n_rows),
               rng.normal(size=n_rows), rng.normal(size=n_rows), rng.normal(size=n_rows),
               np.full(n_rows, 2.5)]
    columns[3][rng.random(n_rows) < 0.02] = np.inf
    columns[3][rng.random(n_rows) < 0.02] = -np.inf
    columns[4][::n_rows // 1024] = -50.0          # the strided sample: outliers only
    for column, kept in ((5, 4096), (6, 4095)):
        columns[column][rng.permutation(n_rows)[kept:]] = np.nan
    return np.column_stack(columns)


@pytest.mark.parametrize("q", QS)
def test_long_columns_sampled_or_not_give_numpys_order_statistics(q, monkeypatch):
    """The sampled selection's answers are NumPy's, including where the sample misleads the
    bracket (that column is partitioned whole)."""
    import mocap.util.order_statistics as order_statistics

    values = _sampling_adversaries(np.random.default_rng(11))
    whole = []
    partitioned = order_statistics._partitioned

    def spied(rows, n, k):
        if rows.shape[1] == len(values):
            whole.append(n)
        return partitioned(rows, n, k)
    monkeypatch.setattr(order_statistics, "_partitioned", spied)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)         # inf - inf in NumPy's lerp
        np.testing.assert_array_equal(nan_column_percentiles(values, q),
                                      np.nanpercentile(values, q, axis=0))
        np.testing.assert_array_equal(nan_column_medians(values), np.nanmedian(values, axis=0))
        for column in values.T:
            finite = column[~np.isnan(column)]
            assert np.array_equal(percentile(finite, q), np.percentile(finite, q),
                                  equal_nan=True)
    assert len(values) in whole and 4095 in whole           # misled, and too few to sample


def test_a_long_array_with_a_nan_has_nan_percentiles():
    values = np.random.default_rng(2).normal(size=50_000)
    values[123] = np.nan
    np.testing.assert_array_equal(percentile(values, [0.0, 50.0, 100.0]), [np.nan] * 3)
