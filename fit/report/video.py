"""Overlay video of captured (red) vs reconstructed (blue) markers over a take,
front view with error vectors, drawn with OpenCV and encoded as VP9 in WebM
(:class:`mocap.viz.webm.WebmWriter`), which browsers play (Chromium, Firefox; the
report embeds it in a ``<video>``)."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from typing import Mapping

import cv2
import numpy as np

from fit.report.views import view_axes
from mocap.errors import InputError
from mocap.util.atomic import atomic_path
from mocap.util.validation import as_int, as_positions, as_positive_float
from mocap.viz.figures import plottable
from mocap.viz.webm import WebmWriter

__all__ = ["VIDEO_SUFFIX", "VIDEO_MIME", "MAX_AUTO_FPS", "video_step", "write_overlay_video",
           "overlay_frames", "OverlayFrames"]

#: The container of the overlay videos, and its MIME type with the codec.
VIDEO_SUFFIX = ".webm"
VIDEO_MIME = 'video/webm; codecs="vp9"'
#: Frames a second of a real-time video that ``step = "auto"`` stays under: what a
#: display shows (a browser plays a faster video by skipping frames).
MAX_AUTO_FPS = 60.0

# BGR colours.
_RED = (40, 39, 214)
_BLUE = (214, 95, 31)
_GREY = (205, 205, 205)
_BLACK = (0, 0, 0)


def video_step(step, rate: float) -> int:
    """Frames of a take per video frame: `step` (int >= 1), or for ``"auto"`` the
    smallest that keeps a real-time video of a take at `rate` Hz at most
    :data:`MAX_AUTO_FPS` frames a second (1 up to 60 Hz, 5 at 276 Hz).

    Examples
    --------
    >>> video_step("auto", 276.0), video_step("auto", 60.0), video_step(3, 276.0)
    (5, 1, 3)
    """
    if step == "auto":      # a rate a rounding above a multiple of 60 Hz counts as it
        return max(1, math.ceil(as_positive_float(rate, "rate") / MAX_AUTO_FPS - 1e-9))
    return as_int(step, "step", minimum=1)


def _project(points: np.ndarray, axes: np.ndarray, scale: float, shift: np.ndarray) -> np.ndarray:
    """(..., 3) mm to pixel coordinates (..., 2), x right, y down, in 1/16 pixel."""
    screen = points @ axes[:2].T
    px = (screen * [scale, -scale] + shift) * 16
    return np.nan_to_num(px, nan=-1e6).round().astype(np.int32)


def write_overlay_video(captured, reconstructed, path, *, neutral, rate: float,
                        labels=None, markerset=None, fps: float | None = None,
                        step: int = 1, size: tuple = (288, 320), exaggerate: float = 1.0,
                        first_frame: int = 0, radius: int = 4) -> int:
    """Write a VP9 WebM video of the take: captured and reconstructed markers, error
    vectors, the capture's frame number and the per-frame RMS, one panel per basis.

    Parameters
    ----------
    captured : array_like, shape (T, M, 3), mm
        Head-stabilized positions, NaN where missing (not drawn, not counted).
    reconstructed : array_like of shape (T, M, 3), or mapping of name to such arrays, mm
        One reconstruction, or one per basis: a panel each, side by side, on one
        scale, each with its name and RMS (one video to encode, one to watch).
    path : str or os.PathLike
        Output ``.webm`` (written atomically; VP9).
    neutral : array_like, shape (M, 3), mm
        Rest positions, drawn in grey; orient the front view (:func:`views.view_axes`).
    rate : float
        Frame rate of the take, Hz (for the time stamp).
    labels : sequence of str, optional
        Marker names, needed with `markerset`.
    markerset : mocap.markerset.MarkerSet, optional
        Landmarks orient the view: the subject's left on the viewer's right.
    fps : float, optional
        Frame rate of the video; default ``rate / step`` (real time).
    step : int or "auto"
        Draw every `step`-th frame; "auto": :func:`video_step`.
    size : (int, int)
        Width and height of one panel, pixels (VP9 encoding time grows with them).
    exaggerate : float
        Error vectors drawn this many times longer (said on screen).
    first_frame : int
        Added to the frame index in the counter (the take's frame numbers).
    radius : int
        Radius of the captured (red) dots, pixels; reconstructed (blue) dots
        are drawn on top at 0.6 times it, so a small error leaves a red ring.

    Returns
    -------
    int
        Frames written.

    Raises
    ------
    InputError
        Bad shapes or options, a suffix other than ``.webm``, or no VP9 (WebM)
        encoder can write `path`.
    """
    if os.path.splitext(os.fspath(path))[1].lower() != VIDEO_SUFFIX:
        raise InputError(f"{path}: the overlay video is VP9 in WebM: name it *{VIDEO_SUFFIX}")
    return overlay_frames(captured, reconstructed, neutral=neutral, rate=rate, labels=labels,
                          markerset=markerset, fps=fps, step=step, size=size,
                          exaggerate=exaggerate, first_frame=first_frame,
                          radius=radius).write(path)


@dataclass(frozen=True)
class OverlayFrames:
    """The frames of an overlay video as they are drawn, without the drawing: what
    :func:`overlay_frames` laid out (every panel on one scale), small enough to send to
    another process (pixel coordinates, not positions). A slice of the frames,
    ``frames[a:b]``, is a part of the video (:meth:`write` of each part, then
    :func:`mocap.viz.webm.join_webm`, is the video in parts).

    Attributes
    ----------
    background : ndarray of shape (height, width · panels, 3), uint8
        The rest pose, scale bar and legend of every panel (BGR).
    captured : ndarray of shape (F, M, 2), int32
        The captured markers' centres, 1/16 pixel, in the first panel.
    seen : ndarray of shape (F, M), bool
        Where a captured marker is drawn.
    panels : tuple of (name, centres (F, M, 2) int32, seen (F, M) bool, rms (F,))
        Each panel's reconstructed markers (its own pixel coordinates) and RMS, mm.
    heads : tuple of str
        Each frame's counter (the capture's frame number and time).
    width : int
        One panel's width, pixels.
    radius : int
        The captured dots' radius, pixels.
    fps : float
        Frames a second of the video.
    start : int
        The first frame's index in the whole video (its time stamp).
    """

    background: np.ndarray
    captured: np.ndarray
    seen: np.ndarray
    panels: tuple
    heads: tuple
    width: int
    radius: int
    fps: float
    start: int = 0

    def __len__(self) -> int:
        return len(self.captured)

    def __getitem__(self, part: slice) -> OverlayFrames:
        """The frames of `part` (a slice of steps 1), a part of the video."""
        first, stop, stride = part.indices(len(self))
        if stride != 1:
            raise ValueError("a part of a video is a run of its frames")
        rows = slice(first, stop)
        return replace(self, captured=self.captured[rows], seen=self.seen[rows],
                       panels=tuple((name, px[rows], seen[rows], rms[rows])
                                    for name, px, seen, rms in self.panels),
                       heads=self.heads[rows], start=self.start + first)

    def write(self, path, *, threads: int = 0) -> int:
        """Draw the frames and write them as a VP9 WebM to `path` (atomically), their time
        stamps from :attr:`start`, encoded by `threads` threads (0: FFmpeg's choice;
        :class:`mocap.viz.webm.WebmWriter`); returns how many."""
        r16 = 16 * self.radius                              # radius in 1/16 pixel (shift 4)
        r16_rec = max(16, round(0.6 * r16))                 # smaller: a red ring stays visible
        offsets = [np.array([k * self.width * 16, 0]) for k in range(len(self.panels))]
        img = np.empty_like(self.background)
        with atomic_path(path) as tmp, WebmWriter(tmp, self.fps, self.background.shape[1::-1],
                                                  start=self.start, threads=threads) as video:
            for k in range(len(self)):
                np.copyto(img, self.background)
                dots = self.captured[k][self.seen[k]]
                for (name, px, seen_rec, rms), shift16 in zip(self.panels, offsets):
                    seen = self.seen[k] & seen_rec[k]
                    lines = np.stack([self.captured[k] + shift16, px[k] + shift16],
                                     axis=1)[seen]
                    cv2.polylines(img, list(lines), False, _BLACK, 1, cv2.LINE_AA, 4)
                    # the centres as Python ints, for OpenCV's point arguments
                    for x, y in (dots + shift16).tolist():
                        cv2.circle(img, (x, y), r16, _RED, -1, cv2.LINE_AA, 4)
                    for x, y in (px[k][seen_rec[k]] + shift16).tolist():
                        cv2.circle(img, (x, y), r16_rec, _BLUE, -1, cv2.LINE_AA, 4)
                    title = (f"{name}: RMS {rms[k]:.2f} mm" if name
                             else f"RMS {rms[k]:.2f} mm")
                    cv2.putText(img, title, (shift16[0] // 16 + 10, 38),
                                cv2.FONT_HERSHEY_SIMPLEX, 0.5, _BLACK, 1, cv2.LINE_AA)
                cv2.putText(img, self.heads[k], (10, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                            _BLACK, 1, cv2.LINE_AA)
                video.write(img)
        return len(self)


def overlay_frames(captured, reconstructed, *, neutral, rate: float, labels=None,
                   markerset=None, fps: float | None = None, step: int = 1,
                   size: tuple = (288, 320), exaggerate: float = 1.0, first_frame: int = 0,
                   radius: int = 4) -> OverlayFrames:
    """The frames of :func:`write_overlay_video` (its parameters but the path), laid out.

    Raises
    ------
    InputError
        Bad shapes or options.
    """
    captured = plottable(as_positions(captured, "captured"), "captured positions",
                         labels=labels, first_frame=first_frame)
    panels = dict(reconstructed) if isinstance(reconstructed, Mapping) else {"": reconstructed}
    if not panels:
        raise InputError("reconstructed is empty: give at least one reconstruction")
    for name in panels:
        panels[name] = plottable(as_positions(panels[name], "reconstructed"),
                                 f"reconstructed positions {name}".rstrip(), labels=labels,
                                 first_frame=first_frame)
        if panels[name].shape != captured.shape:
            raise InputError(f"reconstructed must have the shape of captured {captured.shape}, "
                             f"got {panels[name].shape}")
    rate = as_positive_float(rate, "rate")
    step = video_step(step, rate)
    fps = rate / step if fps is None else as_positive_float(fps, "fps")
    width, height = (as_int(v, "size", minimum=64) for v in size)
    labels = tuple(str(i) for i in range(captured.shape[1])) if labels is None else labels
    axes = view_axes(neutral, labels, markerset)
    neutral = np.asarray(neutral, float)

    cap = captured[::step]
    shown, rms = {}, {}
    for name, rec in panels.items():
        shown[name] = cap + exaggerate * (rec[::step] - cap)
        err = np.linalg.norm(rec[::step] - cap, axis=2)
        counted = np.isfinite(err)
        rms[name] = np.sqrt(np.where(counted, err ** 2, 0).sum(axis=1)
                            / np.maximum(counted.sum(axis=1), 1))
        rms[name][~counted.any(axis=1)] = np.nan
    # One scale for every panel: the rest pose and everything drawn fit, with a margin.
    screen = np.concatenate([cap.reshape(-1, 3), *(v.reshape(-1, 3) for v in shown.values()),
                             neutral]) @ axes[:2].T
    lo, hi = np.nanmin(screen, axis=0), np.nanmax(screen, axis=0)
    top, bottom = 44, 34                                # room for the texts
    scale = min((width - 20) / max(hi[0] - lo[0], 1e-9),
                (height - top - bottom) / max(hi[1] - lo[1], 1e-9))
    centre = (lo + hi) / 2
    shift = np.array([width / 2 - scale * centre[0],
                      top + (height - top - bottom) / 2 + scale * centre[1]])

    panel = np.full((height, width, 3), 255, np.uint8)
    for p in _project(neutral, axes, scale, shift):
        cv2.circle(panel, (int(p[0]), int(p[1])), 16 * radius, _GREY, -1, cv2.LINE_AA, 4)
    bar = int(round(10 * scale))
    cv2.line(panel, (10, height - 12), (10 + bar, height - 12), _BLACK, 2)
    cv2.putText(panel, "10 mm", (15 + bar, height - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                _BLACK, 1, cv2.LINE_AA)
    background = np.concatenate([panel] * len(panels), axis=1)
    legend = "red: captured  blue: reconstructed  (viewer's right = subject's left)" \
        + (f"  errors x{exaggerate:g}" if exaggerate != 1 else "")
    if len(panels) == 1:
        cv2.putText(background, legend, (10, height - 24), cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                    _BLACK, 1, cv2.LINE_AA)
    else:                        # the scale bar in the first panel, the legend beside it
        background[height - 30:, width:] = 255
        cv2.putText(background, legend, (width + 10, height - 12), cv2.FONT_HERSHEY_SIMPLEX,
                    0.4, _BLACK, 1, cv2.LINE_AA)
    index = np.arange(captured.shape[0])[::step]
    return OverlayFrames(
        background=background, captured=_project(cap, axes, scale, shift),
        seen=np.isfinite(cap).all(axis=2),
        panels=tuple((name, _project(v, axes, scale, shift), np.isfinite(v).all(axis=2),
                      rms[name]) for name, v in shown.items()),
        heads=tuple(f"frame {i + first_frame}  t = {i / rate:.2f} s" for i in index),
        width=width, radius=radius, fps=fps)
