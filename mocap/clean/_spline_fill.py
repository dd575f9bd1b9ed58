"""Spline fill: a cubic spline through a marker's own visible samples."""

from __future__ import annotations

import numpy as np


def fill_spline(positions: np.ndarray, visible: np.ndarray, target: int,
                frames: np.ndarray) -> np.ndarray:
    """Cubic-spline estimate of marker `target` at `frames`.

    Parameters
    ----------
    positions : ndarray of shape (n_frames, n_markers, 3), mm, NaN where missing
    visible : ndarray of bool, shape (n_frames, n_markers)
    target : int
        Column of the marker.
    frames : ndarray of int, shape (n,)
        Frame indices to estimate (a gap).

    Returns
    -------
    ndarray of shape (n, 3), mm
        NaN everywhere if the marker has fewer than two visible samples.

    Notes
    -----
    A not-a-knot interpolating cubic spline through all the marker's visible
    samples (Woltring's fill uses a spline through the samples around the
    gap; the influence of a cubic spline's far samples decays geometrically,
    so the whole track gives the same fill near the gap). Frames outside the visible range
    are extrapolated with the end polynomial pieces: the caller only asks for
    them when extrapolation was requested.
    """
    # here: the automatic fill takes a spline last, so a run rarely needs scipy.interpolate,
    # whose import (with scipy.optimize) costs 75 ms
    from scipy.interpolate import CubicSpline

    known = np.flatnonzero(visible[:, target])
    if len(known) < 2:
        return np.full((len(frames), 3), np.nan)
    spline = CubicSpline(known, positions[known, target], axis=0, extrapolate=True)
    return spline(frames)
