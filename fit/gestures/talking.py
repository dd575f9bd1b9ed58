"""The driving speech analysed once for a talking face: loudness and pitch, phones, visemes.

What ``mocap2mesh gestures synthesize`` runs on its WAV before the MRF:
:func:`fit.gestures.prosody.speech_prosody` gives S̃(t) (and F0) at the frame
rate; the phones come from a phones CSV or from PocketSphinx
(:func:`fit.gestures.phones.recognize_phones`, aligned to a transcript when one
is given); :func:`fit.gestures.visemes.viseme_curves` turns them into the viseme
weights d̃_l(t) on the same frames.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

from fit.gestures.phones import PhoneSegments, phones_from_wav, read_phones_csv
from fit.gestures.prosody import Prosody, speech_prosody
from fit.gestures.speech import DEFAULT_WINDOW_S
from fit.gestures.visemes import VisemeCurves, viseme_curves
from mocap.errors import InputError
from mocap.util.atomic import atomic_path

__all__ = ["SpeechAnalysis", "analyze_speech", "write_prosody_csv"]


@dataclass(frozen=True, eq=False)
class SpeechAnalysis:
    """The driving speech at the synthesis frames.

    Attributes
    ----------
    prosody : Prosody
        S̃(t) and, with Praat, F0(t).
    phones : PhoneSegments or None
        None without lips.
    visemes : VisemeCurves or None
        d̃_l(t), as many frames as `prosody`; None without lips.
    """

    prosody: Prosody
    phones: PhoneSegments | None
    visemes: VisemeCurves | None

    @property
    def message(self) -> str:
        """What was measured and how, one line."""
        lips = "no lips" if self.phones is None else \
            f"{len(self.phones)} phones ({self.phones.source})"
        return f"{self.prosody.n_frames} frames; S(t) {self.prosody.source}; {lips}"


def analyze_speech(wav, *, rate: float, intensity: str = "auto",
                   window: float = DEFAULT_WINDOW_S, lips: bool = True,
                   transcript: str | None = None, recognizer: str = "phones",
                   phones=None) -> SpeechAnalysis:
    """Prosody, phones and viseme curves of a speech WAV at `rate`.

    Parameters
    ----------
    wav : str or os.PathLike
    rate : float, Hz
        Synthesis frame rate.
    intensity : {"auto", "praat", "rms"}
        :data:`fit.gestures.prosody.PROSODY_METHODS`.
    window : float, s
        RMS window of ``"rms"``.
    lips : bool
        False: no phones, no visemes (the MRF alone).
    transcript : str, optional
        Words spoken, or a file of them: forced alignment.
    recognizer : {"phones", "words"}
        Recognition without a transcript.
    phones : str or os.PathLike or PhoneSegments, optional
        Phone segments to use instead of recognizing them (a phones CSV).

    Returns
    -------
    SpeechAnalysis

    Raises
    ------
    InputError
        `phones` or `transcript` given with ``lips=False``, both given.
    MissingDependencyError
        Praat or PocketSphinx needed and the ``speech`` extra not installed.
    """
    if not lips and (phones is not None or transcript is not None):
        raise InputError("phones and a transcript are for the lips: drop them or the no-lips "
                         "option")
    if phones is not None and transcript is not None:
        raise InputError("give phone segments or a transcript to align, not both")
    prosody = speech_prosody(wav, frame_rate=rate, method=intensity, window=window)
    if not lips:
        return SpeechAnalysis(prosody, None, None)
    if phones is None:
        segments = phones_from_wav(wav, transcript=transcript, recognizer=recognizer)
    elif isinstance(phones, PhoneSegments):
        segments = phones
    else:
        segments = read_phones_csv(phones)
    curves = viseme_curves(segments, rate=rate, n_frames=prosody.n_frames)
    return SpeechAnalysis(prosody, segments, curves)


def write_prosody_csv(path, prosody: Prosody, *, inputs=()) -> None:
    """Write ``frame,time,intensity_db,pitch_hz`` rows (pitch empty where unvoiced)."""
    if not isinstance(prosody, Prosody):
        raise InputError(f"prosody must be a Prosody, got {type(prosody).__name__}")
    buf = io.StringIO()
    out = csv.writer(buf, lineterminator="\n")
    out.writerow(("frame", "time", "intensity_db", "pitch_hz"))
    pitch = prosody.pitch
    for k, level in enumerate(prosody.intensity):
        f0 = "" if pitch is None or pitch[k] != pitch[k] else f"{pitch[k]:.2f}"
        out.writerow((k, f"{k / prosody.rate:.4f}", f"{level:.3f}", f0))
    with atomic_path(path, inputs=inputs) as tmp:
        Path(tmp).write_text(buf.getvalue(), encoding="utf-8")
