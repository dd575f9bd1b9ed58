"""Benchmark: the report's overlay video, VP9 WebM (what browsers play) against mp4v.

The report used to write one mp4v MP4 per basis (512 × 512, which Chromium cannot
play); it now writes one VP9 WebM with a panel per basis (3 × 288 × 320). Timed
side by side on the demo take (20 s at 120 Hz, every 4th frame as the demo's
run.toml draws it, reconstructions = the capture plus 0.3 mm noise):

* ours: :func:`fit.report.video.write_overlay_video` with three panels, encoded by
  PyAV's libvpx-vp9 in real-time mode (:class:`mocap.viz.webm.WebmWriter`, on a thread
  of its own while the frames are drawn);
* ours as the report writes it: in parts, one for each of a figure queue's helpers
  (forked, as ``mocap2mesh`` forks them; one a spare core) and one for this process,
  joined (:func:`mocap.viz.webm.join_webm`);
* the same video encoded by OpenCV's VP9 writer (libvpx's default mode, which
  OpenCV does not let one change: the encoder without PyAV);
* baseline: the same number of frames encoded with OpenCV's mp4v at the old
  size, three times (the old per-basis videos), frames drawn the same way;
* VP9 one panel per video, three times (what per-basis WebM videos would cost).

Usage: ``python bench/bench_report_video.py``. Timings under load are noisy.
"""

from __future__ import annotations

import os
import time
from functools import partial
from pathlib import Path
from unittest import mock

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from _common import scratch_directory  # noqa: E402

import mocap  # noqa: E402
from fit.demo import make_demo_session  # noqa: E402
from fit.report import _queue_video, video  # noqa: E402
from fit.report.figure_queue import FigureQueue  # noqa: E402
from fit.report.forked_helpers import start_fork_server  # noqa: E402
from fit.report.video import write_overlay_video  # noqa: E402
from mocap.markerset import load_markerset  # noqa: E402
from mocap.stabilize import stabilize  # noqa: E402
from mocap.viz.webm import WebmWriter, join_webm  # noqa: E402

STEP = 4


def mp4v_baseline(n_frames: int, size: tuple, path: Path) -> None:
    """n_frames of markers drawn on white, encoded with mp4v (the old writer's codec)."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, size)
    rng = np.random.default_rng(0)
    points = rng.uniform(40, min(size) - 40, (60, 2)).astype(int)
    for k in range(n_frames):
        image = np.full((size[1], size[0], 3), 255, np.uint8)
        for p in points + k % 7:
            cv2.circle(image, (int(p[0]), int(p[1])), 5, (40, 39, 214), -1, cv2.LINE_AA)
        cv2.putText(image, f"frame {k}", (10, 25), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1,
                    cv2.LINE_AA)
        writer.write(image)
    writer.release()


def main() -> None:
    start_fork_server()             # as the command: helpers forked, not fresh interpreters
    work = scratch_directory("bench-video-")
    session = make_demo_session(work / "session", seconds=20.0)
    markerset = load_markerset(session.paths["markerset"])
    face = stabilize(mocap.read(session.paths["capture"]), markerset.head).take
    face = face.select(markerset.face_markers)
    positions = np.nan_to_num(face.positions, nan=np.nanmean(face.positions))
    rng = np.random.default_rng(1)
    recs = {b: positions + rng.normal(0, 0.3, positions.shape) for b in ("H", "QE", "PCA")}
    neutral = positions[0]
    common = dict(neutral=neutral, rate=face.rate, labels=face.labels, markerset=markerset,
                  step=STEP)
    n = len(range(0, face.n_frames, STEP))

    tic = time.perf_counter()
    write_overlay_video(positions, recs, work / "all.webm", **common)
    ours = time.perf_counter() - tic
    with FigureQueue() as queue:    # made before, as the report's queue is
        tic = time.perf_counter()
        parts = _queue_video(queue, face.replace(positions=positions), recs,
                             work / "parts.webm", neutral=neutral, markerset=markerset,
                             step=STEP, exaggerate=1.0)
        queue.run()
        if len(parts) > 1:
            join_webm(parts, work / "parts.webm")
        in_parts = time.perf_counter() - tic
    tic = time.perf_counter()
    with mock.patch.object(video, "WebmWriter", partial(WebmWriter, encoder="opencv")):
        write_overlay_video(positions, recs, work / "opencv.webm", **common)
    opencv = time.perf_counter() - tic
    tic = time.perf_counter()
    for b in recs:
        mp4v_baseline(n, (512, 512), work / f"{b}.mp4")
    old = time.perf_counter() - tic
    tic = time.perf_counter()
    for b, rec in recs.items():
        write_overlay_video(positions, rec, work / f"{b}.webm", size=(512, 512), **common)
    per_basis = time.perf_counter() - tic
    size = (work / "all.webm").stat().st_size / 1e6
    old_size = sum((work / f"{b}.mp4").stat().st_size for b in recs) / 1e6
    print(f"{n} video frames, {len(recs)} bases (machine load {os.getloadavg()[0]:.1f})")
    print(f"  ours: one VP9 WebM, 3 panels 288x320: {ours:6.1f} s, {size:5.1f} MB")
    print(f"  the same in {len(parts)} part(s), joined:      {in_parts:6.1f} s "
          f"({ours / in_parts:.2f}x as fast; {len(parts) - 1} "
          f"helper(s))")
    print(f"  the same by OpenCV's VP9 writer:      {opencv:6.1f} s, "
          f"{(work / 'opencv.webm').stat().st_size / 1e6:5.1f} MB")
    print(f"  baseline: 3 mp4v MP4 512x512:         {old:6.1f} s, {old_size:5.1f} MB "
          f"(not playable in Chromium)")
    print(f"  3 VP9 WebM 512x512:                   {per_basis:6.1f} s")
    print(f"  ratio ours / OpenCV's VP9: {ours / opencv:.2f}; ours / mp4v baseline: "
          f"{ours / old:.2f}; ours / per-basis VP9: {ours / per_basis:.2f}")


if __name__ == "__main__":
    main()
