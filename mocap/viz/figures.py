"""Matplotlib figures without global state, saved atomically, fed only plain text and sane values.

Labels come from files (marker names, take names) and must reach matplotlib as
plain text: :func:`save_figure` turns mathtext off on every text of the
figure, so that a label such as ``$\\frac{a}{$`` is drawn as typed instead of
failing the figure. A figure is drawn once (:func:`draw_png`: ``savefig``
lays a constrained figure out in a draw of its own first) and its pixels
encoded by OpenCV. Values are checked by :func:`plottable` before they size
axes or figures: non-finite or absurd values (a sample at 1e30 mm) are
refused with an error naming where they are.
"""

from __future__ import annotations

import cv2
import numpy as np
from matplotlib import colormaps, rc_context
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.text import Text

from mocap.errors import InputError
from mocap.util.atomic import atomic_path

__all__ = ["MAX_PLOT_MM", "new_figure", "save_figure", "draw_png", "write_png",
           "distinct_colours", "plottable"]

#: Positions and distances beyond this many mm (1 km) are no capture: refused before plotting.
MAX_PLOT_MM = 1e6
#: Vertices of the pieces Agg strokes a long line in: a line of a few thousand vertices
#: that zigzags over the same rows (a take's noisy residuals, four points a pixel column)
#: is stroked faster in pieces of this size than in one; the pieces' joins differ from one
#: stroke in a few antialiased pixels.
_LINE_PIECE = 256
#: How FreeType renders the text: from the fonts' outlines, without their hinting (at 120
#: dpi the same legible glyphs, a shade softer): interpreting each glyph's hinting costs
#: about a tenth of a report's figure time (its heatmaps: 0.63 → 0.55 s).
_TEXT_HINTING = "no_hinting"
#: zlib level of the PNGs: the size of level 9 at a fraction of its time (charts are flat
#: colours). OpenCV's default (RLE, no row filter) makes noisy heatmaps ten times larger;
#: level 1 with the Up filter below encodes a 35,000-frame run's 20 PNGs in half the time
#: (0.19 s instead of 0.43 s), 12% larger.
_PNG_LEVEL = 6
#: OpenCV's PNG options: the zlib level, and every row filtered by its difference from the
#: row above (PNG's "Up"; OpenCV 4.12 and later let the filter be chosen). A chart's rows
#: mostly repeat the flat colours of the row above, and libpng's own choice among the five
#: filters, row by row, costs about as much as the compression: the 20 PNGs of a
#: 35,000-frame run's report encode in 0.54 s instead of 0.80 s, 1.7% larger, the same
#: pixels.
_PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, _PNG_LEVEL,
               cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_UP]


def new_figure(width: float, height: float) -> Figure:
    """A figure of `width` × `height` inches on the Agg canvas (no pyplot state)."""
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, path, *, dpi: int = 120) -> None:
    """Write `fig` as PNG to `path` (temp file + rename), every text drawn as plain text."""
    for text in fig.findobj(Text):
        text.set_parse_math(False)
    draw_png(fig, path, dpi=dpi)


def draw_png(fig: Figure, path, *, dpi: int = 120) -> None:
    """Draw `fig` once at `dpi` (layout and rendering together) and write its pixels to
    `path` as PNG, atomically; texts the draw makes (tick labels) are plain text, and long
    lines are stroked in pieces (:data:`_LINE_PIECE`), and text unhinted
    (:data:`_TEXT_HINTING`)."""
    with rc_context({"text.parse_math": False, "agg.path.chunksize": _LINE_PIECE,
                     "text.hinting": _TEXT_HINTING}):
        fig.set_dpi(dpi)
        fig.canvas.draw()
    write_png(np.asarray(fig.canvas.buffer_rgba()), path)


def write_png(image, path) -> None:
    """Write an RGB (h, w, 3) or RGBA (h, w, 4, alpha dropped) uint8 image to `path` as PNG,
    atomically."""
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] not in (3, 4):
        raise InputError(f"{path}: need a uint8 RGB or RGBA image, got {image.dtype} "
                         f"{image.shape}")
    code = cv2.COLOR_RGB2BGR if image.shape[2] == 3 else cv2.COLOR_RGBA2BGR
    ok, data = cv2.imencode(".png", cv2.cvtColor(image, code), _PNG_PARAMS)
    if not ok:
        raise InputError(f"{path}: cannot encode the image as PNG")
    with atomic_path(path) as tmp:
        tmp.write_bytes(data.tobytes())


def distinct_colours(n: int) -> list:
    """`n` well-separated colours: tab10, then Dark2, then repeating."""
    palette = list(colormaps["tab10"].colors) + list(colormaps["Dark2"].colors)
    return [palette[i % len(palette)] for i in range(n)]


def plottable(values, name: str, *, limit: float = MAX_PLOT_MM, labels=None,
              first_frame: int = 0) -> np.ndarray:
    """`values` as float64, refused if a value is infinite or beyond ±`limit` (NaN is kept).

    Parameters
    ----------
    values : array_like
        What will be plotted; ``(n_frames, n_markers, ...)`` with `labels`.
    name : str
        What the values are ("captured positions"), for the error.
    limit : float
        Largest magnitude that is plotted (default :data:`MAX_PLOT_MM`).
    labels : sequence of str, optional
        Marker names of axis 1: the error then names the marker and frame.
    first_frame : int
        Frame number of index 0 of axis 0 (with `labels`).

    Raises
    ------
    InputError
        ``"captured positions: marker 'lip' at frame 112 is 1e+30, beyond ±1e+06: not
        plotted"``.

    Examples
    --------
    >>> plottable([[1.0, np.nan]], "errors").tolist()
    [[1.0, nan]]
    >>> plottable([[[0, 0, 1e30]]], "captured positions", labels=["lip"], first_frame=112)
    Traceback (most recent call last):
    ...
    mocap.errors.InputError: captured positions: marker 'lip' at frame 112 is 1e+30, beyond \
±1e+06: not plotted
    """
    values = np.asarray(values, dtype=np.float64)
    bad = np.isinf(values) | (np.abs(np.nan_to_num(values)) > limit)
    if bad.any():
        index = tuple(int(i) for i in np.argwhere(bad)[0])
        where = (f"marker {labels[index[1]]!r} at frame {first_frame + index[0]}"
                 if labels is not None and values.ndim >= 2 and index[1] < len(labels)
                 else f"index {index}")
        raise InputError(f"{name}: {where} is {values[index]:.3g}, beyond ±{limit:.0e}: "
                         "not plotted")
    return values
