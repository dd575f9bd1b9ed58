"""Runs of missing samples (gaps) in marker tracks."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Gaps", "find_gaps"]


@dataclass(frozen=True)
class Gaps:
    """All gaps of a take, one entry per gap, ordered by marker then start.

    Attributes
    ----------
    marker : ndarray of int, shape (n_gaps,)
        Column of the marker.
    start : ndarray of int, shape (n_gaps,)
        Index of the first missing frame.
    stop : ndarray of int, shape (n_gaps,)
        Index one past the last missing frame.
    n_frames : int
        Length of the take, so that edge gaps can be told apart.
    """

    marker: np.ndarray
    start: np.ndarray
    stop: np.ndarray
    n_frames: int

    @property
    def length(self) -> np.ndarray:
        """Gap lengths in frames, shape (n_gaps,)."""
        return self.stop - self.start

    @property
    def at_edge(self) -> np.ndarray:
        """True for gaps touching the first or last frame (no sample on one side)."""
        return (self.start == 0) | (self.stop == self.n_frames)

    def __len__(self) -> int:
        return len(self.marker)

    def longest(self, n_markers: int) -> np.ndarray:
        """Longest gap of each marker in frames, shape (n_markers,), 0 if none."""
        out = np.zeros(n_markers, dtype=np.int64)
        np.maximum.at(out, self.marker, self.length)
        return out


def find_gaps(missing) -> Gaps:
    """Find every run of missing samples, vectorized over markers and frames.

    Parameters
    ----------
    missing : array_like of bool, shape (n_frames, n_markers)
        True where a sample is missing (``Take.missing``).

    Returns
    -------
    Gaps

    Examples
    --------
    >>> import numpy as np
    >>> g = find_gaps(np.array([[0, 1], [1, 1], [1, 0], [0, 0]], bool))
    >>> g.marker.tolist(), g.start.tolist(), g.stop.tolist()
    ([0, 1], [1, 0], [3, 2])
    """
    missing = np.asarray(missing, dtype=bool)
    n_frames, n_markers = missing.shape
    padded = np.zeros((n_markers, n_frames + 2), dtype=np.int8)
    padded[:, 1:-1] = missing.T
    edges = np.diff(padded, axis=1)
    m_start, start = np.nonzero(edges == 1)
    _, stop = np.nonzero(edges == -1)
    return Gaps(marker=m_start, start=start, stop=stop, n_frames=n_frames)
