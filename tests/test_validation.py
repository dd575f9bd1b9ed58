"""Tests of mocap.util.validation.as_float_array's checks of non-finite values."""

from __future__ import annotations

import numpy as np
import pytest

from mocap.errors import InputError
from mocap.util.validation import as_float_array


@pytest.mark.parametrize("bad, message", [(np.inf, "infinite"), (-np.inf, "infinite"),
                                          (np.nan, "NaN")])
def test_one_non_finite_value_among_many_is_found(bad, message):
    values = np.random.default_rng(0).normal(size=(300, 7))
    values[123, 4] = bad
    with pytest.raises(InputError, match=message):
        as_float_array(values, "x", allow_nan=False)


def test_finite_values_whose_sum_overflows_are_accepted():
    """Values that are finite (numpy's own test) pass, though their sum is infinite."""
    values = np.full(10, 1e308)
    with np.errstate(over="ignore"):
        assert np.all(np.isfinite(values)) and not np.isfinite(values.sum())
    with np.errstate(all="raise"):
        np.testing.assert_array_equal(as_float_array(values, "x", allow_nan=False), values)


def test_nan_allowed_when_asked_and_inf_still_refused():
    values = np.array([1.0, np.nan, 2.0])
    np.testing.assert_array_equal(as_float_array(values, "x"), values)
    with pytest.raises(InputError, match="infinite"):
        as_float_array([np.nan, np.inf, -np.inf], "x")


def test_float64_is_not_copied_with_copy_false():
    values = np.zeros((4, 3))
    assert as_float_array(values, "x", copy=False) is values
    assert as_float_array(values, "x") is not values
