"""The vectorized float text against Python's own ``repr`` (the oracle), byte for byte."""

import numpy as np
import pytest

from mocap.util.float_text import FIELD_WIDTH, _shortest_digits, csv_lines, float_fields

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


def test_csv_lines_are_the_percent_format():
    rng = np.random.default_rng(2)
    cells = rng.normal(size=(5000, 7)) * 10.0 ** rng.integers(-6, 6, (5000, 7))
    cells[::3, 2], cells[1, 4], cells[2, 5] = 0.0, -0.0, 1e300
    index = np.arange(-40, 4960) * 3
    text = b"".join(csv_lines(index, cells))
    row = "%d" + ",%r" * cells.shape[1] + "\n"
    assert text == "".join(row % (i, *c) for i, c in zip(index.tolist(), cells.tolist())).encode()


def test_no_lines_for_no_rows():
    assert b"".join(csv_lines(np.zeros(0, int), np.zeros((0, 3)))) == b""
