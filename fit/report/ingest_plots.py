"""QA pictures of ingestion: the gap chart and the head-marker residuals."""

from __future__ import annotations

import numpy as np
from matplotlib.colors import ListedColormap
from matplotlib.patches import Patch

from fit.report.drawing import DPI, column_starts, line_envelope, report_figure
from fit.report.plots import HEATMAP_COLUMNS
from mocap.take import FILL_METHODS, Take
from mocap.viz.figures import distinct_colours

__all__ = ["plot_gaps", "plot_head_residuals"]

_STATE_COLOURS = {"present": "#d9d9d9", "missing": "#202020",
                  "spline": "#1f77b4", "rigid": "#2ca02c", "pca": "#d62728"}


def _state_codes(take: Take, raw_missing: np.ndarray | None) -> np.ndarray:
    """Per sample: 0 present, 1 missing, 2 + i filled by FILL_METHODS[i]; shape (M, T)."""
    codes = np.where(take.missing, 1, 0)
    filled = take.filled.astype(int)
    codes = np.where(filled > 0, filled + 1, codes)
    return codes.T


def plot_gaps(take: Take, path, *, title: str | None = None) -> None:
    """Markers × time chart of present, missing and filled samples (PNG).

    Parameters
    ----------
    take : Take
        After gap filling: ``take.filled`` says which samples were filled by what,
        NaN samples are still missing.
    path : str or os.PathLike
        Output PNG.

    Notes
    -----
    A take of more than :data:`~fit.report.plots.HEATMAP_COLUMNS` frames is drawn with
    that many columns, each showing what matters most among its frames: missing, else
    the last fill method of :data:`mocap.take.FILL_METHODS` that filled one, else present
    (so that drawing the chart at its size on the page hides no gap).
    """
    names = ["present", "missing", *FILL_METHODS]
    codes = _state_codes(take, None)
    counts = {"present": int((codes == 0).sum()), "missing": int(take.missing.sum())}
    counts.update({m: int((take.filled == i + 1).sum()) for i, m in enumerate(FILL_METHODS)})
    if codes.shape[1] > HEATMAP_COLUMNS:
        # rank: present < fills (in order) < missing; the highest rank of each column
        rank = np.r_[0, len(names) - 1, np.arange(1, len(FILL_METHODS) + 1)]
        columns = column_starts(codes.shape[1], HEATMAP_COLUMNS)
        codes = np.argsort(rank)[np.maximum.reduceat(rank[codes], columns, axis=1)]
    cmap = ListedColormap([_STATE_COLOURS[n] for n in names])
    height = min(max(3.0, 0.16 * take.n_markers + 1.6), 14.0)
    with report_figure(path, 11, height) as fig:
        ax = fig.add_subplot()
        t = take.times
        ax.imshow(codes, aspect="auto", interpolation="nearest", cmap=cmap,
                  vmin=-0.5, vmax=len(names) - 0.5,
                  extent=(t[0], t[-1] + 1 / take.rate, take.n_markers - 0.5, -0.5))
        ax.set_yticks(range(take.n_markers))
        ax.set_yticklabels(take.labels, fontsize=max(4, min(8, 400 // max(take.n_markers, 1))))
        ax.set_xlabel("time (s)")
        n_filled = sum(counts[m] for m in FILL_METHODS)
        ax.set_title(title or f"{take.n_markers} markers, {take.n_frames} frames at "
                              f"{take.rate:g} Hz: {n_filled} samples filled, "
                              f"{counts['missing']} still missing")
        handles = [Patch(color=_STATE_COLOURS[n], label=f"{n} ({counts[n]})") for n in names]
        fig.legend(handles=handles, loc="outside upper center", ncol=len(names), frameon=False)


def plot_head_residuals(stabilization, path) -> None:
    """Residual of each head marker after the rigid fit, over time (PNG).

    Parameters
    ----------
    stabilization : mocap.stabilize.Stabilization
        Its ``head_residuals`` (T, H) mm, ``valid`` (T,), ``slips`` and ``take``.
    path : str or os.PathLike
        Output PNG.
    """
    res = np.asarray(stabilization.head_residuals)
    take = stabilization.take
    t = take.times
    markers = stabilization.head_markers
    if not markers:                                # stabilize = "none": nothing was fitted
        with report_figure(path, 11, 4.2) as fig:
            ax = fig.add_subplot()
            ax.text(0.5, 0.5, "no stabilization markers: the take was taken as in the head "
                              "frame (stabilize = 'none')", ha="center", va="center",
                    transform=ax.transAxes)
            ax.set_axis_off()
        return
    colours = dict(zip(markers, distinct_colours(len(markers))))
    slipping = list(dict.fromkeys(s.marker for s in stabilization.slips))
    # Slips on a track of their own above the curves, one lane per slipping marker
    # (labels beside each slip overlap as soon as slips are close together).
    with report_figure(path, 11, 4.4 + 0.22 * len(slipping)) as fig:
        if slipping:
            track, ax = fig.subplots(2, 1, sharex=True,
                                     height_ratios=[0.6 + 0.3 * len(slipping), 4])
            for lane, marker in enumerate(slipping):
                spans = [(t[s.start], t[min(s.stop, len(t)) - 1] - t[s.start] + 1 / take.rate)
                         for s in stabilization.slips if s.marker == marker]
                track.broken_barh(spans, (lane - 0.35, 0.7), color=colours.get(marker, "red"))
            track.set_yticks(range(len(slipping)), slipping, fontsize=8)
            track.set_ylim(len(slipping) - 0.5, -0.5)
            track.tick_params(axis="x", labelbottom=False)
            track.set_title(f"{len(stabilization.slips)} slip(s): runs where a head marker "
                            "leaves its place on the head (listed in the slip table)", fontsize=9)
            track.grid(axis="x", alpha=0.3)
        else:
            ax = fig.add_subplot()
        for j, label in enumerate(markers):
            ax.plot(*line_envelope(t, res[:, j], int(11 * DPI)), lw=0.8, label=label,
                    color=colours[label])
        for slip in stabilization.slips:
            ax.axvspan(t[slip.start], t[min(slip.stop, len(t)) - 1],
                       color=colours.get(slip.marker, "red"), alpha=0.12, lw=0)
        invalid = ~np.asarray(stabilization.valid)
        if invalid.any():
            ax.fill_between(t, 0, 1, where=invalid, transform=ax.get_xaxis_transform(),
                            color="black", alpha=0.12, step="mid", label="< 3 head markers")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("residual (mm)")
        med = np.nanmedian(res)
        ax.set_title(f"Head-marker residuals after the rigid fit (median {med:.2f} mm, "
                     f"{len(stabilization.slips)} slip(s) shaded, {int(invalid.sum())} frames "
                     "without a fit)", fontsize=9)
        fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", fontsize=8,
                   ncol=min(len(markers) + int(invalid.any()), 8), frameon=False)
        ax.set_ylim(bottom=0)
