"""Captured (red) vs reconstructed (blue) markers at chosen frames, front and
side views with error vectors, as Figure 4 of the quasi-eigen faces paper (PNG)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from matplotlib.collections import LineCollection

from fit.report.drawing import PAGE_WIDTH, report_figures
from mocap.errors import InputError
from mocap.util.validation import as_float_array, as_positions
from mocap.viz.figures import MAX_PLOT_MM, plottable

__all__ = ["view_axes", "FrameViews", "plot_frame_views", "plot_views_of_bases",
           "plottable_positions"]

#: Inches per mm of the views at most (a few frames of a small face).
_SCALE = 0.028
CAPTURED_COLOUR = "#d62728"
RECONSTRUCTED_COLOUR = "#1f5fd6"


def view_axes(neutral, labels, markerset=None) -> np.ndarray:
    """Screen axes of the front view: rows right, up, depth (out of the face).

    Parameters
    ----------
    neutral : array_like, shape (M, 3), mm
        Rest positions of the markers named by `labels` (NaN rows ignored).
    labels : sequence of str
    markerset : mocap.markerset.MarkerSet, optional
        Its landmarks orient the view (the subject's left on the viewer's
        right); without it, or if a landmark is absent, the principal axes.

    Returns
    -------
    ndarray, shape (3, 3)
        Orthonormal rows (right, up, depth); ``p @ axes.T`` gives screen
        coordinates, mm.
    """
    neutral = as_float_array(neutral, "neutral", shape=(len(labels), 3))
    labels = list(labels)
    face = [m for m in (markerset.face_markers if markerset else ()) if m in labels]
    if markerset is not None and face:
        points = neutral[[labels.index(m) for m in face]]
        # _front_view_axes reads landmarks by position in markerset.face_markers.
        full = np.full((len(markerset.face_markers), 3), np.nan)
        full[[markerset.face_markers.index(m) for m in face]] = points
        right, up = _front_view_axes(full, markerset)
        if np.isfinite(right).all() and np.isfinite(up).all():
            return np.array([right, up, np.cross(right, up)])
    finite = neutral[np.isfinite(neutral).all(axis=1)]
    right, up = _front_view_axes(finite, _NoLandmarks)
    return np.array([right, up, np.cross(right, up)])


def _front_view_axes(points: np.ndarray, markerset) -> tuple[np.ndarray, np.ndarray]:
    """Screen axes (right, up) of a front view of face markers (F, 3).

    With landmarks: the subject's left is the direction from right-side to
    left-side landmarks, up from chin / lower lip to the brows, made orthogonal.
    Without: the principal axes of the markers (largest spread up, towards
    world +z). The subject's left appears on the viewer's right.
    """
    labels = markerset.face_markers
    lm = markerset.landmarks

    def mean_of(names):
        idx = [labels.index(lm[n]) for n in names if n in lm and lm[n] in labels]
        return points[idx].mean(axis=0) if idx else None

    left = mean_of([n for n in lm if n.endswith("_left")])
    right = mean_of([n for n in lm if n.endswith("_right")])
    top = mean_of(["brow_inner_left", "brow_inner_right", "nose_bridge", "forehead"])
    bottom = mean_of(["chin", "lower_lip_bottom"])
    if all(v is not None for v in (left, right, top, bottom)):
        lateral = left - right
        lateral /= np.linalg.norm(lateral)
        up = top - bottom
        up -= (up @ lateral) * lateral
        return lateral, up / np.linalg.norm(up)
    _, _, vt = np.linalg.svd(points - points.mean(axis=0), full_matrices=False)
    up = vt[0] if vt[0][2] >= 0 else -vt[0]
    return vt[1], up


class _NoLandmarks:
    """A stand-in marker set without landmarks: principal axes only."""

    face_markers: tuple = ()
    landmarks: dict = {}


@dataclass(frozen=True, eq=False)
class FrameViews:
    """What one figure of views shows: some frames of a take, captured and reconstructed.

    Attributes
    ----------
    captured, reconstructed : ndarray of shape (F, M, 3), mm
        Head-stabilized positions at the F frames, NaN where missing (not drawn).
    numbers : ndarray of int, shape (F,)
        The frames' numbers, in the panels' titles.
    captions : sequence of str, optional
        A caption per frame; default its RMS error.
    title : str, optional
        The figure's; default what the colours mean.
    """

    captured: np.ndarray
    reconstructed: np.ndarray
    numbers: np.ndarray
    captions: tuple | None = None
    title: str | None = None


def plot_frame_views(captured, reconstructed, frames, path, *, neutral, labels=None,
                     markerset=None, exaggerate: float = 1.0, first_frame: int = 0,
                     names=None, numbers=None, title: str | None = None) -> None:
    """Front and side views of captured and reconstructed markers at some frames (PNG).

    Parameters
    ----------
    captured, reconstructed : array_like, shape (T, M, 3), mm
        Head-stabilized positions, NaN where missing (those markers are not drawn).
    frames : sequence of int
        Frame indices (0-based), one row of views each.
    path : str or os.PathLike
    neutral : array_like, shape (M, 3), mm
        Rest positions; orient the views (see :func:`view_axes`) and are drawn
        in light grey.
    labels : sequence of str, optional
        Marker names (needed with `markerset`).
    markerset : mocap.markerset.MarkerSet, optional
    exaggerate : float
        Error vectors drawn this many times longer (the blue dot at
        captured + exaggerate·(reconstructed − captured)); said in the title.
    first_frame : int
        Added to the indices in the panel titles (the take's frame numbers).
    names : sequence of str, optional
        A caption per frame (e.g. "RMS 2.1 mm").
    numbers : sequence of int, optional
        The frame number in each panel's title (default ``frames + first_frame``): when
        `captured` holds only the frames shown.
    """
    captured = plottable_positions(captured, "captured", labels=labels, first_frame=first_frame)
    reconstructed = plottable_positions(reconstructed, "reconstructed", labels=labels,
                                        first_frame=first_frame)
    if reconstructed.shape != captured.shape:
        raise InputError(f"reconstructed must have the shape of captured {captured.shape}, "
                         f"got {reconstructed.shape}")
    frames = np.atleast_1d(np.asarray(frames, dtype=np.intp))
    if frames.size == 0 or frames.min() < 0 or frames.max() >= captured.shape[0]:
        raise InputError(f"frames must be 1 or more indices in [0, {captured.shape[0]}), "
                         f"got {frames.tolist()}")
    numbers = frames + first_frame if numbers is None else np.asarray(numbers, dtype=np.intp)
    if numbers.shape != frames.shape:
        raise InputError(f"numbers must give one frame number per frame ({frames.size}), "
                         f"got {numbers.shape}")
    labels = tuple(str(i) for i in range(captured.shape[1])) if labels is None else labels
    shown = FrameViews(captured[frames], reconstructed[frames], numbers,
                       None if names is None else tuple(names), title)
    plot_views_of_bases({"": shown}, {"": path}, neutral=neutral, labels=labels,
                        markerset=markerset, exaggerate=exaggerate)


def plot_views_of_bases(views: Mapping, paths: Mapping, *, neutral, labels=None,
                        markerset=None, exaggerate: float = 1.0) -> None:
    """:func:`plot_frame_views` of several reconstructions of one take, each at its own
    frames, on one scale: one PNG each, the figures of as many frames laid out once
    (:func:`~fit.report.drawing.report_figures`).

    Parameters
    ----------
    views : mapping of name to FrameViews
        Of the markers of `neutral`.
    paths : mapping of name to str or os.PathLike
        The PNG of each.
    neutral, labels, markerset, exaggerate
        As for :func:`plot_frame_views`.

    Raises
    ------
    InputError
        Views of other markers than `neutral`'s, captured and reconstructed of other
        shapes, a number per frame missing, values beyond any capture.
    """
    labels = tuple(str(i) for i in range(len(neutral))) if labels is None else labels
    axes3 = view_axes(neutral, labels, markerset)
    neutral = np.asarray(neutral, dtype=float)
    centre = np.nanmean(neutral, axis=0)               # screen origin: the rest centroid
    rest = (neutral - centre) @ axes3.T
    screen = {name: _on_screen(view, name, labels, centre, axes3, exaggerate)
              for name, view in views.items()}
    every = np.concatenate([rest[None], *(np.concatenate(s) for s in screen.values())])
    every = every.reshape(-1, 3)
    lo, hi = np.nanmin(every, axis=0) - 4, np.nanmax(every, axis=0) + 4
    groups = {}     # figures of as many frames, and titles of as many lines, share a layout
    for name, view in views.items():
        lines = [text.count("\n") for text in (view.title or "", *(view.captions or ()))]
        groups.setdefault((len(view.numbers), *lines), []).append(name)
    for names in groups.values():
        _draw_views({name: (views[name], *screen[name]) for name in names}, paths, rest, lo,
                    hi, exaggerate)


def _on_screen(view: FrameViews, name: str, labels, centre, axes3, exaggerate):
    """The screen coordinates (F, M, 3) of a view's captured markers and of its
    reconstructed ones (the error vectors exaggerated), checked."""
    captured = plottable_positions(view.captured, "captured", labels=labels, first_frame=0)
    reconstructed = plottable_positions(view.reconstructed, "reconstructed", labels=labels,
                                        first_frame=0)
    shape = (len(view.numbers), len(labels), 3)
    if captured.shape != shape or reconstructed.shape != shape:
        raise InputError(f"views {name!r}: captured and reconstructed must have shape "
                         f"{shape} (a frame number each), got {captured.shape} and "
                         f"{reconstructed.shape}")
    cap = (captured - centre) @ axes3.T
    return cap, cap + exaggerate * (reconstructed - captured) @ axes3.T


def _draw_views(views: Mapping, paths: Mapping, rest, lo, hi, exaggerate) -> None:
    """Views of frames, as many in each, on the axes extents `lo` to `hi` (screen mm): the
    figure laid out for the first, its markers, errors and titles replaced for the others.
    `views` maps a name to (FrameViews, captured, reconstructed on screen)."""
    first = next(iter(views.values()))[0]
    n_frames = len(first.numbers)
    span = hi - lo
    # Inches per mm: the frames' views fill the page's width, at most _SCALE; the dots' areas
    # scale with it, so that they keep their size against the face.
    scale = min(_SCALE, (PAGE_WIDTH - 1.2) / (n_frames * (span[0] + span[2])))
    dot = (scale / _SCALE) ** 2
    scale_text = "" if exaggerate == 1 else f", error vectors ×{exaggerate:g}"
    with report_figures(1.2 + scale * n_frames * (span[0] + span[2]),
                        scale * span[1] + 1.6) as (fig, write):
        grid = fig.subplots(1, 2 * n_frames, sharey=True,
                            width_ratios=[span[0], span[2]] * n_frames)
        for ax, h, view in zip(grid, (0, 2) * n_frames, ("front", "side") * n_frames):
            ax.scatter(rest[:, h], rest[:, 1], s=10 * dot, color="#cccccc", zorder=1)
            ax.set_xlim(lo[h], hi[h])
            ax.set_ylim(lo[1], hi[1])
            ax.set_aspect("equal")
            ax.tick_params(labelsize=7)
            ax.set_xlabel(f"{view} (mm)", fontsize=8)
        grid[0].set_ylabel("up (mm)", fontsize=8)
        drawn, heading = [], None       # the markers and errors of the view drawn last
        for name, (shown, cap, rec) in views.items():
            for artist in drawn:
                artist.remove()
            drawn = []
            for k in range(n_frames):
                for ax, h in ((grid[2 * k], 0), (grid[2 * k + 1], 2)):
                    segs = np.stack([cap[k][:, [h, 1]], rec[k][:, [h, 1]]], axis=1)
                    drawn += [
                        ax.add_collection(LineCollection(segs, colors="black",
                                                         linewidths=0.8, zorder=2)),
                        ax.scatter(cap[k][:, h], cap[k][:, 1], s=28 * dot,
                                   color=CAPTURED_COLOUR, zorder=3, label="captured"),
                        ax.scatter(rec[k][:, h], rec[k][:, 1], s=10 * dot,
                                   color=RECONSTRUCTED_COLOUR, zorder=3, label="reconstructed")]
                err = np.linalg.norm(shown.reconstructed[k] - shown.captured[k], axis=1)
                caption = (shown.captions[k] if shown.captions is not None
                           else f"RMS {np.sqrt(np.nanmean(err ** 2)):.2f} mm")
                grid[2 * k].set_title(f"frame {shown.numbers[k]}: {caption}", fontsize=9,
                                      loc="left")
            title = shown.title or (f"Captured (red) vs reconstructed (blue){scale_text}; "
                                    "grey: rest pose. Front: subject's left on the right; "
                                    "side: face to the right")
            if heading is None:
                handles, texts = grid[0].get_legend_handles_labels()
                fig.legend(handles, texts, loc="outside lower center", ncol=2, fontsize=8,
                           frameon=False, markerscale=1 / np.sqrt(dot))
                heading = fig.suptitle(title, fontsize=10)
            else:                       # (suptitle again would move it from its laid-out place)
                heading.set_text(title)
            write(paths[name])


def plottable_positions(values, name: str, *, labels, first_frame: int) -> np.ndarray:
    """`values` (T, M, 3) as float64 (no copy when they already are), refused as
    :func:`mocap.viz.figures.plottable` refuses them; one pass for the extremes instead of
    its pass over every sample, which only runs (to name the sample) when one is out of range."""
    values = as_positions(values, name, copy=False)
    top = max(np.fmax.reduce(values, axis=None, initial=-np.inf),
              -np.fmin.reduce(values, axis=None, initial=np.inf))
    if top > MAX_PLOT_MM:               # NaN samples are kept, as plottable keeps them
        plottable(values, f"{name} positions", labels=labels, first_frame=first_frame)
    return values
