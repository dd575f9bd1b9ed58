"""Take validation and the gap finder."""

import numpy as np
import pytest

from mocap import InputError, MarkerError, Take
from mocap.gaps import find_gaps
from mocap.take import take_of_checked_samples


def test_take_copies_and_freezes_positions():
    pos = np.zeros((3, 2, 3))
    take = Take(("a", "b"), pos, rate=50)
    pos[0, 0, 0] = 7.0
    assert take.positions[0, 0, 0] == 0.0
    with pytest.raises(ValueError):
        take.positions[0, 0, 0] = 1.0


def test_take_rejects_partial_nan():
    pos = np.zeros((3, 2, 3))
    pos[1, 1, 2] = np.nan
    with pytest.raises(MarkerError, match="'b': frame index 1 has some coordinates NaN"):
        Take(("a", "b"), pos, rate=50)


@pytest.mark.parametrize("specials", [[np.nan], [np.nan, 1e308, -1e308],
                                      [np.inf, -np.inf, np.nan, 1e308]],
                         ids=["nan", "nan-and-overflowing-sums", "infinite"])
def test_take_validation_agrees_with_a_check_of_every_sample(specials):
    """Infinite values are refused, samples partly NaN named (the first in frame, then
    marker order), finite values whose sum overflows kept: the oracle is np.isinf and
    np.isnan of every coordinate."""
    rng = np.random.default_rng(len(specials))
    labels = ("a", "b", "c", "d")
    outcomes = set()
    for _ in range(60):
        pos = rng.normal(size=(30, 4, 3))
        pick = rng.random(pos.shape) < rng.choice([0.0, 0.003, 0.02])
        pos[pick] = rng.choice(specials, size=pick.sum())
        pos[rng.random((30, 4)) < 0.1] = np.nan
        nan = np.isnan(pos)
        partial = nan.any(axis=2) & ~nan.all(axis=2)
        if np.isinf(pos).any():
            outcomes.add("infinite")
            with pytest.raises(InputError, match="positions contains infinite values"):
                Take(labels, pos, rate=50)
        elif partial.any():
            outcomes.add("partial")
            t, m = np.argwhere(partial)[0]
            with pytest.raises(MarkerError, match=f"'{labels[m]}': frame index {t} has"):
                Take(labels, pos, rate=50)
        else:
            outcomes.add("valid")
            np.testing.assert_array_equal(Take(labels, pos, rate=50).positions, pos)
    assert outcomes >= {"partial", "valid"}
    overflowing = np.full((1, 1, 3), 1e308)
    np.testing.assert_array_equal(Take(("a",), overflowing, rate=50).positions, overflowing)


def test_a_take_of_checked_samples_is_validated_but_for_its_samples():
    """The readers' constructor leaves the samples to its caller and checks the rest as
    Take does; a take made after it in the same thread checks its samples again."""
    pos = np.zeros((3, 2, 3))
    pos[1, 1] = np.nan
    made = take_of_checked_samples(("a", "b"), pos, 50.0, first_frame=4)
    checked = Take(("a", "b"), pos, rate=50, first_frame=4)
    np.testing.assert_array_equal(made.positions, checked.positions)
    assert (made.labels, made.rate, made.first_frame) == (checked.labels, 50.0, 4)
    assert not made.positions.flags.writeable
    with pytest.raises(MarkerError, match="more than once"):
        take_of_checked_samples(("a", "a"), pos, 50.0)
    with pytest.raises(InputError, match="2 markers but 1 labels"):
        take_of_checked_samples(("a",), pos, 50.0)
    with pytest.raises(InputError, match="rate must be positive"):
        take_of_checked_samples(("a", "b"), pos, 0.0)
    pos[2, 0, 1] = np.nan
    take_of_checked_samples(("a", "b"), pos, 50.0)      # its maker's word, not re-read
    with pytest.raises(MarkerError, match="'a': frame index 2 has some coordinates NaN"):
        Take(("a", "b"), pos, rate=50)


def test_take_rejects_duplicate_labels_and_bad_rate():
    with pytest.raises(MarkerError, match="more than once"):
        Take(("a", "a"), np.zeros((1, 2, 3)), rate=50)
    with pytest.raises(InputError, match="rate must be positive"):
        Take(("a",), np.zeros((1, 1, 3)), rate=0)
    with pytest.raises(InputError, match="2 markers but 1 labels"):
        Take(("a",), np.zeros((1, 2, 3)), rate=50)


def test_unknown_marker_names_known_ones():
    take = Take(("a", "b"), np.zeros((1, 2, 3)), rate=50)
    with pytest.raises(MarkerError, match="'zz': not in the take"):
        take.marker("zz")


def test_find_gaps_against_a_loop():
    rng = np.random.default_rng(0)
    missing = rng.random((200, 7)) < 0.3
    gaps = find_gaps(missing)
    expect = []
    for m in range(7):
        t = 0
        while t < 200:
            if missing[t, m]:
                s = t
                while t < 200 and missing[t, m]:
                    t += 1
                expect.append((m, s, t))
            else:
                t += 1
    assert list(zip(gaps.marker, gaps.start, gaps.stop)) == expect
    assert gaps.length.sum() == missing.sum()


def test_take_keeps_an_immutable_array_and_copies_anything_else():
    owned = np.zeros((4, 2, 3))
    owned.flags.writeable = False
    assert Take(("a", "b"), owned, 100.0).positions is owned          # no second copy
    writable = np.zeros((4, 2, 3))
    take = Take(("a", "b"), writable, 100.0)
    writable[0, 0] = 5.0
    assert take.positions[0, 0, 0] == 0.0
    view = writable.view()
    view.flags.writeable = False                   # read-only, but its memory is not
    take = Take(("a", "b"), view, 100.0)
    writable[1, 0] = 7.0
    assert take.positions[1, 0, 0] == 0.0
    # the fill codes alike; codes of another integer type are converted
    codes = np.zeros((4, 2), np.uint8)
    codes.flags.writeable = False
    assert Take(("a", "b"), owned, 100.0, filled=codes).filled is codes
    codes = np.zeros((4, 2), np.uint8)
    take = Take(("a", "b"), owned, 100.0, filled=codes)
    codes[0, 0] = 1
    assert take.filled[0, 0] == 0 and not take.filled.flags.writeable
    wide = np.ones((4, 2), np.int64)
    wide.flags.writeable = False
    assert Take(("a", "b"), owned, 100.0, filled=wide).filled.dtype == np.uint8


def test_select_is_the_take_of_those_columns():
    """select gathers without re-validating: the result equals a take built from the columns."""
    rng = np.random.default_rng(1)
    positions = rng.standard_normal((50, 5, 3))
    positions[10:20, 3] = np.nan
    filled = rng.integers(0, 2, (50, 5)).astype(np.uint8)
    take = Take(tuple("abcde"), positions, rate=120.0, first_frame=7, filled=filled)
    got = take.select(["d", "a", "e"])
    want = Take(("d", "a", "e"), positions[:, [3, 0, 4]], rate=120.0, first_frame=7,
                filled=filled[:, [3, 0, 4]])
    assert got.labels == want.labels and got.rate == want.rate
    assert got.first_frame == want.first_frame and got.source == take.source
    np.testing.assert_array_equal(got.positions, want.positions)
    np.testing.assert_array_equal(got.filled, want.filled)
    assert not got.positions.flags.writeable and not got.filled.flags.writeable
    assert take.positions.shape == (50, 5, 3)               # the original is untouched
    with pytest.raises(MarkerError, match="'a'.*more than once"):
        take.select(["a", "b", "a"])
    with pytest.raises(MarkerError, match="'z'"):
        take.select(["a", "z"])
