"""VP9 WebM writing by PyAV and by OpenCV: what a browser plays, read back by both decoders."""

from __future__ import annotations

import av  # the speech extra, which the tests install
import cv2
import numpy as np
import pytest

from mocap.errors import InputError
from mocap.viz.webm import ENCODERS, WebmWriter


def _frames(n: int, width: int, height: int) -> np.ndarray:
    """A red disc moving right on white, a blue bar growing down: (n, height, width, 3) BGR."""
    frames = np.full((n, height, width, 3), 255, np.uint8)
    for k, frame in enumerate(frames):
        cv2.circle(frame, (10 + 4 * k, height // 2), 8, (40, 39, 214), -1, cv2.LINE_AA)
        frame[: 5 + 2 * k, -12:] = (214, 95, 31)
    return frames


@pytest.mark.parametrize("encoder", ENCODERS)
@pytest.mark.parametrize("fps", [30.0, 69.0, 29.97])
def test_both_encoders_write_vp9_webm_at_the_rate(tmp_path, encoder, fps):
    frames = _frames(24, 160, 96)
    path = tmp_path / "clip.webm"
    drawn = np.empty_like(frames[0])        # one buffer, redrawn at once: the writer copies
    with WebmWriter(path, fps, (160, 96), encoder=encoder) as video:
        for frame in frames:
            drawn[:] = frame
            video.write(drawn)
            drawn[:] = 0
    assert video.n_frames == len(frames)
    assert [p.name for p in tmp_path.iterdir()] == ["clip.webm"]          # no temporary left
    with av.open(str(path)) as container:                                # FFmpeg's reading
        stream = container.streams.video[0]
        assert container.format.name.startswith("matroska,webm")
        assert stream.codec_context.name == "vp9"
        decoded = [f.to_ndarray(format="bgr24") for f in container.decode(stream)]
        assert float(stream.average_rate) == pytest.approx(fps, rel=1e-3)
    assert len(decoded) == len(frames)
    for shown, drawn in zip(decoded, frames):
        # lossy, but the picture is the one drawn: where the disc and the bar are
        assert np.abs(shown.astype(int) - drawn).mean() < 6
        red = (shown[..., 2] > 150) & (shown[..., 1] < 110)
        assert abs(np.argwhere(red)[:, 1].mean() - np.argwhere(
            (drawn[..., 2] > 150) & (drawn[..., 1] < 110))[:, 1].mean()) < 1.5
    video = cv2.VideoCapture(str(path))                                  # OpenCV's reading
    try:
        assert int(video.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little") == b"VP90"
        assert video.get(cv2.CAP_PROP_FPS) == pytest.approx(fps, rel=1e-3)
    finally:
        video.release()


def test_pyav_is_the_default_when_installed(tmp_path):
    with WebmWriter(tmp_path / "a.webm", 25.0, (32, 32)) as video:
        video.write(np.zeros((32, 32, 3), np.uint8))
    assert video.encoder == "pyav"


@pytest.mark.parametrize("encoder", ENCODERS)
def test_bad_frames_and_paths_are_named(tmp_path, encoder):
    with WebmWriter(tmp_path / "a.webm", 25.0, (32, 32), encoder=encoder) as video:
        with pytest.raises(InputError, match=r"a\.webm: frame 0 is uint8 of shape \(32, 48, 3\)"):
            video.write(np.zeros((32, 48, 3), np.uint8))
        with pytest.raises(InputError, match="frame 0 is float64"):
            video.write(np.zeros((32, 32, 3)))
    with pytest.raises(InputError, match="cannot write"):
        WebmWriter(tmp_path / "missing" / "a.webm", 25.0, (32, 32), encoder=encoder)
    with pytest.raises(InputError, match="encoder must be one of"):
        WebmWriter(tmp_path / "b.webm", 25.0, (32, 32), encoder="x264")
    if encoder == "opencv":         # its time stamps are its own: no part of a video
        with pytest.raises(InputError, match=r"only PyAV's encoder writes a part"):
            WebmWriter(tmp_path / "c.webm", 25.0, (32, 32), encoder=encoder, start=10)


def test_one_encoder_thread_writes_the_frames_the_same_each_time(tmp_path):
    """A part's encoder on one thread (the report's parts, a core each): the frames drawn,
    and the same pictures from the same frames (the files differ only in the muxer's random
    track and segment ids); OpenCV's writer takes no thread count."""
    frames = _frames(24, 160, 96)
    videos = []
    for name in ("a", "b"):
        with WebmWriter(tmp_path / f"{name}.webm", 30.0, (160, 96), threads=1) as video:
            for frame in frames:
                video.write(frame)
        with av.open(str(tmp_path / f"{name}.webm")) as container:
            videos.append(np.stack([f.to_ndarray(format="bgr24")
                                    for f in container.decode(video=0)]))
    np.testing.assert_array_equal(videos[0], videos[1])
    decoded = videos[0]
    assert len(decoded) == len(frames)
    assert max(np.abs(shown.astype(int) - drawn).mean()
               for shown, drawn in zip(decoded, frames)) < 6
    with pytest.raises(InputError, match="only PyAV's encoder takes a number of threads"):
        WebmWriter(tmp_path / "c.webm", 30.0, (160, 96), encoder="opencv", threads=1)
    with pytest.raises(InputError, match="threads"):
        WebmWriter(tmp_path / "d.webm", 30.0, (160, 96), threads=-1)


def test_rows_the_encoder_pads_are_copied_whole(tmp_path):
    """A width whose BGR rows FFmpeg pads to its alignment (166 px: 498 bytes in rows of
    512): each row is copied into its padded place, the picture is the one drawn."""
    frames = _frames(12, 166, 96)
    with WebmWriter(tmp_path / "odd.webm", 30.0, (166, 96), threads=1) as video:
        for frame in frames:
            video.write(frame)
    with av.open(str(tmp_path / "odd.webm")) as container:
        decoded = [f.to_ndarray(format="bgr24") for f in container.decode(video=0)]
    assert len(decoded) == len(frames)
    assert max(np.abs(shown.astype(int) - drawn).mean()
               for shown, drawn in zip(decoded, frames)) < 6


class _FullDisk:
    """A PyAV output container whose writes fail from the `after`-th packet on, as on a
    full disk."""

    def __init__(self, container, after: int):
        self.container, self.after, self.muxed = container, after, 0

    def mux(self, packets):
        self.muxed += 1
        if self.muxed > self.after:
            raise OSError(28, "No space left on device")
        self.container.mux(packets)

    def close(self):
        self.container.close()


def test_an_encoding_error_is_raised_naming_the_file_and_nothing_waits(tmp_path):
    """The frames are encoded on the writer's thread: its error reaches the caller (a
    later write or the close), and frames written after it are dropped, not waited for."""
    import threading

    path = tmp_path / "full.webm"
    frames = _frames(40, 160, 96)
    video = WebmWriter(path, 30.0, (160, 96))
    video._container = _FullDisk(video._container, after=3)
    with pytest.raises(InputError, match=r"full\.webm: cannot write: No space left on device"):
        try:
            for frame in frames:
                video.write(frame)
        finally:
            video.close()
    assert not any(t.name == "webm-encoder" and t.is_alive() for t in threading.enumerate())
