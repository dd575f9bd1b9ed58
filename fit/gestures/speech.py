"""Speech intensity S(t): RMS energy in dB per frame of a take, from audio or an analog channel.

The gestures paper drives its Markov random field with the loudness of speech
(Ju & Lee 2008, sec. 5.1; Praat intensity). Here S(t) is the RMS of the signal
over a window centred on each frame time, in dB relative to full scale (PCM
integers are scaled to [-1, 1)), computed for all frames at once from a
cumulative sum of squares.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.io.wavfile

from mocap.errors import FileFormatError, InputError
from mocap.take import Take, as_take
from mocap.util.validation import as_float_array, as_int, as_positive_float

__all__ = ["speech_intensity", "read_wav", "wav_intensity", "analog_intensity",
           "opening_intensity", "DEFAULT_WINDOW_S", "OPENING_WINDOW_S", "FLOOR_DB"]

#: RMS window, s (Praat's intensity uses ~3.2 / pitch floor, 32-64 ms).
DEFAULT_WINDOW_S = 0.05
#: RMS window of a mouth-opening proxy, s (a few frames at 30 Hz).
OPENING_WINDOW_S = 0.25
#: Intensity of silence, dB re full scale (the RMS is floored at 10^(FLOOR_DB/20)).
FLOOR_DB = -100.0


def speech_intensity(samples, rate: float, *, frame_rate: float, n_frames: int | None = None,
                     window: float = DEFAULT_WINDOW_S, floor_db: float = FLOOR_DB) -> np.ndarray:
    """RMS energy in dB of a signal, sampled at the frames of a take.

    Parameters
    ----------
    samples : array_like of shape (n_samples,) or (n_samples, n_channels)
        The signal, full scale 1 (see :func:`read_wav`); channels are mixed
        to mono by their mean. No NaN.
    rate : float, Hz
        Sampling rate of `samples`.
    frame_rate : float, Hz
        Frame rate of the take the intensity is for; frame k is at ``k / frame_rate`` s.
    n_frames : int, optional
        Frames to return; default: every frame time within the signal,
        ``ceil(n_samples / rate * frame_rate)``. Frames past the end see silence.
    window : float, s, default 0.05
        Width of the RMS window centred on each frame time (cut at the ends of
        the signal: the RMS is over the samples inside).
    floor_db : float, default -100
        Level given to silence (an RMS below ``10**(floor_db / 20)``).

    Returns
    -------
    ndarray of shape (n_frames,), dB re full scale
        ``20 log10(RMS)``: a sine of amplitude A reads ``20 log10(A / sqrt 2)``.

    Raises
    ------
    InputError
        Empty or NaN signal, non-positive rates or window.

    Notes
    -----
    With the cumulative sum ``C[i] = Σ_{k<i} x_k²`` the window of frame t,
    samples ``[a, b)`` with ``a = round((t − w/2) rate)``, ``b = round((t + w/2) rate)``
    clipped to the signal, has ``RMS² = (C[b] − C[a]) / (b − a)``.
    """
    samples = as_float_array(samples, "samples", allow_nan=False)
    if samples.ndim == 2:
        samples = samples.mean(axis=1)
    if samples.ndim != 1 or samples.size == 0:
        raise InputError(f"samples must have shape (n_samples,) or (n_samples, n_channels) "
                         f"with n_samples > 0, got {samples.shape}")
    rate = as_positive_float(rate, "rate")
    frame_rate = as_positive_float(frame_rate, "frame_rate")
    window = as_positive_float(window, "window")
    floor_db = float(floor_db)
    n_frames = (int(np.ceil(len(samples) / rate * frame_rate - 1e-9)) if n_frames is None
                else as_int(n_frames, "n_frames", minimum=1))
    cum = np.concatenate([[0.0], np.cumsum(samples * samples)])
    times = np.arange(n_frames) / frame_rate
    lo = np.clip(np.round((times - window / 2) * rate).astype(np.int64), 0, len(samples))
    hi = np.clip(np.round((times + window / 2) * rate).astype(np.int64), 0, len(samples))
    power = np.where(hi > lo, (cum[hi] - cum[lo]) / np.maximum(hi - lo, 1), 0.0)
    floor = 10.0 ** (floor_db / 10.0)
    return 10.0 * np.log10(np.maximum(power, floor))


def read_wav(path) -> tuple[np.ndarray, float]:
    """Read a WAV file as a mono float signal of full scale 1.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    samples : ndarray of shape (n_samples,)
        Channels mixed by their mean; 8-bit PCM as ``(x − 128) / 128``, 16/32-bit
        PCM as ``x / 2^(bits − 1)``, float PCM as stored.
    rate : float, Hz

    Raises
    ------
    FileFormatError
        Missing, unreadable or empty file, an unsupported sample type.
    """
    path = Path(path)
    try:
        rate, data = scipy.io.wavfile.read(path)
    except FileNotFoundError:
        raise FileFormatError(path, "no such file") from None
    except (OSError, ValueError, EOFError) as exc:
        raise FileFormatError(path, f"cannot read WAV: {exc}") from None
    if data.dtype == np.uint8:
        data = (data.astype(np.float64) - 128.0) / 128.0
    elif np.issubdtype(data.dtype, np.signedinteger):
        data = data.astype(np.float64) / float(2 ** (8 * data.dtype.itemsize - 1))
    elif np.issubdtype(data.dtype, np.floating):
        data = data.astype(np.float64)
    else:
        raise FileFormatError(path, f"unsupported WAV sample type {data.dtype}")
    if data.ndim == 2:
        data = data.mean(axis=1)
    if data.size == 0:
        raise FileFormatError(path, "the WAV file holds no samples")
    if not np.isfinite(data).all():
        raise FileFormatError(path, "the WAV file holds non-finite samples")
    return data, float(rate)


def wav_intensity(path, *, frame_rate: float, n_frames: int | None = None,
                  window: float = DEFAULT_WINDOW_S) -> np.ndarray:
    """S(t) of a WAV file at `frame_rate`: :func:`read_wav` then :func:`speech_intensity`.

    Returns
    -------
    ndarray of shape (n_frames,), dB re full scale
    """
    samples, rate = read_wav(path)
    return speech_intensity(samples, rate, frame_rate=frame_rate, n_frames=n_frames,
                            window=window)


def analog_intensity(take: Take, channel: str, *, window: float = DEFAULT_WINDOW_S) -> np.ndarray:
    """S(t) of a take's analog channel (a microphone recorded with the markers).

    Parameters
    ----------
    take : Take
        With analog data; the intensity is sampled at its frames.
    channel : str
        Analog channel label.
    window : float, s

    Returns
    -------
    ndarray of shape (take.n_frames,), dB re the channel's unit

    Raises
    ------
    InputError
        No analog data, an unknown channel, NaN samples.
    """
    take = as_take(take)
    if take.analog is None:
        raise InputError("the take has no analog channels to read speech from")
    return speech_intensity(take.analog.channel(channel), take.analog.rate,
                            frame_rate=take.rate, n_frames=take.n_frames, window=window)


def opening_intensity(take: Take, upper: str, lower: str, *,
                      window: float = OPENING_WINDOW_S) -> np.ndarray:
    """A stand-in for S(t) in a take recorded without audio: loudness of the mouth opening.

    Parameters
    ----------
    take : Take
        Markers in mm (head-stabilized or not: only a distance is used).
    upper, lower : str
        Labels of an upper-lip and a lower-lip marker (e.g. the lip centres).
    window : float, s, default 0.25

    Returns
    -------
    ndarray of shape (take.n_frames,), dB re 1 mm
        :func:`speech_intensity` at the take's frames of the opening
        ``|upper − lower| − min |upper − lower|`` (mouth opening tracks the
        energy of speech and song). Frames where a marker is missing count as
        a closed mouth (silence).

    Raises
    ------
    MarkerError
        A label not in the take.
    InputError
        Both markers never seen together.
    """
    take = as_take(take)
    pair = take.positions[:, take.indices([upper, lower])]
    gap = np.linalg.norm(pair[:, 0] - pair[:, 1], axis=1)
    seen = np.isfinite(gap)
    if not seen.any():
        raise InputError(f"markers {upper!r} and {lower!r} are never visible together")
    opening = np.where(seen, gap - np.min(gap[seen]), 0.0)
    return speech_intensity(opening, take.rate, frame_rate=take.rate, n_frames=take.n_frames,
                            window=window)
