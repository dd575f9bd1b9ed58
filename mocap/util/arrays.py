"""Read-only arrays for the fields of frozen result objects."""

from __future__ import annotations

import numpy as np

__all__ = ["read_only"]


def read_only(arr: np.ndarray, *, copy: bool = False) -> np.ndarray:
    """Return `arr` (or a C-contiguous copy of it) with its write flag cleared.

    Results are frozen dataclasses; their arrays are made read-only so that a
    caller cannot change a result in place by accident.
    """
    if copy:
        arr = np.array(arr)
    arr.flags.writeable = False
    return arr
