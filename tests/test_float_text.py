"""The vectorized float text against Python's own ``repr`` (the oracle), byte for byte."""

import sys

import numpy as np
import pytest
from helpers import kernel_or_numpy, numba_cannot_cache

from mocap.util import float_text
from mocap.util.float_text import (
    FIELD_WIDTH,
    _shortest_digits,
    csv_lines,
    float_fields,
    write_csv_lines,
)

N = 40_000


def _decimals(rng, digits, exponents):
    """Doubles nearest to random decimals ``d·10^e``, d of `digits` (low, high) digits."""
    mantissas = rng.integers(10 ** (digits[0] - 1), 10 ** digits[1], N)
    return np.array([float(f"{m}e{e}") for m, e in zip(mantissas, rng.integers(*exponents, N))])


def _cases():
    rng = np.random.default_rng(7)
    bits = rng.integers(0, 2 ** 63, N, dtype=np.uint64).view(np.float64)
    short = _decimals(rng, (1, 6), (-12, 12))
    powers_of_two = 2.0 ** rng.integers(-30, 60, N)
    powers_of_ten = np.array([float(10 ** k) for k in range(20)] + [10.0 ** -k for k in range(9)])
    return {
        "every bit pattern": np.where(rng.random(N) < 0.5, bits, -bits),
        "uniform weights": rng.random(N),
        "scaled": rng.random(N) * 10.0 ** rng.integers(-7, 19, N) * rng.choice([-1, 1], N),
        "15 digits or fewer": _decimals(rng, (1, 15), (-20, 3)),
        "16 and 17 digits": _decimals(rng, (16, 17), (-21, 0)),
        "next above short decimals": np.nextafter(short, np.inf),
        "next below short decimals": np.nextafter(short, -np.inf),
        "powers of two and below": np.concatenate([powers_of_two,
                                                   np.nextafter(powers_of_two, 0)]),
        "powers of ten and around": np.concatenate(
            [powers_of_ten, np.nextafter(powers_of_ten, 0), np.nextafter(powers_of_ten, np.inf)]),
        "times of a take": np.arange(N) / 59.94,
        "special": np.array([0.0, -0.0, np.nan, np.inf, -np.inf, 5e-324, -2.2250738585072014e-308,
                             1.7976931348623157e308, 1e-4, 9.999999999999999e-05, 1e16,
                             9999999999999998.0, 0.1, 0.5, 1.0, -1.0, 123.0]),
    }


@pytest.mark.parametrize("name, values", _cases().items())
def test_fields_are_what_repr_writes(name, values):
    chars, lengths = float_fields(values)
    assert chars.shape == (len(values), FIELD_WIDTH)
    got = [chars[i, :n].tobytes().decode() for i, n in enumerate(lengths)]
    expected = [repr(v) for v in values.tolist()]
    wrong = [(e, g) for e, g in zip(expected, got) if e != g]
    assert not wrong, f"{len(wrong)} of {len(values)} differ, e.g. {wrong[:3]}"


def test_the_exact_path_settles_all_but_ties():
    """Only ties and near-ties of a rounding go to repr: none of a million uniform weights."""
    values = np.random.default_rng(1).random(1_000_000)
    _, _, settled = _shortest_digits(values[values >= 1e-4])
    assert settled.all()


@pytest.fixture(params=["compiled", "numpy"])
def lines_by(request, monkeypatch):
    """csv_lines by the compiled kernel (numba: the speed extra, in .[test]) for any table,
    or by NumPy's array operations."""
    return kernel_or_numpy(request.param, monkeypatch, float_text, "_compiled_lines",
                           "_CELLS_WORTH_COMPILING")


def _percent_lines(index, cells) -> bytes:
    """The oracle: each line by Python's ``%d`` and ``%r``."""
    row = "%d" + ",%r" * cells.shape[1] + "\n"
    return "".join(row % (i, *c) for i, c in zip(index.tolist(), cells.tolist())).encode()


def test_csv_lines_are_the_percent_format(lines_by):
    rng = np.random.default_rng(2)
    cells = rng.normal(size=(5000, 7)) * 10.0 ** rng.integers(-6, 6, (5000, 7))
    cells[::3, 2], cells[1, 4], cells[2, 5] = 0.0, -0.0, 1e300
    cells[3, :3] = np.nan, np.inf, -np.inf
    index = np.arange(-40, 4960) * 3
    index[:2] = np.iinfo(np.int64).min, np.iinfo(np.int64).max
    assert b"".join(csv_lines(index, cells)) == _percent_lines(index, cells)


@pytest.mark.parametrize("name, values", _cases().items())
def test_lines_of_every_kind_of_value_are_what_repr_writes(name, values, lines_by):
    """Every case of the fields' test, as lines of 5 (and one column of what is left)."""
    whole = len(values) // 5 * 5
    for cells in (values[:whole].reshape(-1, 5), values[whole:, None]):
        index = np.arange(len(cells)) - 3
        assert b"".join(csv_lines(index, cells)) == _percent_lines(index, cells), name


def test_the_compiled_lines_are_loaded_for_a_table_that_pays_for_it(monkeypatch):
    """Loading numba costs about half a second: a process that has not loaded it writes a
    small table by NumPy, a large one by the compiled kernel, with the same bytes."""
    cells = np.random.default_rng(3).random((300, 4))
    expected = _percent_lines(np.arange(300), cells)
    used = []
    monkeypatch.setattr(float_text, "_compiled_lines",
                        lambda real=float_text._compiled_lines: used.append(1) or real())
    monkeypatch.delitem(sys.modules, "numba")
    assert not float_text.compiled_lines_ready()
    assert b"".join(csv_lines(np.arange(300), cells)) == expected and not used
    monkeypatch.setattr(float_text, "_CELLS_WORTH_COMPILING", cells.size)
    assert b"".join(csv_lines(np.arange(300), cells)) == expected and used


def test_numba_without_a_cache_folder_leaves_the_text_to_numpy_with_a_warning(monkeypatch):
    """numba raises RuntimeError where it can write its compiled code nowhere (a read-only
    install and home): in a process that has loaded numba, the lines are then NumPy's, the
    same bytes, with a warning."""
    import numba  # noqa: F401  (loaded: the compiled text would be used for any table)

    cells = np.random.default_rng(6).normal(size=(50, 4))
    numba_cannot_cache(monkeypatch, "mocap.util._float_text_kernel")
    float_text._compiled_lines.cache_clear()
    try:
        with pytest.warns(UserWarning, match="compiled CSV text is off .*no locator"):
            assert not float_text.compiled_lines_ready()
        assert b"".join(csv_lines(np.arange(50), cells)) == _percent_lines(np.arange(50), cells)
    finally:
        monkeypatch.undo()
        float_text._compiled_lines.cache_clear()
    assert float_text.compiled_lines_ready()            # numba caches again: compiled


def test_an_index_of_another_length_is_refused(lines_by):
    with pytest.raises(ValueError, match=r"an index of \(4,\) for 5 rows"):
        next(csv_lines(np.arange(4), np.zeros((5, 2))))


def test_a_wide_table_is_written_a_few_rows_at_a_time(lines_by, monkeypatch):
    """Blocks hold whole rows and about _CELLS_PER_BLOCK cells, one row at least: a table
    of any width is formatted in a few MB at a time."""
    monkeypatch.setattr(float_text, "_CELLS_PER_BLOCK", 1000)
    cells = np.random.default_rng(4).normal(size=(7, 300))
    blocks = list(csv_lines(np.arange(7), cells))
    assert [block.count(b"\n") for block in blocks] == [3, 3, 1]
    assert b"".join(blocks) == _percent_lines(np.arange(7), cells)
    wide = np.random.default_rng(5).normal(size=(3, 1500))
    blocks = list(csv_lines(np.arange(3), wide))
    assert [block.count(b"\n") for block in blocks] == [1, 1, 1]
    assert b"".join(blocks) == _percent_lines(np.arange(3), wide)


def test_written_lines_are_the_percent_format_in_blocks_from_one_buffer(lines_by, monkeypatch,
                                                                      tmp_path):
    """write_csv_lines writes each block from the memory it is made in (the compiled kernel
    makes every block in one buffer): the file holds every block as it was made, the text
    of %d and %r."""
    monkeypatch.setattr(float_text, "_CELLS_PER_BLOCK", 1000)
    rng = np.random.default_rng(6)
    cells = rng.normal(size=(400, 9)) * 10.0 ** rng.integers(-5, 8, (400, 9))
    index = np.arange(400) + 1
    with open(tmp_path / "lines.csv", "wb") as fh:
        write_csv_lines(fh, index, cells)
    assert (tmp_path / "lines.csv").read_bytes() == _percent_lines(index, cells)


def test_no_lines_for_no_rows(lines_by):
    assert b"".join(csv_lines(np.zeros(0, int), np.zeros((0, 3)))) == b""
    assert b"".join(csv_lines(np.arange(2), np.zeros((2, 0)))) == b"0\n1\n"
