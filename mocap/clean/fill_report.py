"""What gap filling did, in the lines a user reads: what was filled, what was not and why.

:func:`fill_notices` turns a :class:`mocap.clean.gapfill.FillResult` into a few
sentences (one per kind of event), each naming the markers, the frame numbers
and the seconds at stake; :func:`mocap.clean.ingest.ingest` warns with them, so
that ``mocap2mesh ingest`` and ``run`` print them and ``run`` records them.
"""

from __future__ import annotations

from mocap.take import Take

__all__ = ["fill_notices", "marker_visibility"]

#: Markers named in full in one notice; the others are counted.
_LISTED = 8


def _span(take: Take, row) -> str:
    """``"section3-2, frames 1200-1391 (1.92 s)"`` for a gap-table row (frame numbers)."""
    first, length = take.first_frame + int(row.start), int(row.length)
    frames = f"frame {first}" if length == 1 else f"frames {first}-{first + length - 1}"
    return f"{row.marker}, {frames} ({length / take.rate:.2f} s)"


def _listed(items) -> str:
    items = list(items)
    more = len(items) - _LISTED
    return ", ".join(items[:_LISTED]) + (f" and {more} more" if more > 0 else "")


def fill_notices(result, take: Take, *, where: str | None = None) -> tuple[str, ...]:
    """Sentences on what a gap fill did and did not do.

    Parameters
    ----------
    result : mocap.clean.gapfill.FillResult
    take : Take
        The take that was filled (frame numbers, rate, visibility).
    where : str, optional
        Named first in every sentence (default the take's file, or "the take").

    Returns
    -------
    tuple of str
        In order, those that apply: markers seen in too few frames to be
        filled, gaps longer than the maximum left open, and what was filled
        (samples, gaps, methods, the longest fill). Markers deliberately left
        alone (``markers=``) are the caller's to report.
    """
    where = where or take.source.path or "the take"
    gaps = result.gaps
    notes = []
    scarce = gaps.loc[gaps["reason"].str.contains("under min_visible"), "marker"].unique()
    if len(scarce):
        notes.append(f"{where}: {len(scarce)} marker(s) visible in too few frames to fill, "
                     "reported and left with their gaps (ingest min_visible): "
                     f"{_listed(marker_visibility(take, scarce))}")
    long = gaps[gaps["reason"].str.startswith("longer than max_gap")]
    if len(long):
        worst = long.loc[long["length"].idxmax()]
        notes.append(f"{where}: {len(long)} gap(s) longer than max_gap = {result.max_gap} "
                     f"frames ({result.max_gap / take.rate:.2f} s) left unfilled, the longest "
                     f"{_span(take, worst)}; set max_gap to at least {int(worst['length'])} "
                     "frames to fill them all")
    done = gaps[gaps["filled"] > 0]
    if len(done):
        methods = done.groupby("method")["filled"].agg(["count", "sum"])
        by = ", ".join(f"{m} {int(r['sum'])} samples in {int(r['count'])} gaps"
                       for m, r in methods.iterrows())
        worst = done.loc[done["length"].idxmax()]
        notes.append(f"{where}: filled {int(done['filled'].sum())} samples in {len(done)} "
                     f"gap(s) ({by}); the longest {_span(take, worst)}")
    return tuple(notes)


def marker_visibility(take: Take, labels) -> list[str]:
    """``"Unlabeled1 (visible in 35 of 3000 frames)"`` for each of `labels`."""
    seen = (~take.missing).sum(axis=0)
    return [f"{label} (visible in {int(seen[take.index(label)])} of {take.n_frames} frames)"
            for label in labels]
