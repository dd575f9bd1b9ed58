"""An OBJ's vertex lines parsed as one compiled loop (numba, the ``speed`` extra).

:func:`mocap.mesh.mesh.load_shape_vertices` reads the vertex lines of expression shapes
with :func:`numpy.loadtxt`, about 20 ns a byte of text; this loop takes about 2. A number
is converted exactly when its decimal significand fits in 2^53 and its power of ten in
±22 (both are then exact doubles, and one product or quotient of them is correctly
rounded: Clinger's fast path), which is how most exporters write coordinates. A longer
significand, up to 19 digits (``repr`` writes 17, ``numpy.savetxt`` 19 by default), is
multiplied by its power of ten as a 128-bit number (:func:`_rounded_product`, after Eisel
and Lemire), which settles the rounding unless the product is too near a tie. Any other
number is left to the caller, which converts it with ``float`` (also correctly rounded).
So the values are those of ``float``, and of :func:`numpy.loadtxt`, bit for bit.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["vertex_rows"]

#: The powers of ten that are exact doubles, 10^0 .. 10^22.
_EXACT_POWERS = np.array([10.0 ** k for k in range(23)])
#: 2^53: significands up to it are exact doubles.
_EXACT_SIGNIFICAND = 1 << 53
#: Powers of ten the 128-bit products take, 10^_LOWEST_POWER .. 10^_HIGHEST_POWER (far
#: beyond coordinates in any unit; the others go to ``float``).
_LOWEST_POWER, _HIGHEST_POWER = -64, 64


def _powers_of_ten() -> tuple:
    """10^q for each q of the table as M·2^E, M the 128-bit integer in [2^127, 2^128) that
    is the exact value truncated (floor): M's high and low 64 bits (uint64) and E."""
    high, low, exponent = [], [], []
    for q in range(_LOWEST_POWER, _HIGHEST_POWER + 1):
        if q >= 0:
            shift = (10 ** q).bit_length() - 128
            m = 10 ** q >> shift if shift > 0 else 10 ** q << -shift
        else:
            shift = -127 - (10 ** -q).bit_length()
            m = (1 << -shift) // 10 ** -q
        high.append(m >> 64)
        low.append(m & (2 ** 64 - 1))
        exponent.append(shift)
    return np.array(high, np.uint64), np.array(low, np.uint64), np.array(exponent, np.int64)


_POWER_HIGH, _POWER_LOW, _POWER_EXPONENT = _powers_of_ten()
_U32 = np.uint64(32)
_LOW32 = np.uint64(0xFFFFFFFF)
_TOP_BIT = np.uint64(1 << 63)
_ALL_ONES = np.uint64(2 ** 64 - 1)
_ZERO, _ONE = np.uint64(0), np.uint64(1)
_SPACE, _NEWLINE, _RETURN, _MINUS, _PLUS, _POINT = 32, 10, 13, 45, 43, 46


@numba.njit(cache=True, inline="always")
def _is_digit(c):  # pragma: no cover - compiled
    return 48 <= c <= 57


@numba.njit(cache=True, nogil=True)
def vertex_rows(text, out, slow):  # pragma: no cover - compiled; tested against NumPy
    """Parse ``len(out)`` lines ``v x y z`` of `text` (uint8) into `out` (N, 3) float64.

    A line is ``v``, one space and three numbers separated by one space each
    (``[+-]digits[.digits][(e|E)[+-]digits]``, digits on at least one side of the point),
    then its end (``\\n``, ``\\r\\n`` or the end of the text), or a space and any other
    fields up to its end (ignored, as ``loadtxt(usecols=(1, 2, 3))`` ignores them).

    Returns
    -------
    (int, int)
        The lines parsed (-1 when a line is not of that form, or the text holds more),
        and k, the numbers this loop left to the caller: ``slow[:k]`` holds for each its
        flat index into `out`, and its first and last + 1 byte in `text` (`slow` has room
        for 3 N).
    """
    n = text.shape[0]
    i = 0
    n_slow = 0
    for row in range(out.shape[0]):
        if i + 1 >= n or text[i] != 118 or text[i + 1] != _SPACE:       # "v "
            return -1, n_slow
        i += 2
        for col in range(3):
            if col:
                if i >= n or text[i] != _SPACE:
                    return -1, n_slow
                i += 1
            start = i
            negative = False
            if i < n and (text[i] == _MINUS or text[i] == _PLUS):
                negative = text[i] == _MINUS
                i += 1
            significand = np.uint64(0)
            digits = 0              # significant digits (leading zeros not counted)
            power = 0               # of ten, applied to the significand
            exact = True
            seen = False
            point = False
            while i < n:
                c = text[i]
                if _is_digit(c):
                    seen = True
                    if significand or c != 48:
                        digits += 1
                        if digits <= 19:
                            significand = significand * np.uint64(10) + np.uint64(c - 48)
                            if point:
                                power -= 1
                        else:
                            exact = False
                    elif point:
                        power -= 1
                elif c == _POINT and not point:
                    point = True
                else:
                    break
                i += 1
            if not seen:
                return -1, n_slow
            if i < n and (text[i] == 101 or text[i] == 69):                  # e, E
                i += 1
                negative_power = False
                if i < n and (text[i] == _MINUS or text[i] == _PLUS):
                    negative_power = text[i] == _MINUS
                    i += 1
                written = 0
                exponent = 0
                while i < n and _is_digit(text[i]):
                    if exponent < 100_000:
                        exponent = exponent * 10 + (text[i] - 48)
                    written += 1
                    i += 1
                if not written:
                    return -1, n_slow
                power += -exponent if negative_power else exponent
            if significand == 0:
                value = 0.0
            elif exact and significand <= _EXACT_SIGNIFICAND and -22 <= power <= 22:
                value = (float(significand) * _EXACT_POWERS[power] if power >= 0
                         else float(significand) / _EXACT_POWERS[-power])
            elif exact and _LOWEST_POWER <= power <= _HIGHEST_POWER:
                value = _rounded_product(significand, power)
            else:
                value = -1.0
            if value < 0.0:
                slow[n_slow, 0] = 3 * row + col
                slow[n_slow, 1] = start
                slow[n_slow, 2] = i
                n_slow += 1
                value = 0.0
            out[row, col] = -value if negative else value
        if i < n and text[i] == _SPACE:                   # other fields: to the line's end
            while i < n and text[i] != _NEWLINE:
                i += 1
        if i < n and text[i] == _RETURN:
            i += 1
        if i < n:
            if text[i] != _NEWLINE:
                return -1, n_slow
            i += 1
    if i != n:
        return -1, n_slow
    return out.shape[0], n_slow


@numba.njit(cache=True, inline="always")
def _wide_product(a, b):  # pragma: no cover - compiled
    """The 128-bit product of the uint64 `a` and `b`: its high and low 64 bits."""
    a0, a1, b0, b1 = a & _LOW32, a >> _U32, b & _LOW32, b >> _U32
    p00, p01, p10, p11 = a0 * b0, a0 * b1, a1 * b0, a1 * b1
    middle = (p00 >> _U32) + (p01 & _LOW32) + (p10 & _LOW32)
    return p11 + (p01 >> _U32) + (p10 >> _U32) + (middle >> _U32), \
        (p00 & _LOW32) | (middle << _U32)


@numba.njit(cache=True)
def _rounded_product(significand, power):  # pragma: no cover - compiled; tested against float
    """``significand · 10^power`` rounded to the nearest double (ties to even), for a
    significand of up to 19 digits (uint64, not 0) and a power in the table; -1.0 when
    the 128-bit product leaves the rounding open (the caller asks ``float``).

    With the significand shifted to fill 64 bits and 10^power as M·2^E (M truncated to 128
    bits), the product's top 128 bits fall short of the exact product's by less than 2 in
    their last place (M's truncation and the dropped low 64 bits add less than 1 each). Of
    them the top 53 are the mantissa and the next one the rounding bit: below half (bit
    0) the value rounds down, above (bit 1) up, unless the bits under the rounding bit
    are within 2 of all-ones (a carry could reach it) or, with the bit set, all zero (a
    tie to break to even, or just above one).
    """
    k = power - _LOWEST_POWER
    shifted, lz = significand, 0
    while shifted < _TOP_BIT:
        shifted <<= _ONE
        lz += 1
    high, low = _wide_product(shifted, _POWER_HIGH[k])
    carry, _ = _wide_product(shifted, _POWER_LOW[k])
    low += carry
    if low < carry:
        high += _ONE
    shift = np.uint64(10) + (high >> np.uint64(63))      # 11 when the product fills 128 bits
    mantissa = high >> shift
    below = high & ((_ONE << (shift - _ONE)) - _ONE)     # the bits under the rounding bit
    near_carry = below == (_ONE << (shift - _ONE)) - _ONE and low >= _ALL_ONES - _ONE
    if (high >> (shift - _ONE)) & _ONE:
        if below == _ZERO and low <= _ONE or near_carry:
            return -1.0
        mantissa += _ONE
        if mantissa == np.uint64(1 << 53):
            mantissa >>= _ONE
            shift += _ONE
    elif near_carry:
        return -1.0
    exponent = np.int64(shift) + 128 + _POWER_EXPONENT[k] - lz
    if not -1074 <= exponent <= 971:                    # not a normal double
        return -1.0
    return math.ldexp(float(mantissa), exponent)
