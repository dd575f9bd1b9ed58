"""The chain needs every face marker in every frame: what ingestion left missing, and why.

Gap filling stops at the maximum gap and at markers seen in too few frames
(:func:`mocap.clean.fill_gaps`); the binding and the retargeting then cannot
use the take. :func:`require_complete` says so before they run, naming the
marker, the frames and the option that would fill them.
"""

from __future__ import annotations

import numpy as np

from mocap.errors import MarkerError
from mocap.gaps import find_gaps
from mocap.take import Take

__all__ = ["require_complete"]


def require_complete(take: Take, labels, fill=None) -> None:
    """Raise MarkerError when one of `labels` has a sample missing in `take`.

    Parameters
    ----------
    take : Take
        The ingested take, cut to its complete span
        (:func:`fit.pipeline.stages.complete_span`).
    labels : sequence of str
        The markers the chain reconstructs (the face markers).
    fill : mocap.clean.gapfill.FillResult, optional
        What gap filling did: its reason for leaving the marker's longest
        unfilled gap open is quoted.

    Raises
    ------
    MarkerError
        Names the marker with the longest gap left, its frame numbers and
        duration, the number of such markers, and why filling left it.
    """
    face = take.select(labels)
    gaps = find_gaps(face.missing)
    if len(gaps) == 0:
        return
    worst = int(np.argmax(gaps.length))
    label = face.labels[gaps.marker[worst]]
    first = take.first_frame + int(gaps.start[worst])
    length = int(gaps.length[worst])
    reason = ""
    if fill is not None:
        table = fill.gaps[(fill.gaps["marker"] == label) & (fill.gaps["filled"] == 0)]
        if len(table):
            reason = str(table.loc[table["length"].idxmax(), "reason"])
    if reason.startswith("longer than max_gap"):
        remedy = f"set [ingest] max_gap = {length} or more to fill it"
    elif "min_visible" in reason:
        remedy = "lower [ingest] min_visible to fill it anyway"
    else:
        remedy = "fill it ([ingest] fill, max_gap, min_visible)"
    n_markers = len(np.unique(gaps.marker))
    raise MarkerError(label, f"{take.source.path or 'the take'}: missing in frames {first}-"
                             f"{first + length - 1} ({length / take.rate:.2f} s) after gap "
                             f"filling{f' ({reason})' if reason else ''}; {n_markers} face "
                             "marker(s) have gaps left, and the chain needs every face marker "
                             f"in every frame: {remedy}, or leave the marker out of the "
                             "marker set")
