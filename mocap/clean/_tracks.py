"""Per-marker statistics of marker tracks, shared by swap and outlier detection.

NaN policy: every function takes positions (T, M, 3), mm, with NaN for a
missing sample and skips them; a marker never seen gives NaN (or -1 for a
frame index).
"""

from __future__ import annotations

import numpy as np

from mocap.gaps import find_gaps
from mocap.util.order_statistics import nan_column_medians

__all__ = ["MIN_STEP_MM", "last_visible", "typical_step", "long_gap_starts"]

#: Floor of a marker's typical frame-to-frame motion, mm: below any optical
#: capture noise, so that noise-free data does not make every jump significant.
MIN_STEP_MM = 0.05


def last_visible(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each marker's last visible sample before each frame t = 1 .. n_frames - 1.

    Returns ``prev`` of shape (n_frames - 1, n_markers, 3), its position (NaN
    if none), and ``last`` of shape (n_frames - 1, n_markers), its frame index
    (-1 if none).
    """
    n_frames, n_markers = positions.shape[:2]
    visible = ~np.isnan(positions[:, :, 0])
    index = np.where(visible, np.arange(n_frames)[:, None], -1)
    last = np.maximum.accumulate(index, axis=0)[:-1]
    prev = positions[np.maximum(last, 0), np.arange(n_markers)]
    prev[last < 0] = np.nan
    return prev, last


def typical_step(positions: np.ndarray) -> np.ndarray:
    """Median frame-to-frame motion of each marker over visible pairs, mm, shape (M,)."""
    step = np.linalg.norm(np.diff(positions, axis=0), axis=2)
    typical = nan_column_medians(step)
    return np.fmax(np.nan_to_num(typical, nan=MIN_STEP_MM), MIN_STEP_MM)


def long_gap_starts(missing: np.ndarray, max_gap: int) -> list[np.ndarray]:
    """Per marker, the first frames of its gaps longer than `max_gap` frames."""
    gaps = find_gaps(missing)
    long = gaps.length > max_gap
    return [gaps.start[long & (gaps.marker == m)] for m in range(missing.shape[1])]
