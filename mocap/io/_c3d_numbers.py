"""Numbers as C3D stores them: 16-bit words and 32-bit floats in three byte orders.

C3D files come from Intel (little-endian IEEE), DEC (little-endian words,
VAX F-floating floats) and MIPS/SGI (big-endian IEEE) machines; the
processor byte of the parameter section says which.
"""

from __future__ import annotations

import numpy as np

__all__ = ["PROCESSORS", "BYTE_ORDERS", "int16", "uint16", "float32"]

#: Processor byte of the parameter section -> byte order name.
PROCESSORS = {84: "intel", 85: "dec", 86: "mips"}
#: The byte order names, as SourceInfo.byte_order reports them.
BYTE_ORDERS = tuple(PROCESSORS.values())


def _endian(order: str) -> str:
    return ">" if order == "mips" else "<"


def int16(raw, order: str) -> np.ndarray:
    """Signed 16-bit words of `raw` (bytes-like, even length) as an int16 view."""
    return np.frombuffer(raw, dtype=_endian(order) + "i2")


def uint16(raw, order: str) -> np.ndarray:
    """Unsigned 16-bit words of `raw` (bytes-like, even length) as a uint16 view."""
    return np.frombuffer(raw, dtype=_endian(order) + "u2")


def _vax_to_float64(raw) -> np.ndarray:
    """Decode VAX F-floating numbers exactly into float64.

    A VAX F float is two little-endian 16-bit words, the first holding the sign,
    the 8-bit exponent (bias 128) and the high 7 fraction bits, the second the low
    16 fraction bits; its value is ``0.1f x 2**(e - 128)`` with a hidden leading
    bit after the point. Exponent 0 encodes zero.
    """
    words = np.frombuffer(raw, dtype="<u2").reshape(-1, 2).astype(np.uint32)
    bits = (words[:, 0] << 16) | words[:, 1]
    exponent = ((bits >> 23) & 0xFF).astype(np.int64)
    mantissa = ((bits & 0x7FFFFF) | 0x800000).astype(np.float64)
    value = np.ldexp(mantissa, exponent - 152)
    value[exponent == 0] = 0.0
    return np.where(bits >> 31, -value, value)


def float32(raw, order: str) -> np.ndarray:
    """32-bit floats of `raw` (bytes-like, length a multiple of 4) as float64."""
    if order == "dec":
        return _vax_to_float64(raw)
    with np.errstate(invalid="ignore"):      # signalling NaNs in damaged files
        return np.frombuffer(raw, dtype=_endian(order) + "f4").astype(np.float64)
