"""Contiguous runs of visible samples, grouped across markers that share them."""

from __future__ import annotations

import numpy as np

from mocap.gaps import find_gaps


def visible_segments(missing: np.ndarray) -> list[tuple[int, int, np.ndarray]]:
    """Runs of visible samples, one entry per distinct frame range.

    Parameters
    ----------
    missing : ndarray of bool, shape (n_frames, n_markers)

    Returns
    -------
    list of (start, stop, markers)
        Frames ``start:stop`` are visible for every column in `markers`
        (ndarray of int); markers whose visible runs coincide share one entry,
        so that a filter or an interpolant can treat them in one call.
    """
    runs = find_gaps(~np.asarray(missing, dtype=bool))
    if len(runs) == 0:
        return []
    key = runs.start * (runs.n_frames + 1) + runs.stop
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    order = np.argsort(inverse, kind="stable")
    splits = np.cumsum(np.bincount(inverse))[:-1]
    groups = np.split(runs.marker[order], splits)
    return [(int(runs.start[i]), int(runs.stop[i]), markers)
            for i, markers in zip(first, groups)]
