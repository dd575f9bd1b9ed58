"""QA pictures of ingestion: the gap chart and the head-marker residuals."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from matplotlib.colors import to_rgba
from matplotlib.patches import Patch

from fit.report.drawing import DPI, column_starts, label_ticks, line_envelope, report_figure
from fit.report.plots import HEATMAP_COLUMNS
from mocap.take import FILL_METHODS, Take
from mocap.viz.figures import distinct_colours

__all__ = ["GapChart", "HeadResiduals", "plot_gaps", "plot_head_residuals"]

_STATE_COLOURS = {"present": "#d9d9d9", "missing": "#202020",
                  "spline": "#1f77b4", "rigid": "#2ca02c", "pca": "#d62728"}
#: The states of the gap chart, in the order of its codes.
_STATES = ("present", "missing", *FILL_METHODS)
#: The RGBA (uint8) of each code of the gap chart.
_STATE_RGBA = np.round(255 * np.array([to_rgba(_STATE_COLOURS[n])
                                       for n in _STATES])).astype(np.uint8)


@dataclass(frozen=True, eq=False)
class GapChart:
    """What the gap chart shows of a take: a few columns of states per marker, small
    enough to send to a figure helper (:class:`fit.report.figure_queue.FigureQueue`).

    Attributes
    ----------
    labels : tuple of str
        The M markers.
    codes : ndarray of int8, shape (M, C)
        Per marker and column of frames: 0 present, 1 missing, 2 + i filled by
        ``FILL_METHODS[i]``. A take of more than :data:`~fit.report.plots.HEATMAP_COLUMNS`
        frames has that many columns, each showing what matters most among its frames:
        missing, else the last fill method that filled one, else present (so that drawing
        the chart at its size on the page hides no gap); else one column a frame.
    counts : dict of str to int
        Samples in each state over the whole take.
    times : tuple of float
        Start of the first frame and end of the last, s.
    n_frames : int
    rate : float
        Hz.
    """

    labels: tuple
    codes: np.ndarray
    counts: dict
    times: tuple
    n_frames: int
    rate: float

    @classmethod
    def of(cls, take: Take) -> GapChart:
        """The chart of `take` after gap filling (``take.filled`` says which samples were
        filled by what, NaN samples are still missing)."""
        filled = take.filled.astype(np.int8)
        codes = np.where(filled > 0, filled + 1, take.missing.astype(np.int8)).T
        counts = {state: int(n) for state, n in
                  zip(_STATES, np.bincount(codes.ravel(), minlength=len(_STATES)))}
        counts["missing"] = int(take.missing.sum())
        if codes.shape[1] > HEATMAP_COLUMNS:
            # rank: present < fills (in order) < missing; the highest rank of each column
            rank = np.r_[0, len(_STATES) - 1, np.arange(1, len(FILL_METHODS) + 1)]
            columns = column_starts(codes.shape[1], HEATMAP_COLUMNS)
            codes = np.argsort(rank)[np.maximum.reduceat(rank[codes], columns, axis=1)]
        t = take.times
        return cls(take.labels, codes.astype(np.int8), counts,
                   (float(t[0]), float(t[-1] + 1 / take.rate)), take.n_frames, take.rate)


def plot_gaps(take: Take | GapChart, path, *, title: str | None = None) -> None:
    """Markers × time chart of present, missing and filled samples (PNG).

    Parameters
    ----------
    take : Take or GapChart
        After gap filling: ``take.filled`` says which samples were filled by what,
        NaN samples are still missing; or its :class:`GapChart`.
    path : str or os.PathLike
        Output PNG.
    """
    chart = take if isinstance(take, GapChart) else GapChart.of(take)
    n_markers = len(chart.labels)
    counts = chart.counts
    height = min(max(3.0, 0.16 * n_markers + 1.6), 14.0)
    with report_figure(path, 11, height) as fig:
        ax = fig.add_subplot()
        # coloured here, a state's colour for each code, at the chart's size: matplotlib
        # would map the codes at the image's size on the page (nearest-neighbour, so the
        # same colours either way), several hundred times the pixels
        ax.imshow(_STATE_RGBA[chart.codes], aspect="auto", interpolation="nearest",
                  extent=(*chart.times, n_markers - 0.5, -0.5))
        label_ticks(ax, range(n_markers), chart.labels,
                    fontsize=max(4, min(8, 400 // max(n_markers, 1))))
        ax.set_xlabel("time (s)")
        n_filled = sum(counts[m] for m in FILL_METHODS)
        ax.set_title(title or f"{n_markers} markers, {chart.n_frames} frames at "
                              f"{chart.rate:g} Hz: {n_filled} samples filled, "
                              f"{counts['missing']} still missing")
        handles = [Patch(color=_STATE_COLOURS[n], label=f"{n} ({counts[n]})") for n in _STATES]
        fig.legend(handles=handles, loc="outside upper center", ncol=len(_STATES), frameon=False)


@dataclass(frozen=True, eq=False)
class HeadResiduals:
    """What the head-residual figure shows of a stabilization (its residuals, fitted frames
    and slips, not the take): small enough to send to a figure helper.

    Attributes
    ----------
    head_markers : tuple of str
    head_residuals : ndarray of shape (T, H), mm
    valid : ndarray of bool, shape (T,)
    slips : tuple of mocap.stabilize.Slip
    times : ndarray of shape (T,), s
    rate : float
        Hz.
    """

    head_markers: tuple
    head_residuals: np.ndarray
    valid: np.ndarray
    slips: tuple
    times: np.ndarray
    rate: float

    @classmethod
    def of(cls, stabilization) -> HeadResiduals:
        """The figure's part of a :class:`mocap.stabilize.Stabilization`."""
        take = stabilization.take
        return cls(tuple(stabilization.head_markers), np.asarray(stabilization.head_residuals),
                   np.asarray(stabilization.valid), tuple(stabilization.slips), take.times,
                   take.rate)


def plot_head_residuals(stabilization, path) -> None:
    """Residual of each head marker after the rigid fit, over time (PNG).

    Parameters
    ----------
    stabilization : mocap.stabilize.Stabilization or HeadResiduals
        Its ``head_residuals`` (T, H) mm, ``valid`` (T,), ``slips`` and times.
    path : str or os.PathLike
        Output PNG.
    """
    view = stabilization if isinstance(stabilization, HeadResiduals) \
        else HeadResiduals.of(stabilization)
    res, t, markers = view.head_residuals, view.times, view.head_markers
    if not markers:                                # stabilize = "none": nothing was fitted
        with report_figure(path, 11, 4.2) as fig:
            ax = fig.add_subplot()
            ax.text(0.5, 0.5, "no stabilization markers: the take was taken as in the head "
                              "frame (stabilize = 'none')", ha="center", va="center",
                    transform=ax.transAxes)
            ax.set_axis_off()
        return
    colours = dict(zip(markers, distinct_colours(len(markers))))
    slips = view.slips
    slipping = list(dict.fromkeys(s.marker for s in slips))
    # Slips on a track of their own above the curves, one lane per slipping marker
    # (labels beside each slip overlap as soon as slips are close together).
    with report_figure(path, 11, 4.4 + 0.22 * len(slipping)) as fig:
        if slipping:
            track, ax = fig.subplots(2, 1, sharex=True,
                                     height_ratios=[0.6 + 0.3 * len(slipping), 4])
            for lane, marker in enumerate(slipping):
                spans = [(t[s.start], t[min(s.stop, len(t)) - 1] - t[s.start] + 1 / view.rate)
                         for s in slips if s.marker == marker]
                track.broken_barh(spans, (lane - 0.35, 0.7), color=colours.get(marker, "red"))
            track.set_yticks(range(len(slipping)), slipping, fontsize=8)
            track.set_ylim(len(slipping) - 0.5, -0.5)
            track.tick_params(axis="x", labelbottom=False)
            track.set_title(f"{len(slips)} slip(s): runs where a head marker "
                            "leaves its place on the head (listed in the slip table)", fontsize=9)
            track.grid(axis="x", alpha=0.3)
        else:
            ax = fig.add_subplot()
        for j, label in enumerate(markers):
            ax.plot(*line_envelope(t, res[:, j], int(11 * DPI)), lw=0.8, label=label,
                    color=colours[label])
        for slip in slips:
            ax.axvspan(t[slip.start], t[min(slip.stop, len(t)) - 1],
                       color=colours.get(slip.marker, "red"), alpha=0.12, lw=0)
        invalid = ~np.asarray(view.valid)
        if invalid.any():
            ax.fill_between(t, 0, 1, where=invalid, transform=ax.get_xaxis_transform(),
                            color="black", alpha=0.12, step="mid", label="< 3 head markers")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("residual (mm)")
        med = np.nanmedian(res)
        ax.set_title(f"Head-marker residuals after the rigid fit (median {med:.2f} mm, "
                     f"{len(slips)} slip(s) shaded, {int(invalid.sum())} frames "
                     "without a fit)", fontsize=9)
        fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", fontsize=8,
                   ncol=min(len(markers) + int(invalid.any()), 8), frameon=False)
        ax.set_ylim(bottom=0)
