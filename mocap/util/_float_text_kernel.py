"""CSV lines of floats as ``repr`` writes them, one compiled pass (numba, the ``speed`` extra).

The same arithmetic as :mod:`mocap.util.float_text`'s array operations, value by value, with
the text written straight into the lines: about a third of the time (NumPy spends the rest on
its temporaries and on gathering the fields' characters). A value it does not settle exactly
is marked, and :func:`lines` takes its text from ``repr``.
"""

from __future__ import annotations

import numba
import numpy as np

from mocap.util import float_text

__all__ = ["csv_block", "shortest_digits", "lines"]

#: What :func:`shortest_digits` found: positional digits, ``0.0``, or ``repr``'s to take.
DIGITS, ZERO, REPR = 0, 1, 2
_POW10 = float_text._POW10
#: Dekker's two-product, compiled into the loop.
_two_product = numba.njit(inline="always")(float_text._two_product)
#: The doubles nearest 10^-5 ... 10^16.
_NEAR_POW10 = np.array([float(f"1e{k}") for k in range(-5, 17)])
#: 2^j for j from _POW2_FIRST: half a double's spacing, by its binary exponent.
_POW2_FIRST = -70
_POW2 = np.ldexp(1.0, np.arange(_POW2_FIRST, 8))
#: The two characters of 0-99.
_PAIRS = np.ascontiguousarray(float_text._GROUPS[:100, 2:])


def csv_block(index, cells, out) -> np.ndarray:
    """The CSV lines of a block of rows, as :func:`mocap.util.float_text.csv_lines` writes,
    as the view of `out` they are written into.

    Parameters
    ----------
    index : ndarray of int64, shape (R,)
    cells : ndarray of float64, shape (R, C), C-contiguous
    out : ndarray of uint8
        Room for the lines: R · (1 + (C + 1) · (FIELD_WIDTH + 1)) bytes.
    """
    values = cells.ravel()
    digits = np.empty(values.size, np.int64)
    exponents = np.empty(values.size, np.int64)
    kinds = np.empty(values.size, np.uint8)
    shortest_digits(values, digits, exponents, kinds)
    texts, lengths = float_text._repr_fields(values[kinds == REPR])
    return out[:lines(index, cells, digits, exponents, kinds, texts, lengths, out)]


@numba.njit(cache=True, nogil=True)
def shortest_digits(values, digits, exponents, kinds):  # pragma: no cover - compiled
    """The shortest digits of each value, as :func:`mocap.util.float_text._shortest_digits`.

    Parameters
    ----------
    values : ndarray of float64, shape (n,)
    digits, exponents : ndarray of int64, shape (n,)
        Out: the digits as a 17-digit integer and the exponent of the first, where
        `kinds` is DIGITS.
    kinds : ndarray of uint8, shape (n,)
        Out: DIGITS, ZERO (±0.0) or REPR (``repr`` writes it).
    """
    pow10 = _POW10
    bits = values.view(np.int64)
    for k in range(values.size):
        x = values[k]
        m = abs(x)
        if not (1e-4 <= m < 1e16):
            if x == 0.0:
                kinds[k] = ZERO
            else:
                kinds[k] = REPR
            continue
        # m in [2^(b-1), 2^b) (b: frexp's exponent; m is normal here), so floor(log10 m)
        # is floor(b · log10 2) or one less: the comparison tells, within one ulp of a
        # power of ten, where the product below corrects it
        binary = ((bits[k] >> 52) & 0x7FF) - 1022
        e = (binary * 78913) >> 18                      # floor(binary · log10 2)
        if m < _NEAR_POW10[e + 5]:
            e -= 1
        hi, lo = _two_product(m, pow10[16 - e])
        if hi > 1e17 or (hi == 1e17 and lo >= 0):
            e += 1
            hi, lo = _two_product(m, pow10[16 - e])
        elif hi < 1e16 or (hi == 1e16 and lo < 0):
            e -= 1
            hi, lo = _two_product(m, pow10[16 - e])
        whole = np.int64(hi)
        # half the spacing of m, 2^(b - 53) / 2, in X's units
        half = _POW2[binary - 53 - _POW2_FIRST] * pow10[16 - e] / 2
        r = np.rint(lo)
        best = whole + np.int64(r)
        settled = abs(lo - r) != 0.5
        # 16, then 15 digits (constant units: their divisions are multiplications)
        reads, nearest, sure = _nearest_decimal(whole, lo, half, 10)
        if reads:
            best = nearest
        settled = settled and sure
        reads, nearest, sure = _nearest_decimal(whole, lo, half, 100)
        if reads:
            best = nearest
        settled = settled and sure
        if settled:
            digits[k], exponents[k], kinds[k] = best, e, DIGITS
        else:
            kinds[k] = REPR


@numba.njit(cache=True, nogil=True, inline="always")
def _nearest_decimal(whole, lo, half, unit):  # pragma: no cover - compiled
    """The multiple of `unit` nearest X = whole + lo: whether it reads back (within `half`
    of X), it, and whether neither that nor the rounding was (nearly) a tie, as
    :func:`mocap.util.float_text._nearest` and ``_reads_back`` decide."""
    quotient = whole // unit
    share = (whole - quotient * unit + lo) / unit
    rounded = np.rint(share)
    nearest = (quotient + np.int64(rounded)) * unit
    tie = abs(abs(share - rounded) - 0.5) < 1e-9
    distance = abs((nearest - whole) - lo)
    return distance < half, nearest, not tie and not abs(distance - half) < 1e-9


@numba.njit(cache=True, nogil=True, inline="always")
def _put_int(out, at, value):  # pragma: no cover - compiled
    """Write the decimal integer `value` (int64) at ``out[at:]``; return the end."""
    magnitude = np.uint64(value)
    if value < 0:
        out[at] = 45                                    # "-"
        at += 1
        magnitude = np.uint64(0) - magnitude            # two's complement: int64's least too
    ten = np.uint64(10)
    end = at + 1
    probe = magnitude // ten
    while probe != 0:
        end += 1
        probe //= ten
    for pos in range(end - 1, at - 1, -1):
        out[pos] = 48 + magnitude % ten
        magnitude //= ten
    return end


@numba.njit(cache=True, nogil=True, inline="always")
def _put_digits(out, at, digits):  # pragma: no cover - compiled
    """Write the 17 digits of `digits` at ``out[at:at + 17]``, two at a time."""
    value = np.uint64(digits)
    high = np.uint32(value // np.uint64(1_000_000_000))    # digits 0-7
    low = np.uint32(value - np.uint64(high) * np.uint64(1_000_000_000))  # 8-16
    for pair in range(3, -1, -1):
        rest = high // np.uint32(100)
        two = high - rest * np.uint32(100)
        out[at + 2 * pair], out[at + 2 * pair + 1] = _PAIRS[two, 0], _PAIRS[two, 1]
        high = rest
    for pair in range(3, -1, -1):
        rest = low // np.uint32(100)
        two = low - rest * np.uint32(100)
        out[at + 9 + 2 * pair], out[at + 10 + 2 * pair] = _PAIRS[two, 0], _PAIRS[two, 1]
        low = rest
    out[at + 8] = 48 + low


@numba.njit(cache=True, nogil=True, inline="always")
def _significant_end(out, end):  # pragma: no cover - compiled
    """The end of the digits before ``out[end]`` less their trailing zeros ("0": 48)."""
    while out[end - 1] == 48:
        end -= 1
    return end


@numba.njit(cache=True, nogil=True)
def lines(index, values, digits, exponents, kinds, texts, lengths, out):  # pragma: no cover
    """Write the lines ``index,value,...,value\\n`` into `out`.

    Parameters
    ----------
    index : ndarray of int64, shape (R,)
    values : ndarray of float64, shape (R, C)
    digits, exponents, kinds : ndarray, shape (R · C,)
        :func:`shortest_digits` of the values.
    texts : ndarray of uint8, shape (n_repr, width)
        ``repr`` of the REPR values, in order; `lengths` (n_repr,) their characters.
    out : ndarray of uint8
        Out: room for the longest lines.

    Returns
    -------
    int
        The bytes written.
    """
    R, C = values.shape
    at = 0
    taken = 0
    for row in range(R):
        at = _put_int(out, at, index[row])
        for col in range(C):
            k = row * C + col
            out[at] = 44                                # ","
            at += 1
            kind = kinds[k]
            if kind == REPR:
                for c in range(lengths[taken]):
                    out[at + c] = texts[taken, c]
                at += lengths[taken]
                taken += 1
                continue
            if np.signbit(values[row, col]):
                out[at] = 45                            # "-"
                at += 1
            if kind == ZERO:
                out[at], out[at + 1], out[at + 2] = 48, 46, 48
                at += 3
                continue
            # the digits are written where they go (the first is not 0), then cut after
            # the last significant one
            e = exponents[k]
            if e < 0:                                   # 0.000ddd
                out[at], out[at + 1] = 48, 46
                at += 2
                for _ in range(-e - 1):
                    out[at] = 48
                    at += 1
                _put_digits(out, at, digits[k])
                at = _significant_end(out, at + 17)
            else:                                       # digits 0..e, the point, the rest
                _put_digits(out, at + 1, digits[k])
                for pos in range(e + 1):
                    out[at + pos] = out[at + 1 + pos]
                out[at + e + 1] = 46                    # "."
                end = _significant_end(out, at + 18)
                if end == at + e + 2:                   # none after the point: "0"
                    out[end] = 48
                    end += 1
                at = end
        out[at] = 10                                    # "\n"
        at += 1
    return at
