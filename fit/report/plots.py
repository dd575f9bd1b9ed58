"""QA charts of reconstruction errors (PNG): α over time, marker × time heatmap,
per-marker errors by region."""

from __future__ import annotations

import textwrap
from dataclasses import dataclass
from typing import Mapping

import numpy as np
from matplotlib import colormaps
from matplotlib.cm import ScalarMappable
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.colors import Normalize, to_rgba
from matplotlib.patches import Patch

from fit._moved import PLOTS_NAMES
from fit.metrics import ReconstructionErrors
from fit.report.drawing import (
    IMAGE_WIDTH_PX,
    PAGE_WIDTH,
    column_starts,
    label_ticks,
    line_envelope,
    plain_log_axis,
    report_figure,
    report_figures,
)
from mocap.errors import InputError
from mocap.util.deprecation import moved_names
from mocap.util.order_statistics import percentile
from mocap.viz.figures import distinct_colours

__all__ = ["plot_alpha", "plot_error_heatmap", "plot_error_heatmaps", "HeatmapColumns",
           "plot_marker_errors", "plot_marker_error_charts", "plot_held_out", "error_axis_top",
           "region_groups", "region_colours", "bar_collection", "HEATMAP_COLUMNS"]

#: Most columns of an error heatmap: fewer than its pixels across at the page's width (about
#: 1,000 with the marker names, region names and colour bar beside it), so that drawing the
#: image drops no column, with room for longer names.
HEATMAP_COLUMNS = 800


def region_groups(labels, markerset=None) -> tuple[np.ndarray, list]:
    """Order markers region by region.

    Parameters
    ----------
    labels : sequence of str
        The markers, in their column order.
    markerset : mocap.markerset.MarkerSet, optional
        Gives the regions (in file order); markers it does not name go last, in
        a group ``"unassigned"``. Without it, one group ``"markers"``.

    Returns
    -------
    order : ndarray of int, shape (M,)
        Columns in display order.
    groups : list of (region, start, stop)
        Each region's slice of the display order.
    """
    labels = list(labels)
    if markerset is None:
        return np.arange(len(labels)), [("markers", 0, len(labels))]
    column = {label: i for i, label in enumerate(labels)}
    named = [("head", markerset.head), *markerset.regions.items()]
    order, groups, seen = [], [], set()
    for region, members in named:
        cols = [column[m] for m in members if m in column]
        if cols:
            groups.append((region, len(order), len(order) + len(cols)))
            order += cols
            seen.update(cols)
    rest = [i for i in range(len(labels)) if i not in seen]
    if rest:
        groups.append(("unassigned", len(order), len(order) + len(rest)))
        order += rest
    return np.array(order, dtype=np.intp), groups


def _as_results(results) -> dict:
    if isinstance(results, ReconstructionErrors):
        return {results.name or "reconstruction": results}
    if isinstance(results, Mapping):
        out = dict(results)
    else:
        out = {r.name: r for r in results}
    if not out:
        raise InputError("results is empty: give at least one ReconstructionErrors")
    return out


def _time_axis(n_frames: int, rate: float | None) -> tuple[np.ndarray, str]:
    if rate is None:
        return np.arange(n_frames, dtype=float), "frame index"
    return np.arange(n_frames) / rate, "time (s)"


def plot_alpha(results, path, *, rate: float | None = None, worst: Mapping | None = None,
               n_worst: int = 5, separation: int | None = None, first_frame: int = 0,
               log: bool | None = None, title: str | None = None) -> None:
    """α(t) of eq. 6 for each basis on one chart, the worst frames marked (PNG).

    Parameters
    ----------
    results : mapping of name to ReconstructionErrors, or a sequence of them
        One curve each.
    path : str or os.PathLike
    rate : float, optional
        Frame rate, Hz: time in seconds on the x axis (else frame indices).
    worst : mapping of name to frame indices, optional
        Frames to mark on each curve (ranked); default each result's
        `n_worst` worst frames by RMS, at least `separation` frames apart.
    n_worst : int
    separation : int, optional
        Default T / 50.
    first_frame : int
        Added to the frame indices in the labels (the take's frame numbers).
    log : bool, optional
        Logarithmic α axis; default when the bases' median α differ by over 10×.
    """
    results = _as_results(results)
    first = next(iter(results.values()))
    x, xlabel = _time_axis(first.n_frames, rate)
    separation = separation or max(1, first.n_frames // 50)
    if worst is None:
        worst = {name: r.worst_frames(n_worst, separation=separation)
                 for name, r in results.items()}
    medians = [np.nanmedian(r.alpha) for r in results.values()]
    if log is None:
        positive = [m for m in medians if m > 0]
        log = len(positive) > 1 and max(positive) / min(positive) > 10
    with report_figure(path, PAGE_WIDTH, 4.8) as fig:
        ax = fig.add_subplot()
        for (name, res), colour in zip(results.items(), distinct_colours(len(results))):
            ax.plot(*line_envelope(x, res.alpha, IMAGE_WIDTH_PX), lw=0.8, color=colour,
                    label=f"{name}: α = {res.totals['alpha']:.3g} % over the take, "
                          f"max {res.totals['alpha_max']:.3g} %")
            frames = np.asarray(worst.get(name, ()), dtype=np.intp)
            ax.scatter(x[frames], res.alpha[frames], s=40, facecolor="none", edgecolor=colour,
                       linewidth=1.5, zorder=3)
            for rank, t in enumerate(frames, start=1):
                ax.annotate(f"#{rank}: {t + first_frame}", (x[t], res.alpha[t]), fontsize=7,
                            color=colour, xytext=(0, 7 + 9 * (rank % 2)), ha="center",
                            textcoords="offset points",
                            bbox=dict(boxstyle="square,pad=0.1", fc="white", ec="none", alpha=0.7))
        if log:
            ax.set_yscale("log")
            plain_log_axis(ax.yaxis)
        else:
            ax.set_ylim(0, ax.get_ylim()[1] * 1.08)
        ax.set_xlim(x[0], x[-1])
        ax.set_xlabel(xlabel)
        ax.set_ylabel("α (%)")
        origin = ", ".join(f"{v:.0f}" for v in first.origin)
        ax.set_title(title or f"Reconstruction error α (eq. 6, origin at ({origin}) mm); "
                              "circles: worst frames by RMS, #rank: frame")
        fig.legend(loc="outside upper center", fontsize=8, ncol=min(len(results), 3),
                   frameon=False)
        ax.grid(alpha=0.3, which="both")


def _region_labels_right(ax, groups) -> None:
    """White separators between the heatmap's region rows, region names on the right."""
    for _, start, _ in groups[1:]:
        ax.axhline(start - 0.5, color="white", lw=1.5)
    sec = ax.secondary_yaxis("right")
    sec.set_yticks([(start + stop - 1) / 2 for _, start, stop in groups],
                   labels=[name.replace("_", " ") for name, _, _ in groups], fontsize=8)
    sec.tick_params(length=0)


def plot_error_heatmap(errors: ReconstructionErrors, path, *, markerset=None,
                       rate: float | None = None, vmax: float | None = None,
                       title: str | None = None) -> None:
    """Marker × time heatmap of the error (mm), markers grouped by region (PNG).

    Parameters
    ----------
    errors : ReconstructionErrors
    path : str or os.PathLike
    markerset : mocap.markerset.MarkerSet, optional
        Groups the rows by region (separators and region names on the right).
    rate : float, optional
        Frame rate, Hz, for a time axis in seconds.
    vmax : float, optional
        Top of the colour scale, mm; default the 99.5th percentile of the errors
        (larger errors saturate). Excluded samples are grey.

    Notes
    -----
    A take of more than :data:`HEATMAP_COLUMNS` frames is drawn with that many
    columns, each the largest error of its frames (so that resampling the
    image hides no error), grey only where every one of its frames is excluded.
    """
    name = errors.name or "reconstruction"
    plot_error_heatmaps({name: errors}, {name: path}, markerset=markerset, rate=rate,
                        vmax=vmax, titles=None if title is None else {name: title})


@dataclass(frozen=True, eq=False)
class HeatmapColumns:
    """What an error heatmap shows of a reconstruction: its errors in at most
    :data:`HEATMAP_COLUMNS` columns of frames, small enough to send to a figure helper
    (:class:`fit.report.figure_queue.FigureQueue`).

    Attributes
    ----------
    name : str
    labels : tuple of str
        The M markers.
    columns : ndarray, shape (M, C), mm
        Per marker, the largest error of each column's frames (so that drawing the
        image at its size on the page hides no error), NaN where every one of its frames
        is excluded; one column a frame for a take of at most HEATMAP_COLUMNS frames.
    top : float
        The 99.5th percentile of all its errors, mm (1 without any): the colour scale's
        default top.
    rms_mm : float
    n_frames : int
    """

    name: str
    labels: tuple
    columns: np.ndarray
    top: float
    rms_mm: float
    n_frames: int

    @classmethod
    def of(cls, errors: ReconstructionErrors) -> HeatmapColumns:
        """The heatmap's columns of `errors`."""
        data = errors.errors.T
        finite = data[np.isfinite(data)]
        top = percentile(finite, 99.5, overwrite_input=True) if finite.size else 1.0
        if data.shape[1] > HEATMAP_COLUMNS:         # more columns than pixels: max-pool
            data = np.fmax.reduceat(data, column_starts(data.shape[1], HEATMAP_COLUMNS),
                                    axis=1)
        return cls(errors.name, tuple(errors.labels), np.ascontiguousarray(data), float(top),
                   float(errors.totals["rms_mm"]), errors.n_frames)


def plot_error_heatmaps(results: Mapping, paths: Mapping, *, markerset=None,
                        rate: float | None = None, vmax: float | None = None,
                        titles: Mapping | None = None) -> None:
    """:func:`plot_error_heatmap` of each of several reconstructions of one take, on one
    colour scale: one PNG each, the figure laid out once (:func:`report_figures`).

    Parameters
    ----------
    results : mapping of name to ReconstructionErrors or HeatmapColumns
        Of the same markers and frames.
    paths : mapping of name to str or os.PathLike
        The PNG of each.
    markerset, rate
        As for :func:`plot_error_heatmap`.
    vmax : float, optional
        Top of the colour scale, mm; default the largest of their 99.5th percentiles
        (:attr:`HeatmapColumns.top`).
    titles : mapping of name to str, optional

    Raises
    ------
    InputError
        Results of other markers or frames than the first's.
    """
    results = _of_one_take({name: r if isinstance(r, HeatmapColumns) else HeatmapColumns.of(r)
                            for name, r in results.items()}, "error heatmaps")
    first = next(iter(results.values()))
    order, groups = region_groups(first.labels, markerset)
    if vmax is None:
        vmax = max(r.top for r in results.values())
    # coloured here, at the columns' size: matplotlib would colour the image at its size on
    # the page, 20 times the pixels (nearest-neighbour, so the same colours either way)
    colours = ScalarMappable(Normalize(0, vmax),
                             colormaps["magma"].with_extremes(bad="#b0b0b0"))
    x, xlabel = _time_axis(first.n_frames, rate)
    step = x[1] - x[0] if len(x) > 1 else 1.0
    n = len(order)
    headings = {name: (titles or {}).get(name) or
                f"{heatmap.name or 'reconstruction'}: error per marker and frame "
                f"(RMS {heatmap.rms_mm:.2f} mm; grey = missing)"
                for name, heatmap in results.items()}
    for names in _same_layouts(headings):
        image = None
        with report_figures(PAGE_WIDTH, min(max(3.5, 0.17 * n + 1.8), 14.0)) as (fig, write):
            ax = fig.add_subplot()
            for name in names:
                pixels = colours.to_rgba(np.ma.masked_invalid(results[name].columns[order]),
                                         bytes=True)
                if image is None:
                    image = ax.imshow(pixels, aspect="auto", interpolation="nearest",
                                      extent=(x[0], x[-1] + step, n - 0.5, -0.5))
                    label_ticks(ax, range(n), [first.labels[i] for i in order],
                                fontsize=max(4, min(8, 400 // max(n, 1))))
                    _region_labels_right(ax, groups)
                    ax.set_xlabel(xlabel)
                    fig.colorbar(colours, ax=ax, label="error (mm)", extend="max", pad=0.01,
                                 fraction=0.05)
                else:
                    image.set_data(pixels)
                ax.set_title(headings[name])
                write(paths[name])


def plot_marker_errors(errors: ReconstructionErrors, path, *, markerset=None,
                       ymax: float | None = None, title: str | None = None) -> None:
    """Mean and 95th-percentile error of each marker, grouped and coloured by region (PNG).

    Parameters
    ----------
    errors : ReconstructionErrors
    path : str or os.PathLike
    markerset : mocap.markerset.MarkerSet, optional
        Regions; without it all markers share one colour.
    ymax : float, optional
        Top of the error axis, mm (one scale for every basis of a report); default
        :func:`error_axis_top`.
    """
    name = errors.name or "reconstruction"
    plot_marker_error_charts({name: errors}, {name: path}, markerset=markerset, ymax=ymax,
                             titles=None if title is None else {name: title})


def plot_marker_error_charts(results: Mapping, paths: Mapping, *, markerset=None,
                             ymax: float | None = None, titles: Mapping | None = None) -> None:
    """:func:`plot_marker_errors` of each of several reconstructions of one take, on one
    error axis: one PNG each, the figure laid out once (:func:`report_figures`).

    Parameters
    ----------
    results : mapping of name to ReconstructionErrors
        Of the same markers (their per-frame statistics are enough:
        :meth:`~fit.metrics.ReconstructionErrors.per_frame`).
    paths : mapping of name to str or os.PathLike
    markerset
        As for :func:`plot_marker_errors`.
    ymax : float, optional
        Top of the error axis, mm; default :func:`error_axis_top` of them all.
    titles : mapping of name to str, optional

    Raises
    ------
    InputError
        Results of other markers than the first's.
    """
    results = _of_one_take(results, "per-marker error charts", frames=False)
    first = next(iter(results.values()))
    order, groups = region_groups(first.labels, markerset)
    gap = 0.8
    pos = np.concatenate([np.arange(start, stop) + gap * k
                          for k, (_, start, stop) in enumerate(groups)])
    colours = region_colours(groups)
    # every bar in one collection, the wide pale ones first (under the narrow ones)
    at, widths = np.concatenate([pos, pos]), np.repeat([0.8, 0.45], len(pos))
    faces = np.concatenate([colours * [1, 1, 1, 0.35], colours])
    ymax = error_axis_top(results) if ymax is None else ymax
    headings = {name: (titles or {}).get(name) or
                f"{errors.name or 'reconstruction'}: error per marker "
                f"(mean {errors.totals['mean_mm']:.2f} mm, "
                f"95th percentile {errors.totals['p95_mm']:.2f} mm)"
                for name, errors in results.items()}
    width = _marker_chart_width(len(pos), len(groups), gap)
    for names in _same_layouts(headings):
        bars = None
        with report_figures(width, 5.0) as (fig, write):
            ax = fig.add_subplot()
            for name in names:
                errors = results[name]
                lengths = np.concatenate([errors.marker_p95[order], errors.marker_mean[order]])
                if bars is None:
                    bars = ax.add_collection(bar_collection(at, lengths, widths, faces))
                    _marker_chart_axes(ax, fig, pos, groups, gap,
                                       [first.labels[i] for i in order], ymax)
                else:
                    bars.set_verts(_bar_corners(at, lengths, widths)[0])
                    bars.set_facecolor(faces[np.isfinite(lengths)])
                ax.set_title(headings[name])
                write(paths[name])


def _same_layouts(titles: Mapping) -> list:
    """The names of `titles` (name to title) in groups whose charts share a layout, in
    order: those whose titles have as many lines (a chart's layout depends on its title's
    height, not on its words)."""
    groups = {}
    for name, title in titles.items():
        groups.setdefault(title.count("\n"), []).append(name)
    return list(groups.values())


def _marker_chart_axes(ax, fig, pos, groups, gap: float, labels, ymax: float) -> None:
    """What every per-marker chart of a take shares: the markers' names below, the regions'
    above and dotted lines between them, the error axis to `ymax`, the legend."""
    label_ticks(ax, pos, labels, axis="x", rotation=70, ha="right", rotation_mode="anchor",
                fontsize=7)
    sec = ax.secondary_xaxis("top")
    sec.set_xticks([(pos[start] + pos[stop - 1]) / 2 for _, start, stop in groups],
                   labels=[name.replace("_", " ") for name, _, _ in groups], fontsize=8,
                   rotation=30, ha="left", rotation_mode="anchor")
    sec.tick_params(length=0)
    between = [pos[start] - 0.5 - gap / 2 for _, start, _ in groups[1:]]
    ax.add_collection(LineCollection([[(x, 0), (x, 1)] for x in between], colors="grey",
                                     linewidths=0.6, linestyles=":",
                                     transform=ax.get_xaxis_transform()), autolim=False)
    ax.set_xlim(pos[0] - 0.8, pos[-1] + 0.8)
    ax.set_ylabel("error (mm)")
    ax.set_ylim(0, ymax)
    fig.legend(handles=[Patch(color="grey", alpha=0.35, label="95th percentile (wide, pale)"),
                        Patch(color="grey", label="mean (narrow)")],
               loc="outside lower center", ncol=2, fontsize=8, frameon=False)
    ax.grid(axis="y", alpha=0.3)


def error_axis_top(results: Mapping) -> float:
    """Top of the per-marker charts' error axis for all `results` (name to
    ReconstructionErrors), mm: 8 % above the largest 95th percentile of a marker."""
    tops = [np.nanmax(r.marker_p95) for r in results.values() if np.isfinite(r.marker_p95).any()]
    return 1.08 * max(max(tops, default=0.0), 1e-6)


def _of_one_take(results: Mapping, what: str, *, frames: bool = True) -> dict:
    """`results` (name to ReconstructionErrors or HeatmapColumns), checked to share the
    first's markers (and frames): the charts of several share its layout."""
    results = dict(results)
    if not results:
        raise InputError(f"{what}: give at least one ReconstructionErrors")
    first_name, first = next(iter(results.items()))
    for name, errors in results.items():
        if tuple(errors.labels) != tuple(first.labels):
            raise InputError(f"{what}: {name!r} is of other markers than {first_name!r} "
                             f"({', '.join(errors.labels[:3])}... against "
                             f"{', '.join(first.labels[:3])}...): give the charts of one take")
        if frames and errors.n_frames != first.n_frames:
            raise InputError(f"{what}: {name!r} has {errors.n_frames} frames, {first_name!r} "
                             f"{first.n_frames}: give the charts of one take")
    return results


def _marker_chart_width(n_markers: int, n_groups: int, gap: float) -> float:
    """Inches of the per-marker chart: the page's width when its labels fit there (a marker's
    rotated name needs about 0.11 in), wider for more markers, narrower for a few."""
    slots = n_markers + gap * (n_groups - 1)
    return min(max(8.0, 0.28 * n_markers + 2.5), max(PAGE_WIDTH, 0.11 * slots + 1.6))


def region_colours(groups) -> np.ndarray:
    """RGBA (M, 4) of the markers in display order, a colour per group of
    :func:`region_groups`."""
    palette = np.array([to_rgba(c) for c in distinct_colours(len(groups))])
    return np.repeat(palette, [stop - start for _, start, stop in groups], axis=0)


def bar_collection(at, lengths, widths, colours, *, horizontal: bool = False) -> PolyCollection:
    """Bars from 0 to `lengths`, centred on `at`, as one collection (NaN lengths: no bar).

    Parameters
    ----------
    at, lengths, widths : ndarray, shape (B,)
    colours : ndarray, shape (B, 4)
        RGBA of each bar, drawn in order (later bars over earlier ones).
    horizontal : bool
        Bars along x (``Axes.barh``) instead of y (``Axes.bar``).

    Returns
    -------
    matplotlib.collections.PolyCollection
        For ``Axes.add_collection``; the length axis sticks to 0 as with ``Axes.bar``.
    """
    corners, keep = _bar_corners(at, lengths, widths, horizontal=horizontal)
    bars = PolyCollection(corners, facecolors=colours[keep], edgecolors="none", linewidths=0)
    (bars.sticky_edges.x if horizontal else bars.sticky_edges.y).append(0)
    return bars


def _bar_corners(at, lengths, widths, *, horizontal: bool = False):
    """The corners (B', 4, 2) of the bars of :func:`bar_collection`, and which of the B
    bars they are (those of finite length)."""
    keep = np.isfinite(lengths)
    at, lengths, half = at[keep], lengths[keep], widths[keep] / 2
    zero = np.zeros_like(at)
    corners = np.stack([np.column_stack(c) for c in ((at - half, zero), (at - half, lengths),
                                                     (at + half, lengths), (at + half, zero))],
                       axis=1)
    return (corners[:, :, ::-1] if horizontal else corners), keep


def plot_held_out(in_sample: dict, held_out: dict, path, *, label: str) -> None:
    """RMS and 95th-percentile marker error of each basis, in-sample beside out-of-sample (PNG).

    Parameters
    ----------
    in_sample : mapping of basis name to ReconstructionErrors
        Scored on the frames the basis was built from (every basis).
    held_out : mapping of basis name to ReconstructionErrors
        The same bases scored on frames they were not built from (a subset).
    path : str or os.PathLike
    label : str
        How the frames were held out (the subtitle).
    """
    names = list(in_sample)
    with report_figure(path, 7.5, 3.4) as fig:
        axes = fig.subplots(1, 2)
        colours = {"in-sample": "#7f9fbf", "out-of-sample": "#d9822b"}
        for ax, key, what in zip(axes, ("rms_mm", "p95_mm"), ("RMS", "95th percentile")):
            for k, (kind, source) in enumerate((("in-sample", in_sample),
                                               ("out-of-sample", held_out))):
                x = [i + (k - 0.5) * 0.38 for i, n in enumerate(names) if n in source]
                v = [source[n].totals[key] for n in names if n in source]
                bars = ax.bar(x, v, width=0.36, color=colours[kind], label=kind)
                ax.bar_label(bars, fmt="%.2f", fontsize=7, padding=1)
            ax.set_xticks(range(len(names)), names)
            ax.set_ylabel(f"marker error, {what} (mm)")
            ax.set_ylim(0, ax.get_ylim()[1] * 1.15)
            ax.grid(axis="y", alpha=0.3)
        handles, texts = axes[0].get_legend_handles_labels()
        fig.legend(handles, texts, loc="outside lower center", ncol=2, fontsize=8, frameon=False)
        fig.suptitle("\n".join(textwrap.wrap(f"In-sample vs out-of-sample: {label}", 95)),
                     fontsize=8)


__getattr__ = moved_names(__name__, PLOTS_NAMES)
