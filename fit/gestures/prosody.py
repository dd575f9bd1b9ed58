"""Praat's intensity and pitch of speech, sampled at the frames of a take.

Ju & Lee (2008, sec. 3) measure the loudness and pitch of speech with Praat;
the loudness is the speech term S(t) of the Markov random field (sec. 5.1).
Here Praat itself does it, through ``praat-parselmouth`` (GPL-3.0, in the
optional extra ``mocap2mesh[speech]``): ``Sound: To Intensity`` and
``Sound: To Pitch`` with Praat's own algorithms and defaults, then sampled at
the frame times ``k / frame_rate``. Without the extra, :func:`speech_prosody`
falls back to the RMS level of :mod:`fit.gestures.speech` (with a warning),
which has no pitch.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fit.gestures.speech import DEFAULT_WINDOW_S, read_wav, speech_intensity
from mocap.errors import InputError
from mocap.util.arrays import read_only
from mocap.util.optional import available, require
from mocap.util.validation import as_choice, as_float_array, as_int, as_positive_float

__all__ = ["Prosody", "praat_prosody", "rms_prosody", "speech_prosody", "PROSODY_METHODS",
           "PITCH_FLOOR_HZ", "PITCH_CEILING_HZ"]

#: How the loudness is measured: Praat (the paper's), the RMS level, or Praat when
#: the ``speech`` extra is installed and the RMS level otherwise.
PROSODY_METHODS = ("auto", "praat", "rms")
#: Pitch range of Praat's pitch analysis, Hz (its defaults for speech). The floor also
#: sets the intensity window, 3.2 / floor s (Praat's "minimum pitch").
PITCH_FLOOR_HZ = 75.0
PITCH_CEILING_HZ = 600.0
#: Praat's analysis step, s: finer than any frame rate the synthesis runs at.
_STEP_S = 0.005
#: Praat's level of digital silence is -300 dB; the MRF floors every curve 60 dB below
#: its loud frames anyway, so levels are clipped here to keep the CSV readable.
_FLOOR_DB = -100.0


@dataclass(frozen=True, eq=False)
class Prosody:
    """Loudness and pitch of a speech signal at frame times.

    Attributes
    ----------
    intensity : ndarray of shape (n_frames,), dB
        S(t). ``praat``: Praat's intensity, dB SPL re 20 µPa with the signal read
        as pascals (full scale 1 Pa: a sine of amplitude A reads
        ``20 log10(A / (√2 · 2e-5))``); ``rms``: dB re full scale.
    pitch : ndarray of shape (n_frames,) or None, Hz
        Praat's F0, NaN where unvoiced; None with ``rms``.
    rate : float, Hz
        Frame rate; frame k is at ``k / rate`` s.
    method : str
        ``"praat"`` or ``"rms"``.
    """

    intensity: np.ndarray
    pitch: np.ndarray | None
    rate: float
    method: str

    @property
    def n_frames(self) -> int:
        """Number of frames T."""
        return len(self.intensity)

    @property
    def source(self) -> str:
        """One line saying what the intensity is (kept in clips)."""
        if self.method == "praat":
            return "speech: Praat intensity, dB SPL (signal as Pa)"
        return "speech: RMS dB re full scale"


def _frames(n_samples: int, rate: float, frame_rate: float, n_frames) -> int:
    if n_frames is None:
        return int(np.ceil(n_samples / rate * frame_rate - 1e-9))
    return as_int(n_frames, "n_frames", minimum=1)


def _sampled(xs: np.ndarray, values: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Linear interpolation at `times` of a Praat track; NaN propagates, the ends are held."""
    if len(xs) == 1:
        return np.full(len(times), values[0])
    return np.interp(times, xs, values)


def praat_prosody(samples, rate: float, *, frame_rate: float, n_frames: int | None = None,
                  pitch_floor: float = PITCH_FLOOR_HZ,
                  pitch_ceiling: float = PITCH_CEILING_HZ) -> Prosody:
    """Praat's intensity and pitch of a signal, at the frames of a take.

    Parameters
    ----------
    samples : array_like of shape (n_samples,)
        Mono signal, full scale 1 (:func:`fit.gestures.speech.read_wav`). No NaN.
    rate : float, Hz
    frame_rate : float, Hz
        Frame k is at ``k / frame_rate`` s.
    n_frames : int, optional
        Default: every frame time within the signal.
    pitch_floor, pitch_ceiling : float, Hz
        Praat's pitch range (75-600, its defaults); the floor also sets the
        intensity's analysis window (3.2 / floor s, Praat's rule).

    Returns
    -------
    Prosody
        ``method="praat"``. Frames before the first or after the last analysis
        frame (half a window at each end) hold the nearest value; the pitch is
        NaN where Praat finds the frame unvoiced and where the interpolation
        would bridge a voiced and an unvoiced analysis frame.

    Raises
    ------
    MissingDependencyError
        praat-parselmouth is not installed.
    InputError
        Empty or NaN signal, a signal shorter than one analysis window, bad rates.

    Notes
    -----
    ``Sound: To Intensity`` (minimum pitch = `pitch_floor`, time step 5 ms,
    subtract mean) and ``Sound: To Pitch`` (autocorrelation, time step 5 ms),
    both sampled by linear interpolation at the frame times.
    """
    parselmouth = require("parselmouth", package="praat-parselmouth", extra="speech",
                          purpose="Praat's intensity and pitch")
    samples = as_float_array(samples, "samples", ndim=1, allow_nan=False)
    rate = as_positive_float(rate, "rate")
    frame_rate = as_positive_float(frame_rate, "frame_rate")
    floor = as_positive_float(pitch_floor, "pitch_floor")
    ceiling = as_positive_float(pitch_ceiling, "pitch_ceiling")
    if ceiling <= floor:
        raise InputError(f"pitch_ceiling ({ceiling:g} Hz) must be above pitch_floor "
                         f"({floor:g} Hz)")
    window = 3.2 / floor
    if len(samples) / rate < window:
        raise InputError(f"the signal lasts {len(samples) / rate:.3g} s, shorter than Praat's "
                         f"intensity window of {window:.3g} s (3.2 / pitch floor)")
    n_frames = _frames(len(samples), rate, frame_rate, n_frames)
    sound = parselmouth.Sound(samples, sampling_frequency=rate)
    times = np.arange(n_frames) / frame_rate
    intensity = sound.to_intensity(minimum_pitch=floor, time_step=_STEP_S, subtract_mean=True)
    level = _sampled(intensity.xs(), np.maximum(intensity.values[0], _FLOOR_DB), times)
    pitch = sound.to_pitch(time_step=_STEP_S, pitch_floor=floor, pitch_ceiling=ceiling)
    f0 = pitch.selected_array["frequency"].astype(float)
    f0[f0 <= 0] = np.nan
    return Prosody(read_only(level), read_only(_sampled(pitch.xs(), f0, times)), frame_rate,
                   "praat")


def rms_prosody(samples, rate: float, *, frame_rate: float, n_frames: int | None = None,
                window: float = DEFAULT_WINDOW_S) -> Prosody:
    """The RMS level of :func:`fit.gestures.speech.speech_intensity` as a :class:`Prosody`.

    Returns
    -------
    Prosody
        ``method="rms"``, dB re full scale, no pitch.
    """
    level = speech_intensity(samples, rate, frame_rate=frame_rate, n_frames=n_frames,
                             window=window)
    return Prosody(read_only(level), None, as_positive_float(frame_rate, "frame_rate"), "rms")


def speech_prosody(path, *, frame_rate: float, n_frames: int | None = None,
                   method: str = "auto", window: float = DEFAULT_WINDOW_S) -> Prosody:
    """Loudness (and with Praat, pitch) of a WAV file at `frame_rate`.

    Parameters
    ----------
    path : str or os.PathLike
        WAV file (:func:`fit.gestures.speech.read_wav`).
    frame_rate : float, Hz
    n_frames : int, optional
    method : {"auto", "praat", "rms"}
        See :data:`PROSODY_METHODS`.
    window : float, s
        RMS window of ``"rms"``.

    Returns
    -------
    Prosody

    Raises
    ------
    MissingDependencyError
        ``method="praat"`` without the ``speech`` extra.
    FileFormatError
        An unreadable WAV file.

    Warns
    -----
    UserWarning
        ``"auto"`` fell back to the RMS level.
    """
    method = as_choice(method, "method", PROSODY_METHODS)
    samples, rate = read_wav(path)
    if method == "auto":
        method = "praat" if available("parselmouth") else "rms"
        if method == "rms":
            warnings.warn(f"{Path(path).name}: praat-parselmouth is not installed (pip install "
                          "'mocap2mesh[speech]'): S(t) is the RMS level, without pitch",
                          stacklevel=2)
    if method == "praat":
        return praat_prosody(samples, rate, frame_rate=frame_rate, n_frames=n_frames)
    return rms_prosody(samples, rate, frame_rate=frame_rate, n_frames=n_frames, window=window)
