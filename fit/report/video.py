"""MP4 overlay of captured (red) vs reconstructed (blue) markers over a take,
front view with error vectors, drawn with OpenCV."""

from __future__ import annotations

import os

import cv2
import numpy as np

from fit.report.views import view_axes
from mocap.errors import InputError
from mocap.util.atomic import atomic_path
from mocap.util.validation import as_int, as_positions, as_positive_float
from mocap.viz.figures import plottable

__all__ = ["write_overlay_video"]

# BGR colours.
_RED = (40, 39, 214)
_BLUE = (214, 95, 31)
_GREY = (205, 205, 205)
_BLACK = (0, 0, 0)


def _project(points: np.ndarray, axes: np.ndarray, scale: float, shift: np.ndarray) -> np.ndarray:
    """(..., 3) mm to pixel coordinates (..., 2), x right, y down, in 1/16 pixel."""
    screen = points @ axes[:2].T
    px = (screen * [scale, -scale] + shift) * 16
    return np.nan_to_num(px, nan=-1e6).round().astype(np.int32)


def write_overlay_video(captured, reconstructed, path, *, neutral, rate: float,
                        labels=None, markerset=None, fps: float | None = None,
                        step: int = 1, size: tuple = (512, 512), exaggerate: float = 1.0,
                        first_frame: int = 0, radius: int = 5) -> int:
    """Write an MP4 of the take: captured and reconstructed markers, error vectors,
    frame counter and per-frame RMS.

    Parameters
    ----------
    captured, reconstructed : array_like, shape (T, M, 3), mm
        Head-stabilized positions, NaN where missing (not drawn, not counted).
    path : str or os.PathLike
        Output ``.mp4`` (written atomically; codec ``mp4v``).
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
    step : int
        Draw every `step`-th frame.
    size : (int, int)
        Width and height, pixels.
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
        Bad shapes or options, or OpenCV cannot open a writer for `path`.
    """
    captured = plottable(as_positions(captured, "captured"), "captured positions",
                         labels=labels, first_frame=first_frame)
    reconstructed = plottable(as_positions(reconstructed, "reconstructed"),
                              "reconstructed positions", labels=labels,
                              first_frame=first_frame)
    if reconstructed.shape != captured.shape:
        raise InputError(f"reconstructed must have the shape of captured {captured.shape}, "
                         f"got {reconstructed.shape}")
    rate = as_positive_float(rate, "rate")
    step = as_int(step, "step", minimum=1)
    fps = rate / step if fps is None else as_positive_float(fps, "fps")
    width, height = (as_int(v, "size", minimum=64) for v in size)
    labels = tuple(str(i) for i in range(captured.shape[1])) if labels is None else labels
    axes = view_axes(neutral, labels, markerset)

    cap = captured[::step]
    shown = cap + exaggerate * (reconstructed[::step] - cap)
    err = np.linalg.norm(reconstructed[::step] - cap, axis=2)
    counted = np.isfinite(err)
    rms = np.sqrt(np.where(counted, err ** 2, 0).sum(axis=1) / np.maximum(counted.sum(axis=1), 1))
    rms[~counted.any(axis=1)] = np.nan
    # Fit the rest pose and everything drawn into the frame, with a margin.
    screen = np.concatenate([cap.reshape(-1, 3), shown.reshape(-1, 3),
                             np.asarray(neutral, float)]) @ axes[:2].T
    lo, hi = np.nanmin(screen, axis=0), np.nanmax(screen, axis=0)
    top, bottom = 40, 50                                # room for the texts
    scale = min((width - 40) / max(hi[0] - lo[0], 1e-9),
                (height - top - bottom) / max(hi[1] - lo[1], 1e-9))
    centre = (lo + hi) / 2
    shift = np.array([width / 2 - scale * centre[0],
                      top + (height - top - bottom) / 2 + scale * centre[1]])
    cap_px = _project(cap, axes, scale, shift)              # (F, M, 2), all frames at once
    rec_px = _project(shown, axes, scale, shift)
    seen_cap = np.isfinite(cap).all(axis=2)
    seen_rec = np.isfinite(shown).all(axis=2)
    seen_both = seen_cap & seen_rec

    background = np.full((height, width, 3), 255, np.uint8)
    for p in _project(np.asarray(neutral, float), axes, scale, shift):
        cv2.circle(background, (int(p[0]), int(p[1])), 16 * radius, _GREY, -1, cv2.LINE_AA, 4)
    bar = int(round(10 * scale))
    cv2.line(background, (20, height - 15), (20 + bar, height - 15), _BLACK, 2)
    cv2.putText(background, "10 mm", (25 + bar, height - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                _BLACK, 1, cv2.LINE_AA)
    legend = "red: captured  blue: reconstructed  (viewer's right = subject's left)"
    if exaggerate != 1:
        legend += f"  errors x{exaggerate:g}"
    cv2.putText(background, legend, (10, height - 35), cv2.FONT_HERSHEY_SIMPLEX, 0.4, _BLACK,
                1, cv2.LINE_AA)

    r16 = 16 * radius                                  # radius in 1/16 pixel (shift 4)
    r16_rec = max(16, round(0.6 * r16))                # smaller: a red ring stays visible
    img = np.empty_like(background)
    index = np.arange(captured.shape[0])[::step]
    texts = [f"frame {i + first_frame}  t = {i / rate:.2f} s  RMS {r:.2f} mm"
             for i, r in zip(index, rms)]
    with atomic_path(path) as tmp:
        video_tmp = tmp.with_name(tmp.name + ".mp4")   # OpenCV picks the container by suffix
        try:
            writer = cv2.VideoWriter(os.fspath(video_tmp), cv2.VideoWriter_fourcc(*"mp4v"),
                                     fps, (width, height))
            if not writer.isOpened():
                raise InputError(f"{path}: cannot write: OpenCV has no mp4v writer for it")
            try:
                for k in range(len(cap)):
                    np.copyto(img, background)
                    lines = np.stack([cap_px[k], rec_px[k]], axis=1)[seen_both[k]]
                    cv2.polylines(img, list(lines), False, _BLACK, 1, cv2.LINE_AA, 4)
                    for p in cap_px[k][seen_cap[k]]:
                        cv2.circle(img, (int(p[0]), int(p[1])), r16, _RED, -1, cv2.LINE_AA, 4)
                    for p in rec_px[k][seen_rec[k]]:
                        cv2.circle(img, (int(p[0]), int(p[1])), r16_rec, _BLUE, -1, cv2.LINE_AA,
                                   4)
                    cv2.putText(img, texts[k], (10, 25), cv2.FONT_HERSHEY_SIMPLEX, 0.6, _BLACK,
                                1, cv2.LINE_AA)
                    writer.write(img)
            finally:
                writer.release()
            os.replace(video_tmp, tmp)
        finally:
            if video_tmp.exists():
                video_tmp.unlink()
    return len(cap)
