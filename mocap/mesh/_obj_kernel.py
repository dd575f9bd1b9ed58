"""An OBJ's vertex lines parsed as one compiled loop (numba, the ``speed`` extra).

:func:`mocap.mesh.mesh.load_shape_vertices` reads the vertex lines of expression shapes
with :func:`numpy.loadtxt`, about 20 ns a byte of text; this loop takes about 2. A number
is converted exactly when its decimal significand fits in 2^53 and its power of ten in
±22 (both are then exact doubles, and one product or quotient of them is correctly
rounded: Clinger's fast path), which is how exporters write coordinates; any other number
is left to the caller, which converts it with ``float`` (also correctly rounded). So the
values are those of ``float``, and of :func:`numpy.loadtxt`, bit for bit.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["vertex_rows"]

#: The powers of ten that are exact doubles, 10^0 .. 10^22.
_EXACT_POWERS = np.array([10.0 ** k for k in range(23)])
#: 2^53: significands up to it are exact doubles.
_EXACT_SIGNIFICAND = 1 << 53
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
            else:
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
