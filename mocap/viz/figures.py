"""Matplotlib figures without global state, saved atomically."""

from __future__ import annotations

from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from mocap.util.atomic import atomic_path

__all__ = ["new_figure", "save_figure", "distinct_colours"]


def new_figure(width: float, height: float) -> Figure:
    """A figure of `width` × `height` inches on the Agg canvas (no pyplot state)."""
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, path, *, dpi: int = 120) -> None:
    """Write `fig` as PNG to `path` (temp file + rename)."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")


def distinct_colours(n: int) -> list:
    """`n` well-separated colours: tab10, then Dark2, then repeating."""
    palette = list(colormaps["tab10"].colors) + list(colormaps["Dark2"].colors)
    return [palette[i % len(palette)] for i in range(n)]
