"""The frames of a take where the face is at its extremes, found on the captured markers.

Widest mouth opening, strongest smile, brows highest: the frames a TD looks
at first, because a basis or a retargeting that fails somewhere fails there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fit.report.views import view_axes
from mocap.util.validation import as_positions

__all__ = ["Extreme", "take_extremes"]


@dataclass(frozen=True)
class Extreme:
    """One extreme frame of a take.

    Attributes
    ----------
    name : str
        ``"mouth open"``, ``"smile"`` or ``"brows up"``.
    frame : int
        0-based index into the take.
    value : float, mm
        The measure there (see :func:`take_extremes`).
    measure : str
        What was measured, for captions.
    """

    name: str
    frame: int
    value: float
    measure: str


def _centroid(positions, labels, members):
    cols = [labels.index(m) for m in members if m in labels]
    return None if not cols else np.nanmean(positions[:, cols], axis=1)


def take_extremes(positions, neutral, labels, markerset) -> list:
    """The widest mouth opening, the strongest smile and the highest brows of a take.

    Parameters
    ----------
    positions : array_like, shape (T, M, 3), mm
        Head-stabilized markers, NaN where missing (those frames are not picked).
    neutral : array_like, shape (M, 3), mm
        Rest positions.
    labels : sequence of str
    markerset : mocap.markerset.MarkerSet
        Its ``upper_lip`` / ``lower_lip`` / ``left_brow`` / ``right_brow``
        regions and ``mouth_corner_left`` / ``_right`` landmarks.

    Returns
    -------
    list of Extreme
        Mouth open: largest distance between the centroids of the upper- and
        lower-lip markers. Smile: largest widening of the mouth over the rest
        pose (the mouth corners' distance, or without the corner landmarks the
        lip markers' spread across the face). Brows up: largest mean rise of
        the brow markers along the face's up axis. An extreme whose markers the
        take lacks, or that never goes past the rest pose, is left out.

    Examples
    --------
    >>> from mocap.markerset import MarkerSet
    >>> ms = MarkerSet(name="m", head=(), regions={"upper_lip": ("u",), "lower_lip": ("l",)})
    >>> p = np.zeros((3, 2, 3)); p[:, 1, 1] = [-1.0, -5.0, -2.0]
    >>> [(e.name, e.frame) for e in take_extremes(p, p[0], ("u", "l"), ms)]
    [('mouth open', 1)]
    """
    positions = as_positions(positions, "positions", copy=False)        # only read
    labels = list(labels)
    neutral = np.asarray(neutral, dtype=float)
    regions = markerset.regions
    found = []

    def pick(name, series, measure):
        if series is not None and np.isfinite(series).any() and np.nanmax(series) > 0:
            t = int(np.nanargmax(series))
            found.append(Extreme(name, t, float(series[t]), measure))

    upper = _centroid(positions, labels, regions.get("upper_lip", ()))
    lower = _centroid(positions, labels, regions.get("lower_lip", ()))
    if upper is not None and lower is not None:
        pick("mouth open", np.linalg.norm(upper - lower, axis=1), "lip opening")
    lm = markerset.landmarks
    corners = [lm.get(f"mouth_corner_{side}") for side in ("left", "right")]
    lips = [m for m in (*regions.get("upper_lip", ()), *regions.get("lower_lip", ()))
            if m in labels]
    if all(c in labels for c in corners):
        i, j = labels.index(corners[0]), labels.index(corners[1])
        width = np.linalg.norm(positions[:, i] - positions[:, j], axis=1)
        pick("smile", width - np.linalg.norm(neutral[i] - neutral[j]), "mouth widening")
    elif len(lips) > 1:
        cols = [labels.index(m) for m in lips]
        lateral = view_axes(neutral, labels, markerset)[0]
        across = positions[:, cols] @ lateral
        rest = neutral[cols] @ lateral
        pick("smile", np.nanmax(across, axis=1) - np.nanmin(across, axis=1) - np.ptp(rest),
             "lip spread")
    brows = [labels.index(m) for m in (*regions.get("left_brow", ()),
                                       *regions.get("right_brow", ())) if m in labels]
    if brows:
        up = view_axes(neutral, labels, markerset)[1]
        rise = np.nanmean((positions[:, brows] - neutral[brows]) @ up, axis=1)
        pick("brows up", rise, "brow rise")
    return found
