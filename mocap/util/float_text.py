"""Text of float64 arrays as ``repr`` writes it, byte for byte, a whole array at a time.

``repr(float)`` writes the fewest significant digits that read back as the same double
(David Gay's algorithm), one number at a time, at about half a microsecond each: the
whole cost of a weights CSV. Here the digits come from array operations instead, for
the numbers ``repr`` writes without an exponent (magnitudes in [1e-4, 1e16)):

- X = ``|x| · 10^s`` in [1e16, 1e17) (``10^s`` exact in binary64 for s ≤ 22) exactly,
  as the unevaluated sum of Dekker's two-product, so that its nearest integers at 17,
  16 and 15 significant digits are exact;
- a decimal reads back as x when it is within half x's spacing of it. At 15 digits, at
  most one decimal can be (the doubles are closer together than they), so when the
  nearest one is, it is the shortest digits, less its trailing zeros; else the nearest
  16-digit decimal when it is; else the nearest 17-digit decimal, which always is.
  ``repr`` takes the nearest of the shortest too.

In that range the powers of two are exact decimals of at most 16 digits, so the
narrower spacing below them never decides, and no double rounds up to the next power
of ten. A number this does not settle exactly (zero's sign, not finite, outside the
range, a tie or near-tie at a rounding or at half the spacing) is written by ``repr``
itself. So the text is always ``repr``'s, and ``float`` reads every field back exactly.

With numba (the ``speed`` extra), :func:`csv_lines` does the same arithmetic value by
value in one compiled pass that writes the lines (:mod:`mocap.util._float_text_kernel`).
"""

from __future__ import annotations

import functools
from typing import Iterator

import numpy as np

from mocap.util.optional import compiled, compiled_if_worth, numba_loaded

__all__ = ["FIELD_WIDTH", "csv_lines", "write_csv_lines", "float_fields",
           "compiled_lines_ready"]

#: Characters of the longest ``repr`` of a double (``-2.2250738585072014e-308``).
FIELD_WIDTH = 24
#: Exact powers of ten in binary64.
_POW10 = np.array([float(10 ** k) for k in range(23)])
#: Veltkamp's splitter for binary64: 2**27 + 1.
_SPLIT = 134217729.0
#: The characters of every 4-digit group, (10000, 4) ASCII (by arithmetic: ten thousand
#: Python lists would cost the import a collection or two).
_GROUPS = (np.arange(10000)[:, None] // np.array([1000, 100, 10, 1]) % 10
           + ord("0")).astype(np.uint8)
#: The text of 0.0.
_ZERO = np.frombuffer(b"0.0", np.uint8)
#: The same as 4-byte words, and "0000".
_GROUP_WORDS = _GROUPS.view(np.uint32).ravel()
_ZEROS = _GROUP_WORDS[0]
#: Cells formatted at a time (their temporaries stay within a few MB).
_CELLS_PER_PASS = 1 << 15
#: Cells of a CSV formatted at a time (whole rows, at least one): a block's text and
#: temporaries stay within a few MB however wide the table.
_CELLS_PER_BLOCK = 1 << 17
#: Cells of a CSV for which loading numba (about half a second, once a process) pays for
#: itself; in a process that has loaded it, the compiled lines are used for any CSV.
_CELLS_WORTH_COMPILING = 2_000_000


def float_fields(values) -> tuple[np.ndarray, np.ndarray]:
    """``repr`` of every value, as fixed-width ASCII fields.

    Parameters
    ----------
    values : array_like of float64, shape (n,)

    Returns
    -------
    chars : ndarray of uint8, shape (n, FIELD_WIDTH)
        Each value's text, left-aligned; what follows it is unspecified.
    lengths : ndarray of int64, shape (n,)
        Characters of each value's text.
    """
    values = np.ascontiguousarray(values, dtype=np.float64).ravel()
    chars = np.empty((len(values), FIELD_WIDTH), np.uint8)
    lengths = np.empty(len(values), np.int64)
    for first in range(0, len(values), _CELLS_PER_PASS):
        rows = slice(first, first + _CELLS_PER_PASS)
        _format_pass(values[rows], chars[rows], lengths[rows])
    return chars, lengths


def csv_lines(index, cells) -> Iterator[bytes]:
    """CSV lines ``index,cell,...,cell`` of integers and floats, as ``%d`` and ``%r`` write
    them, in blocks of lines.

    Parameters
    ----------
    index : array_like of int, shape (T,)
        The first field of each line.
    cells : array_like of float64, shape (T, C)
        The other fields.

    Yields
    ------
    bytes
        The next lines, each ended by ``\n``; T lines in all.
    """
    for block in _line_blocks(index, cells):
        yield block.tobytes()


def write_csv_lines(fh, index, cells) -> None:
    """Write the lines of :func:`csv_lines` to the binary file `fh`, each block of lines
    from the memory it is made in (no copy of its text into ``bytes``: about 5% of a large
    CSV's writing)."""
    for block in _line_blocks(index, cells):
        fh.write(block)


def _line_blocks(index, cells) -> Iterator[np.ndarray]:
    """The lines of :func:`csv_lines`, a block at a time, as uint8 arrays valid until the
    next block is asked for (the compiled kernel writes every block into one buffer)."""
    index = np.ascontiguousarray(index, dtype=np.int64)
    cells = np.asarray(cells, dtype=np.float64)
    T, C = cells.shape
    if index.shape != (T,):
        raise ValueError(f"an index of {index.shape} for {T} rows of cells")
    rows = max(1, min(T, _CELLS_PER_BLOCK // max(C, 1)))
    write = _numpy_lines
    kernel = compiled_if_worth(_compiled_lines, T * C, _CELLS_WORTH_COMPILING)
    if kernel is not None:
        out = np.empty(rows * (1 + (C + 1) * (FIELD_WIDTH + 1)), np.uint8)
        write = functools.partial(kernel, out=out)
    for first in range(0, T, rows):
        block = np.ascontiguousarray(cells[first:first + rows])
        yield write(index[first:first + len(block)], block)


def compiled_lines_ready() -> bool:
    """Whether :func:`csv_lines` writes any table by its compiled kernel (numba, the
    ``speed`` extra) without loading numba: this process has loaded it."""
    return numba_loaded() and _compiled_lines() is not None


@functools.cache
def _compiled_lines():
    """:func:`mocap.util._float_text_kernel.csv_block`, or None (NumPy writes the lines):
    :func:`mocap.util.optional.compiled`."""
    return compiled("mocap.util._float_text_kernel", "csv_block", what="CSV text",
                    fallback="NumPy writes it, about three times slower")


def _numpy_lines(index, cells) -> np.ndarray:
    """The lines of :func:`csv_lines` for a block of rows (R,) and (R, C), by array
    operations."""
    R, C = cells.shape
    head = index.astype(f"S{FIELD_WIDTH}").view(np.uint8).reshape(R, FIELD_WIDTH)
    chars, lengths = float_fields(cells)
    # fixed-width fields, a comma before each float, a newline after the last; the
    # characters kept are each field's text
    line = np.empty((R, FIELD_WIDTH + C * (FIELD_WIDTH + 1) + 1), np.uint8)
    keep = np.empty(line.shape, bool)
    line[:, :FIELD_WIDTH], keep[:, :FIELD_WIDTH] = head, head != 0
    fields = line[:, FIELD_WIDTH:-1].reshape(R, C, FIELD_WIDTH + 1)
    fields[:, :, 0], fields[:, :, 1:] = ord(","), chars.reshape(R, C, FIELD_WIDTH)
    kept = keep[:, FIELD_WIDTH:-1].reshape(R, C, FIELD_WIDTH + 1)
    kept[:] = np.arange(FIELD_WIDTH + 1) <= lengths.reshape(R, C, 1)
    line[:, -1], keep[:, -1] = ord("\n"), True
    return line[keep]


def _repr_fields(values) -> tuple[np.ndarray, np.ndarray]:
    """``repr`` of `values` (k,) itself: fields (k, FIELD_WIDTH) uint8 and lengths (k,)."""
    texts = np.array([repr(value) for value in values.tolist()], f"S{FIELD_WIDTH}")
    return (texts.view(np.uint8).reshape(len(values), FIELD_WIDTH),
            np.char.str_len(texts).astype(np.int64))


def _format_pass(values, chars, lengths) -> None:
    """Fill `chars` (n, FIELD_WIDTH) and `lengths` (n,) with the ``repr`` of `values` (n,)."""
    magnitude = np.abs(values)
    negative = np.signbit(values)
    zero = magnitude == 0
    chars[:, :3], lengths[:] = _ZERO, 3                # the zeros' text, the others' after
    fast = np.flatnonzero((magnitude >= 1e-4) & (magnitude < 1e16))
    digits, exponent, settled = _shortest_digits(magnitude[fast])
    fast, digits, exponent = fast[settled], digits[settled], exponent[settled]
    _place(digits, exponent, negative[fast], chars, lengths, fast)
    done = zero & ~negative                             # -0.0 as the others below
    done[fast] = True
    rest = np.flatnonzero(~done)                        # those that repr itself writes
    chars[rest], lengths[rest] = _repr_fields(values[rest])


def _two_product(a, b):
    """``a · b`` exactly, as ``hi + lo`` with ``hi = fl(a · b)`` (Dekker), float64."""
    hi = a * b
    t = _SPLIT * a
    a_hi = t - (t - a)
    a_lo = a - a_hi
    t = _SPLIT * b
    b_hi = t - (t - b)
    b_lo = b - b_hi
    lo = ((a_hi * b_hi - hi) + a_hi * b_lo + a_lo * b_hi) + a_lo * b_lo
    return hi, lo


def _shortest_digits(magnitude):
    """The shortest digits of positive doubles in [1e-4, 1e16), (n,) each.

    Returns
    -------
    digits : ndarray of int64
        The digits as a 17-digit integer, padded with trailing zeros.
    exponent : ndarray of int64
        The decimal exponent of the first digit.
    settled : ndarray of bool
        Whether the digits were found exactly (else ``repr`` must write the value).
    """
    exponent = np.floor(np.log10(magnitude)).astype(np.int64)
    hi, lo = _two_product(magnitude, _POW10[16 - exponent])
    # log10 may round across a power of ten: the product X = hi + lo must be in [1e16, 1e17)
    shift = ((hi > 1e17) | ((hi == 1e17) & (lo >= 0))).astype(np.int64)
    shift -= (hi < 1e16) | ((hi == 1e16) & (lo < 0))
    wrong = np.flatnonzero(shift)
    exponent[wrong] += shift[wrong]
    hi[wrong], lo[wrong] = _two_product(magnitude[wrong], _POW10[16 - exponent[wrong]])
    whole = hi.astype(np.int64)             # hi ≥ 1e16 > 2**53: an even integer
    # the decimals that read back as x are those within half its spacing, in X's units
    half = np.spacing(magnitude) * _POW10[16 - exponent] / 2

    # the nearest 17-digit integer: hi is even, so rint(lo)'s ties go where X's do
    digits = whole + np.rint(lo).astype(np.int64)
    settled = np.abs(lo - np.rint(lo)) != 0.5
    for unit in (10, 100):                  # 16, then 15 digits
        nearest, tie = _nearest(whole, lo, unit)
        reads, near = _reads_back(nearest * unit - whole, lo, half)
        digits = np.where(reads, nearest * unit, digits)
        settled &= ~tie & ~near
    return digits, exponent, settled


def _nearest(whole, lo, unit):
    """The nearest integer to ``(whole + lo) / unit``, and whether it was (nearly) a tie."""
    quotient, remainder = np.divmod(whole, unit)
    share = (remainder + lo) / unit                     # in (-1, 2)
    rounded = np.rint(share)
    return quotient + rounded.astype(np.int64), np.abs(np.abs(share - rounded) - 0.5) < 1e-9


def _reads_back(offset, lo, half):
    """Whether a decimal ``offset - lo`` from X (offset an exact integer) is within `half`
    of it, and whether it is too near that bound to tell."""
    distance = np.abs(offset - lo)
    return distance < half, np.abs(distance - half) < 1e-9


def _place(digits, exponent, negative, chars, lengths, rows) -> None:
    """Write the positional text of ``digits · 10^(exponent - 16)`` into `rows` of `chars`.

    The digits, after four zeros, are a 21-character string E whose digit of 10^0 is
    ``E[4 + e]``: the text is a sign, ``E[a:5+e]`` (the whole part, "0" below 1),
    the point and ``E[5+e:]`` (cut after the last significant digit, or after one
    digit), for each exponent e a copy of fixed columns.
    """
    n = len(digits)
    # 4-digit groups as 4-byte words: E is bytes 0-20 of 24 (the last 3 unused)
    extended = np.empty((n, 6), np.uint32)
    extended[:, 0] = _ZEROS
    high, low = np.divmod(digits, 10 ** 9)
    extended[:, 1] = _GROUP_WORDS[high // 10 ** 4]
    extended[:, 2] = _GROUP_WORDS[high % 10 ** 4]
    extended[:, 3] = _GROUP_WORDS[low // 10 ** 5]
    extended[:, 4] = _GROUP_WORDS[low % 10 ** 5 // 10]
    extended[:, 5] = _GROUP_WORDS[low % 10 * 1000]          # the last digit, then "000"
    extended = extended.view(np.uint8)[:, :21]
    significant = 17 - np.argmax(extended[:, :3:-1] != ord("0"), axis=1)
    start = np.minimum(4, 4 + exponent)
    lengths[rows] = np.maximum(4 + significant, 6 + exponent) - start + 1 + negative
    key = (exponent + 4) * 2 + negative
    for value in np.flatnonzero(np.bincount(key)):
        group = np.flatnonzero(key == value)
        e, sign = divmod(int(value), 2)
        e -= 4
        first = min(4, 4 + e)
        point = sign + 5 + e - first
        text = np.empty((len(group), FIELD_WIDTH), np.uint8)
        text[:, 0] = ord("-")
        text[:, sign:point] = extended[group, first:5 + e]
        text[:, point] = ord(".")
        text[:, point + 1:point + 17 - e] = extended[group, 5 + e:]
        chars[rows[group]] = text
