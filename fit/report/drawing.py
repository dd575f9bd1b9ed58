"""The report's matplotlib figures: drawn once, at the size the page shows them, every text
as typed (PNG).

:func:`report_figure` gives a figure to draw on and writes its pixels when the block ends
(:func:`mocap.viz.figures.draw_png`: one draw), with plain text without a pass over the
figure's artists (labels come from files: ``$\\frac{a}{$`` is drawn as typed).
"""

from __future__ import annotations

from contextlib import contextmanager

from matplotlib import rc_context
from matplotlib.ticker import LogFormatter

from mocap.viz.figures import draw_png, new_figure

__all__ = ["DPI", "PAGE_WIDTH", "PAGE_WIDTH_PX", "FIGURE_MARGIN_PX", "IMAGE_WIDTH_PX",
           "report_figure", "plain_log_axis"]

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
    with rc_context({"text.parse_math": False}):
        fig = new_figure(width, height)
        fig.set_dpi(DPI)
        yield fig
        draw_png(fig, path, dpi=DPI)


class _PlainLogFormatter(LogFormatter):
    """The ticks a log axis labels by default, each labelled as a plain number ("0.7", "10")."""

    def _num_to_string(self, x, vmin, vmax):
        return f"{x:g}"


def plain_log_axis(axis) -> None:
    """Plain-number tick labels on a log `axis`: its default labels are mathtext
    (``$\\mathdefault{10^{0}}$``), which :func:`report_figure` turns off."""
    axis.set_major_formatter(_PlainLogFormatter())
    axis.set_minor_formatter(_PlainLogFormatter(labelOnlyBase=False))
