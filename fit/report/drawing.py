"""The report's matplotlib figures: drawn once, at the size the page shows them, every text
as typed (PNG).

:func:`report_figure` gives a figure to draw on and writes its pixels when the block ends
(:func:`mocap.viz.figures.draw_png`: one draw), with plain text without a pass over the
figure's artists (labels come from files: ``$\\frac{a}{$`` is drawn as typed);
:func:`report_figures` one written several times, laid out once (a chart of each basis).
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np
from matplotlib import rc_context, rcParams
from matplotlib.lines import TICKDOWN, TICKLEFT
from matplotlib.ticker import LogFormatter
from matplotlib.transforms import ScaledTranslation

from mocap.viz.figures import draw_png, new_figure

__all__ = ["DPI", "PAGE_WIDTH", "PAGE_WIDTH_PX", "FIGURE_MARGIN_PX", "IMAGE_WIDTH_PX",
           "report_figure", "report_figures", "plain_log_axis", "column_starts", "line_envelope",
           "label_ticks"]

#: Widest the report page's body gets, CSS pixels.
PAGE_WIDTH_PX = 1400
#: Left and right margin of a ``<figure>`` on the page (the browsers' default), CSS pixels.
FIGURE_MARGIN_PX = 40
#: Widest the page shows an image: one this wide is shown pixel for pixel, a wider one scaled
#: down (and its text with it).
IMAGE_WIDTH_PX = PAGE_WIDTH_PX - 2 * FIGURE_MARGIN_PX
#: Pixels per inch of every figure: its fonts' size on the page.
DPI = 120
#: Figure width, inches, that fills the page's image width at :data:`DPI`.
PAGE_WIDTH = IMAGE_WIDTH_PX / DPI


@contextmanager
def report_figure(path, width: float, height: float):
    """A new figure of `width` × `height` inches, written to `path` as PNG when the block ends.

    Every text made in the block is plain (mathtext off, tick labels included); the figure is
    drawn once, at :data:`DPI`. Nothing is written when the block raises.

    Parameters
    ----------
    path : str or os.PathLike
        Output PNG (written atomically).
    width, height : float
        Inches.

    Yields
    ------
    matplotlib.figure.Figure
        Constrained layout, on an Agg canvas.
    """
    with report_figures(width, height) as (fig, write):
        yield fig
        write(path)


@contextmanager
def report_figures(width: float, height: float):
    """A new figure of `width` × `height` inches written to several PNGs as it changes.

    ``write(path)`` draws the figure as it is then. The first write lays it out (constrained
    layout); the later ones keep that layout and skip its cost, about half of a chart's
    drawing. So between writes the figure may change only in what its layout does not
    depend on (an image's pixels, bars under a fixed axis, a title's words but not its
    number of lines): each PNG then holds the pixels of the figure drawn anew for it
    (:func:`report_figure`). Every text is plain, as there.

    Yields
    ------
    fig : matplotlib.figure.Figure
        Constrained layout until the first write, on an Agg canvas.
    write : callable
        ``write(path)``: the PNG of the figure as it is now (written atomically).
    """
    with rc_context({"text.parse_math": False}):
        fig = new_figure(width, height)
        fig.set_dpi(DPI)

        def write(path) -> None:
            draw_png(fig, path, dpi=DPI)
            fig.set_layout_engine("none")       # the positions the layout gave stay

        yield fig, write


def label_ticks(ax, positions, labels, *, axis: str = "y", **text) -> None:
    """Tick marks and labels at `positions` (data units) on the left (``"y"``) or bottom
    (``"x"``) of `ax`, drawn as ``set_yticks(positions, labels)`` draws them, but as one
    line of tick-mark markers and one text per label, the same pixels: no axis ``Tick`` per
    label (two tick lines, a grid line, two texts and their markers, made and laid out for
    each: about 1 ms a label, half a second of a report's figures of markers). The axis
    keeps no ticks of its own.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    positions : array_like of float, shape (k,)
    labels : sequence of str, length k
    axis : {"y", "x"}
    **text
        Text properties of the labels (``fontsize``, ``rotation``, ``ha``,
        ``rotation_mode``...), over the axis' defaults.
    """
    positions = np.asarray(positions, dtype=float)
    size, pad = rcParams[f"{axis}tick.major.size"], rcParams[f"{axis}tick.major.pad"]
    offset = (size + pad) / 72                          # inches, as an outward tick's label
    if axis == "y":
        ax.set_yticks([])
        along, marker = ax.get_yaxis_transform(), TICKLEFT
        points = np.zeros_like(positions), positions
        shift = ScaledTranslation(-offset, 0, ax.figure.dpi_scale_trans)
        text = {"ha": "right", "va": "center_baseline", **text}
    else:
        ax.set_xticks([])
        along, marker = ax.get_xaxis_transform(), TICKDOWN
        points = positions, np.zeros_like(positions)
        shift = ScaledTranslation(0, -offset, ax.figure.dpi_scale_trans)
        text = {"ha": "center", "va": "top", **text}
    ax.plot(*points, linestyle="none", marker=marker, markersize=size,
            markeredgewidth=rcParams[f"{axis}tick.major.width"],
            color=rcParams[f"{axis}tick.color"], transform=along, clip_on=False)
    for x, y, label in zip(*points, labels):
        ax.text(x, y, label, transform=along + shift, **text)


class _PlainLogFormatter(LogFormatter):
    """The ticks a log axis labels by default, each labelled as a plain number ("0.7", "10")."""

    def _num_to_string(self, x, vmin, vmax):
        return f"{x:g}"


def plain_log_axis(axis) -> None:
    """Plain-number tick labels on a log `axis`: its default labels are mathtext
    (``$\\mathdefault{10^{0}}$``), which :func:`report_figure` turns off."""
    axis.set_major_formatter(_PlainLogFormatter())
    axis.set_minor_formatter(_PlainLogFormatter(labelOnlyBase=False))


def column_starts(n: int, columns: int) -> np.ndarray:
    """First sample of each of `columns` runs of consecutive samples, as even as `n` allows:
    the samples one pixel column of a picture shows, ``(columns,)`` int."""
    return np.linspace(0, n, columns, endpoint=False).astype(np.intp)


def line_envelope(x, y, columns: int):
    """The points of a long line that its picture shows, at most 4 per column: (x, y).

    The samples are cut into `columns` runs of consecutive samples (as many as the pixel
    columns the line spans, or more); each run keeps its first, lowest, highest and last
    sample, in order (M4 aggregation, Jugel et al., VLDB 2014): drawn, the line reaches
    the same extremes in every column as all of its samples, in a fraction of the time
    (the antialiased pictures differ where lines cross, as the order of the strokes
    within a column does). NaN samples (breaks in the line) are kept, every one. A line
    of at most ``4 * columns`` samples is returned as it is.

    Parameters
    ----------
    x, y : array_like of shape (T,)
        The line, `x` ascending (e.g. time).
    columns : int
        Runs, at least the pixel columns of the line's axes.

    Returns
    -------
    x, y : ndarray of shape (≤ 4 columns + NaN count,)
    """
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    n = len(y)
    if n <= 4 * columns:
        return x, y
    starts = column_starts(n, columns)
    run = np.repeat(np.arange(columns), np.diff(np.r_[starts, n]))
    # the lowest and highest finite sample of each run (a run of NaN keeps its ends only)
    finite = np.isfinite(y)
    order = np.lexsort((np.where(finite, y, 0.0), ~finite, run))   # by run, finite by value
    counts = np.bincount(run[finite], minlength=columns)
    low = order[starts]
    high = order[np.maximum(starts + counts - 1, starts)]
    keep = np.zeros(n, bool)
    keep[starts] = keep[np.r_[starts[1:] - 1, n - 1]] = True
    keep[low] = keep[high] = True
    keep |= ~finite
    return x[keep], y[keep]
