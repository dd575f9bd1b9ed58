"""Captured (red) vs reconstructed (blue) markers at chosen frames, front and
side views with error vectors, as Figure 4 of the quasi-eigen faces paper (PNG)."""

from __future__ import annotations

import numpy as np
from matplotlib.collections import LineCollection

from fit.report.drawing import PAGE_WIDTH, report_figure
from mocap.errors import InputError
from mocap.util.validation import as_float_array, as_positions
from mocap.viz.figures import MAX_PLOT_MM, plottable

__all__ = ["view_axes", "plot_frame_views", "plottable_positions"]

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
    axes3 = view_axes(neutral, labels, markerset)
    neutral = np.asarray(neutral, dtype=float)
    centre = np.nanmean(neutral, axis=0)               # screen origin: the rest centroid
    rest = (neutral - centre) @ axes3.T
    cap = (captured[frames] - centre) @ axes3.T        # (F, M, 3) screen coordinates
    rec = cap + exaggerate * (reconstructed[frames] - captured[frames]) @ axes3.T
    every = np.concatenate([rest[None], cap, rec]).reshape(-1, 3)
    lo, hi = np.nanmin(every, axis=0) - 4, np.nanmax(every, axis=0) + 4
    span = hi - lo
    # Inches per mm: the frames' views fill the page's width, at most _SCALE; the dots' areas
    # scale with it, so that they keep their size against the face.
    scale = min(_SCALE, (PAGE_WIDTH - 1.2) / (len(frames) * (span[0] + span[2])))
    dot = (scale / _SCALE) ** 2
    scale_text = "" if exaggerate == 1 else f", error vectors ×{exaggerate:g}"
    with report_figure(path, 1.2 + scale * len(frames) * (span[0] + span[2]),
                       scale * span[1] + 1.6) as fig:
        grid = fig.subplots(1, 2 * len(frames), sharey=True,
                            width_ratios=[span[0], span[2]] * len(frames))
        for k, t in enumerate(frames):
            err = np.linalg.norm(reconstructed[t] - captured[t], axis=1)
            caption = (names[k] if names is not None
                       else f"RMS {np.sqrt(np.nanmean(err ** 2)):.2f} mm")
            for ax, h, view in ((grid[2 * k], 0, "front"), (grid[2 * k + 1], 2, "side")):
                ax.scatter(rest[:, h], rest[:, 1], s=10 * dot, color="#cccccc", zorder=1)
                segs = np.stack([cap[k][:, [h, 1]], rec[k][:, [h, 1]]], axis=1)
                ax.add_collection(LineCollection(segs, colors="black", linewidths=0.8,
                                                 zorder=2))
                ax.scatter(cap[k][:, h], cap[k][:, 1], s=28 * dot, color=CAPTURED_COLOUR,
                           zorder=3, label="captured")
                ax.scatter(rec[k][:, h], rec[k][:, 1], s=10 * dot, color=RECONSTRUCTED_COLOUR,
                           zorder=3, label="reconstructed")
                ax.set_xlim(lo[h], hi[h])
                ax.set_ylim(lo[1], hi[1])
                ax.set_aspect("equal")
                ax.tick_params(labelsize=7)
                ax.set_xlabel(f"{view} (mm)", fontsize=8)
            grid[2 * k].set_title(f"frame {numbers[k]}: {caption}", fontsize=9, loc="left")
        grid[0].set_ylabel("up (mm)", fontsize=8)
        handles, texts = grid[0].get_legend_handles_labels()
        fig.legend(handles, texts, loc="outside lower center", ncol=2, fontsize=8,
                   frameon=False, markerscale=1 / np.sqrt(dot))
        fig.suptitle(title or f"Captured (red) vs reconstructed (blue){scale_text}; grey: "
                              "rest pose. Front: subject's left on the right; side: face to "
                              "the right", fontsize=10)


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
