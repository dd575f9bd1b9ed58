"""The talking face as a video with its speech: frames from the project's renderer, VP9 + Opus WebM.

Frames are rendered by :func:`mocap.viz.render.render_mesh` and encoded as VP9
in WebM, which browsers play (:class:`mocap.viz.webm.WebmWriter`: by PyAV when it
is installed, else by OpenCV, a core dependency). The speech is muxed in with
PyAV, the Python binding of FFmpeg (the field's standard for audio/video streams;
its wheels bundle FFmpeg with libopus and libvpx, nothing to install beside it):
the VP9 packets are copied as they are and the WAV is encoded as Opus, the audio
codec of WebM. PyAV's FFmpeg build is GPL, so it lives in the optional extra
``mocap2mesh[speech]``; without it the video is written silent, with a warning.
"""

from __future__ import annotations

import os
import warnings
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np
import scipy.signal
from tqdm import tqdm

from fit.gestures.speech import read_wav
from mocap.errors import InputError
from mocap.mesh.mesh import Mesh
from mocap.util.atomic import atomic_path
from mocap.util.optional import available, require
from mocap.util.validation import as_float_array, as_int, as_positive_float
from mocap.viz.render import Camera, compiled_renders, render_mesh
from mocap.viz.webm import WebmWriter

__all__ = ["write_talking_video", "AUDIO_RATE"]

#: Sampling rate of the Opus track, Hz (Opus runs at 48 kHz).
AUDIO_RATE = 48000
_AUDIO_FRAME = 960              # 20 ms Opus frames
_CHUNK_FRAMES = 64              # frames of vertices evaluated at once


def write_talking_video(path, neutral: Mesh, displacements, weights, *, rate: float, audio=None,
                        rotation=None, translation=None, size=(480, 480),
                        view="front", inputs=()) -> int:
    """Write a WebM of the talking face, with the speech as its audio track.

    Parameters
    ----------
    path : str or os.PathLike
        Output ``.webm``, written atomically, never over one of `inputs`.
    neutral : Mesh
        The target face (its faces are drawn).
    displacements : array_like of shape (n_targets, N, 3), mesh units
        Morph targets (:attr:`fit.gestures.lipsync.TalkingFace.displacements`).
    weights : array_like of shape (n_frames, n_targets)
        Their weights per frame. No NaN.
    rate : float, Hz
        Frame rate of the weights: the video's frame rate.
    audio : str or os.PathLike, optional
        The speech WAV, from frame 0. None: a silent video.
    rotation : array_like of shape (n_frames, 3, 3), optional
        Head motion on the mesh (:func:`fit.gestures.transfer.head_motion_on_mesh`);
        vertex v of frame t is drawn at ``rotation[t] @ v + translation[t]``.
    translation : array_like of shape (n_frames, 3), mesh units, optional
    size : (int, int)
        Width and height, pixels (even numbers, for VP9's 4:2:0).
    view : str
        Of :meth:`mocap.viz.render.Camera.fit`; the camera frames the neutral
        with room for the head motion and stays put.

    Returns
    -------
    int
        Frames written.

    Raises
    ------
    InputError
        Bad sizes, motion of another frame count, no VP9 (WebM) encoder, the
        file cannot be written.
    FileFormatError
        An unreadable WAV.

    Warns
    -----
    UserWarning
        PyAV (the ``speech`` extra) is missing: the video has no sound.
    """
    if not isinstance(neutral, Mesh):
        raise InputError(f"neutral must be a Mesh, got {type(neutral).__name__}")
    displacements = as_float_array(displacements, "displacements",
                                   shape=(None, neutral.n_vertices, 3), allow_nan=False)
    weights = as_float_array(weights, "weights", shape=(None, len(displacements)),
                             allow_nan=False)
    rate = as_positive_float(rate, "rate")
    width, height = (as_int(v, "size", minimum=16) for v in size)
    if width % 2 or height % 2:
        raise InputError(f"size must be even (VP9 4:2:0), got {width}x{height}")
    n = len(weights)
    if (rotation is None) != (translation is None):
        raise InputError("rotation and translation go together")
    if rotation is not None:
        rotation = as_float_array(rotation, "rotation", shape=(n, 3, 3), allow_nan=False)
        translation = as_float_array(translation, "translation", shape=(n, 3),
                                     allow_nan=False)
    samples = None
    if audio is not None:
        samples, audio_rate = read_wav(audio)
        if not available("av"):
            warnings.warn("PyAV is not installed (pip install 'mocap2mesh[speech]'): the "
                          "video has no sound", stacklevel=2)
            samples = None
    camera = Camera.fit(neutral.vertices, view=view, size=(width, height), margin=0.12)
    with atomic_path(path, inputs=inputs) as tmp:
        silent = tmp.with_name(tmp.name + ".video.webm")
        try:
            _write_frames(silent, neutral, displacements, weights, camera, rate, rotation,
                          translation)
            if samples is None:
                os.replace(silent, tmp)
            else:
                _mux(silent, samples, audio_rate, tmp)
        finally:
            if silent.exists():
                silent.unlink()
    return n


def _write_frames(path: Path, neutral, displacements, weights, camera, rate, rotation,
                  translation) -> None:
    writer = WebmWriter(path, rate, camera.size)
    compiled_renders(len(weights), neutral.n_faces)         # loaded once for every frame
    progress = tqdm(total=len(weights), unit="frame", desc="talking video", disable=None,
                    leave=False)
    try:
        flat = displacements.reshape(len(displacements), -1)
        for lo in range(0, len(weights), _CHUNK_FRAMES):  # chunks of frames
            chunk = (weights[lo:lo + _CHUNK_FRAMES] @ flat).reshape(-1, neutral.n_vertices, 3) \
                + neutral.vertices
            if rotation is not None:
                part = slice(lo, lo + len(chunk))
                chunk = np.einsum("tij,tvj->tvi", rotation[part], chunk) \
                    + translation[part, None]
            for vertices in chunk:                              # rasterize each frame
                image = render_mesh(vertices, neutral.faces, camera=camera, supersample=1)
                writer.write(cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
            progress.update(len(chunk))
    finally:
        progress.close()
        writer.close()


def _mux(video: Path, samples: np.ndarray, rate: float, out: Path) -> None:
    """Copy the VP9 stream of `video` into `out` beside the speech encoded as Opus."""
    av = require("av", package="av", extra="speech", purpose="the video's sound track")
    g = np.gcd(AUDIO_RATE, int(round(rate)))
    pcm = scipy.signal.resample_poly(samples, AUDIO_RATE // g, int(round(rate)) // g)
    pcm = np.clip(pcm, -1.0, 1.0).astype(np.float32)
    with av.open(os.fspath(video)) as source, \
            av.open(os.fspath(out), mode="w", format="webm") as target:
        v_in = source.streams.video[0]
        v_out = target.add_stream_from_template(v_in)
        a_out = target.add_stream("libopus", rate=AUDIO_RATE, layout="mono")
        a_out.time_base = Fraction(1, AUDIO_RATE)
        packets = []
        for start in range(0, len(pcm), _AUDIO_FRAME):
            block = np.zeros((1, _AUDIO_FRAME), np.float32)
            part = pcm[start:start + _AUDIO_FRAME]
            block[0, :len(part)] = part
            frame = av.AudioFrame.from_ndarray(block, format="flt", layout="mono")
            frame.sample_rate, frame.pts = AUDIO_RATE, start
            frame.time_base = Fraction(1, AUDIO_RATE)
            packets.extend(a_out.encode(frame))
        packets.extend(a_out.encode(None))
        for packet in source.demux(v_in):
            if packet.dts is None:
                continue
            packet.stream = v_out
            packets.append(packet)
        # Interleave by time, as a player reading the file front to back wants.
        packets.sort(key=lambda p: float((p.dts if p.dts is not None else p.pts or 0)
                                         * p.time_base))
        for packet in packets:
            target.mux(packet)
