"""VP9 video in WebM (what browsers play) from BGR frames, one frame at a time.

With PyAV (the ``speech`` extra: a GPL build of FFmpeg) the frames go to
libvpx-vp9 in its real-time mode; without PyAV, through OpenCV's FFmpeg backend,
which leaves libvpx in its slow default mode and takes no encoder options (the
demo's overlay video: 10.7 s against 1.4 s, ``bench/bench_report_video.py``).
Either way the file is VP9 in WebM at the frame rate asked for.

The frames are encoded on a thread of the writer's own, in order, while the caller
draws the next ones: both encoders (libvpx and FFmpeg's conversion to YUV through
PyAV, OpenCV's writer) leave the GIL, so drawing and encoding share two cores. A
frame is copied when it is written (the caller may draw the next one in the same
memory); at most :data:`_FRAMES_AHEAD` wait for the encoder.
"""

from __future__ import annotations

import contextlib
import os
import queue
import sys
import tempfile
import threading
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

from mocap.errors import InputError
from mocap.util.atomic import atomic_path
from mocap.util.optional import available, require
from mocap.util.validation import as_int

__all__ = ["WebmWriter", "ENCODERS", "can_join", "join_webm"]

#: Who encodes: PyAV's libvpx-vp9 in real-time mode, or OpenCV's VideoWriter.
ENCODERS = ("pyav", "opencv")
#: Bits a second per pixel a second of the real-time encoder's target: sharp dots and
#: lines on flat colour (1.2 Mbit/s for 864 × 320 at 30 frames a second).
_BITS_PER_PIXEL = 0.15
#: Frames written and not yet encoded, at most (each a copy: 0.8 MB for 864 × 320).
_FRAMES_AHEAD = 4


class WebmWriter:
    """Write BGR frames (height, width, 3) uint8 as a VP9 WebM video.

    Parameters
    ----------
    path : str or os.PathLike
        The output file (its suffix need not be ``.webm``: the container is set).
    fps : float
        Frames a second.
    size : (int, int)
        Width and height of every frame, pixels (even numbers: VP9's 4:2:0 chroma).
    encoder : {"pyav", "opencv"}, optional
        Default PyAV's when it is installed, else OpenCV's.
    start : int, default 0
        The first frame's index in a longer video, of which this file is a part (its
        time stamps count from there: :func:`join_webm`); PyAV's encoder only.
    threads : int, default 0
        The encoder's threads; 0: FFmpeg's choice (one per core). PyAV's encoder only.
        One where other processes encode the video's other parts, a core each: no thread
        then waits for a busy core, and the same frames give the same bytes.

    Raises
    ------
    InputError
        The encoder cannot write VP9 WebM to `path` (named).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "grey.webm"
    >>> with WebmWriter(path, 30.0, (64, 48)) as video:
    ...     video.write(np.full((48, 64, 3), 128, np.uint8))
    >>> path.read_bytes()[:4] == b"\\x1a\\x45\\xdf\\xa3"          # EBML: a WebM file
    True
    """

    def __init__(self, path, fps: float, size: tuple, *, encoder: str | None = None,
                 start: int = 0, threads: int = 0):
        self.path = Path(path)
        self.size = (int(size[0]), int(size[1]))
        self.encoder = ("pyav" if available("av") else "opencv") if encoder is None else encoder
        if self.encoder not in ENCODERS:
            raise InputError(f"encoder must be one of {ENCODERS}, got {self.encoder!r}")
        self.start = as_int(start, "start", minimum=0)
        if self.start and self.encoder != "pyav":
            raise InputError("only PyAV's encoder writes a part of a video (start > 0)")
        threads = as_int(threads, "threads", minimum=0)
        if threads and self.encoder != "pyav":
            raise InputError("only PyAV's encoder takes a number of threads")
        if not self.path.parent.is_dir():
            raise InputError(f"{self.path}: cannot write: directory {self.path.parent} does "
                             "not exist")
        self.n_frames = 0
        if self.encoder == "pyav":
            self._open_pyav(float(fps), threads)
        else:
            self._open_opencv(float(fps))
        # the encoding thread: frames in order, None to stop; its first error kept. A thread
        # of its own, not one of mocap.util.blas.shared_pool's: it is busy for the whole
        # video, while the caller may share work on the pool meanwhile
        self._frames: queue.Queue = queue.Queue(maxsize=_FRAMES_AHEAD)
        self._failure: BaseException | None = None
        self._reported = False              # the failure raised already (by write)
        self._encoding = threading.Thread(target=self._encode_frames, daemon=True,
                                          name="webm-encoder")
        self._encoding.start()

    def _open_pyav(self, fps: float, threads: int) -> None:
        av = require("av", package="av", extra="speech", purpose="VP9 encoding by PyAV")
        self._av = av
        rate = Fraction(fps).limit_denominator(1001)
        with self._writing():
            self._container = av.open(os.fspath(self.path), mode="w", format="webm")
        width, height = self.size
        try:
            self._stream = self._container.add_stream(
                "libvpx-vp9", rate=rate,
                options={"deadline": "realtime", "cpu-used": "8", "row-mt": "1"})
        except (ValueError, av.FFmpegError) as exc:     # a build without libvpx
            self._container.close()
            raise InputError(f"{self.path}: cannot write: PyAV's FFmpeg has no VP9 encoder "
                             f"({exc})") from None
        self._stream.width, self._stream.height = width, height
        self._stream.pix_fmt = "yuv420p"
        if threads:
            self._stream.codec_context.thread_count = threads
        self._stream.bit_rate = int(_BITS_PER_PIXEL * width * height * fps)
        self._time_base = Fraction(1, 1) / rate

    def _open_opencv(self, fps: float) -> None:
        # container by suffix: a temporary .webm beside the file, renamed on close
        self._opencv_path = self.path.with_name(self.path.name + ".webm")
        with _stderr_captured() as said:
            self._writer = cv2.VideoWriter(os.fspath(self._opencv_path),
                                           cv2.VideoWriter_fourcc(*"VP90"), fps, self.size)
        if not self._writer.isOpened():
            raise InputError(f"{self.path}: cannot write: OpenCV has no VP9 (WebM) writer"
                             + (f" ({said[0].strip()})" if said and said[0].strip() else ""))

    def write(self, frame: np.ndarray) -> None:
        """Append one BGR frame, uint8 of shape (height, width, 3) (copied: the caller may
        reuse its memory at once).

        Raises
        ------
        InputError
            A frame of another shape or type; the file could not be written (an error of
            the encoding of an earlier frame, raised here or by :meth:`close`).
        """
        if frame.shape != (self.size[1], self.size[0], 3) or frame.dtype != np.uint8:
            raise InputError(f"{self.path}: frame {self.n_frames} is {frame.dtype} of shape "
                             f"{frame.shape}, expected uint8 of shape "
                             f"({self.size[1]}, {self.size[0]}, 3)")
        if self._failure is not None:
            self._reported = True
            raise self._failure
        if self.encoder == "pyav":
            image = self._av.VideoFrame(self.size[0], self.size[1], "bgr24")
            plane = image.planes[0]         # its rows may be padded: copied into, not over
            np.copyto(np.frombuffer(plane, np.uint8).reshape(-1, plane.line_size)[
                :, :frame.shape[1] * 3].reshape(frame.shape), frame)
            image.pts, image.time_base = self.start + self.n_frames, self._time_base
        else:
            image = frame.copy()
        self._frames.put(image)
        self.n_frames += 1

    def _encode_frames(self) -> None:
        """The encoding thread: each frame of the queue, until None. After an error it
        keeps taking the frames (dropped), so that :meth:`write` never waits for it."""
        while (image := self._frames.get()) is not None:
            if self._failure is not None:
                continue
            try:
                if self.encoder == "pyav":
                    with self._writing():
                        self._container.mux(self._stream.encode(image))
                else:
                    self._writer.write(image)
            except BaseException as exc:  # noqa: BLE001 - raised in the caller's thread
                self._failure = exc

    def close(self) -> None:
        """Finish the file (the frames written encoded, the encoder flushed, the index
        written).

        Raises
        ------
        InputError
            The file could not be written (unless :meth:`write` raised it already).
        """
        self._frames.put(None)
        self._encoding.join()
        if self.encoder == "pyav":
            with self._writing():
                try:
                    if self._failure is None:
                        self._container.mux(self._stream.encode(None))
                finally:
                    self._container.close()
        else:
            self._writer.release()
            if self._opencv_path.exists():
                if self._failure is None:
                    os.replace(self._opencv_path, self.path)
                else:
                    self._opencv_path.unlink()
        if self._failure is not None and not self._reported:
            raise self._failure

    @contextlib.contextmanager
    def _writing(self):
        """FFmpeg's write errors (a full disk) as an InputError naming the file."""
        try:
            yield
        except OSError as exc:
            raise InputError(f"{self.path}: cannot write: {exc.strerror or exc}") from None

    def __enter__(self) -> "WebmWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def can_join() -> bool:
    """Whether :func:`join_webm` can join parts here (it needs PyAV, the ``speech`` extra)."""
    return available("av")


def join_webm(parts, path) -> None:
    """Write the videos `parts`, one after the other, as one WebM video at `path`.

    Their VP9 packets are copied as they are, not encoded again: the parts are
    :class:`WebmWriter` files of one size, frame rate and encoder, each with the time
    stamps of its frames in the whole video (``start``), and each starts with a key frame
    (as every video does), which a player shows as it shows any other.

    Parameters
    ----------
    parts : sequence of path
        The parts, in order.
    path : str or os.PathLike
        Written atomically.

    Raises
    ------
    InputError
        A part that is not such a video, or not of the first part's codec, size and rate,
        or `path` cannot be written (named).
    """
    av = require("av", package="av", extra="speech", purpose="joining WebM videos")
    with atomic_path(path) as tmp, av.open(os.fspath(tmp), mode="w", format="webm") as out:
        stream = first = None
        for part in parts:
            try:
                with av.open(os.fspath(part)) as source:
                    video = source.streams.video[0]
                    kind = (video.codec_context.name, video.codec_context.width,
                            video.codec_context.height, video.average_rate)
                    if stream is None:
                        stream, first = out.add_stream_from_template(video), kind
                    elif kind != first:
                        raise InputError(f"{part}: a part of another video ({kind[0]} "
                                         f"{kind[1]} x {kind[2]} at {float(kind[3]):g} frames "
                                         f"a second, not {first[0]} {first[1]} x {first[2]} at "
                                         f"{float(first[3]):g})")
                    for packet in source.demux(video):
                        if packet.dts is None:          # the demuxer's flush packet
                            continue
                        packet.stream = stream
                        out.mux(packet)
            except (av.FFmpegError, IndexError) as exc:
                raise InputError(f"{part}: not a part of a WebM video ({exc})") from None


@contextlib.contextmanager
def _stderr_captured():
    """Capture what C code writes to file descriptor 2 (a list, filled on exit).

    OpenCV's FFmpeg writer prints that the 'VP90' tag "is not supported with
    codec id 167 and format webm" and then writes VP9 all the same (the tag is
    only the container's codec label); that notice must not reach the user.
    """
    said: list = []
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield said
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            said.append(sink.read().decode("utf-8", "replace"))
