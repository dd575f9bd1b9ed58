"""Reference clips from captures: ingestion, decomposition and speech intensity in one call.

What ``mocap2mesh gestures analyze`` runs: the capture is gap-filled, resampled
to the synthesis rate and head-stabilized (:func:`mocap.clean.ingest.ingest`); the
expression shapes are sampled at the bound markers (:func:`fit.solve.marker_basis.marker_basis`); the
take is decomposed (:func:`analyze_gestures`); S(t) comes from a WAV file
recorded with the take, from one of its analog channels, or, failing both,
from a stand-in: the loudness of the lip opening. A WAV's S(t) is Praat's
intensity when the ``speech`` extra is installed, its RMS level otherwise
(:func:`fit.gestures.prosody.speech_prosody`).
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass

from basis.artist import ArtistBasis
from fit.gestures.analysis import GestureAnalysis, analyze_gestures
from fit.gestures.clip import GestureClip, clip_from_analysis
from fit.gestures.prosody import speech_prosody
from fit.gestures.speech import (
    DEFAULT_WINDOW_S,
    OPENING_WINDOW_S,
    analog_intensity,
    opening_intensity,
)
from fit.solve.marker_basis import marker_basis
from mocap.bind import Binding
from mocap.clean.ingest import IngestOptions, ingest
from mocap.errors import InputError
from mocap.markerset import MarkerSet
from mocap.neutral import find_neutral
from mocap.take import Take

__all__ = ["CaptureClip", "clip_from_capture", "OPENING_LANDMARKS"]

#: Marker-set landmarks whose distance stands in for speech when there is no audio.
OPENING_LANDMARKS = ("upper_lip_top", "lower_lip_bottom")


@dataclass(frozen=True, eq=False)
class CaptureClip:
    """A reference clip made from a capture, and how.

    Attributes
    ----------
    clip : GestureClip
    analysis : GestureAnalysis
    neutral_frame : int
        Frame index (at the clip's rate) whose stabilized markers are N.
    message : str
    """

    clip: GestureClip
    analysis: GestureAnalysis
    neutral_frame: int
    message: str

    @property
    def intensity_source(self) -> str:
        """What S(t) was made of (``clip.intensity_source``)."""
        return self.clip.intensity_source


def _intensity(markerset, cleaned: Take, stabilized: Take, wav, analog, opening, window,
               method):
    """S(t) at the frames of the take and the sentence that says what it is."""
    given = [x is not None for x in (wav, analog, opening)]
    if sum(given) > 1:
        raise InputError("give one source of speech intensity: a WAV file, an analog channel "
                         "or a lip-marker pair")
    if wav is not None:
        prosody = speech_prosody(wav, frame_rate=cleaned.rate, n_frames=cleaned.n_frames,
                                 method=method, window=window or DEFAULT_WINDOW_S)
        return prosody.intensity, f"{prosody.source} of {wav}"
    if analog is not None:
        return (analog_intensity(cleaned, analog, window=window or DEFAULT_WINDOW_S),
                f"speech: RMS dB of analog channel {analog!r}")
    if opening is None:
        absent = [x for x in OPENING_LANDMARKS if x not in markerset.landmarks]
        if absent:
            raise InputError(f"no speech given (a WAV file or an analog channel) and the "
                             f"marker set has no landmarks {absent} for the lip-opening "
                             f"stand-in: name the two lip markers")
        opening = tuple(markerset.landmarks[x] for x in OPENING_LANDMARKS)
    upper, lower = opening
    source = (f"stand-in (no audio): loudness of the lip opening {upper}-{lower}, RMS dB "
              f"over {window or OPENING_WINDOW_S:g} s")
    return (opening_intensity(stabilized, upper, lower, window=window or OPENING_WINDOW_S),
            source)


def clip_from_capture(take: Take, markerset: MarkerSet, binding: Binding, basis: ArtistBasis,
                      *, name: str, rate: float = 30.0, wav=None, analog: str | None = None,
                      opening=None, intensity_window: float | None = None,
                      intensity: str = "auto",
                      options: IngestOptions | None = None, neutral_frame="auto",
                      epsilon: float = 0.1, window: int = 41, estimator: str = "exact",
                      seed=0) -> CaptureClip:
    """Build a reference clip of the gesture palette from a raw capture.

    Parameters
    ----------
    take : Take
        The capture as read (:func:`mocap.read`), mm, NaN where missing.
    markerset : MarkerSet
        Head markers, regions (lips, brows, eyes:
        :data:`fit.gestures.analysis.DETAIL_GROUPS`) and,
        for the default intensity, the landmarks of :data:`OPENING_LANDMARKS`.
    binding : Binding
        The capture's markers bound to ``basis.neutral`` in the head frame
        (``mocap2mesh bind --stabilize``); every region marker must be bound.
    basis : ArtistBasis
        The expression shapes whose weights the clip holds.
    name : str
        Style name of the clip.
    rate : float, Hz, default 30
        The clip's frame rate: the synthesis rate.
    wav : str or os.PathLike, optional
        Speech recorded with the take, starting at its first frame.
    analog : str, optional
        Analog channel of the take holding the speech (a microphone).
    opening : pair of str, optional
        Upper and lower lip markers for the stand-in; default: the marker
        set's :data:`OPENING_LANDMARKS`. Used when neither `wav` nor `analog`
        is given, with a warning.
    intensity_window : float, s, optional
        RMS window (default 0.05 s for speech, 0.25 s for the stand-in).
    intensity : {"auto", "praat", "rms"}
        How a WAV's loudness is measured
        (:data:`fit.gestures.prosody.PROSODY_METHODS`).
    options : IngestOptions, optional
        Swap repair, removal of implausible samples, gap filling and low-pass;
        resampling to `rate` and stabilization are always on (default:
        ``fill="auto"``).
    neutral_frame : int, "auto" or "hold"
        Frame index at `rate` of the neutral N, or picked on the stabilized
        region markers: the frame closest to their median pose, or the neutral
        hold the take starts with (:func:`mocap.neutral.resolve_neutral_frame`),
        whose window's mean pose (:func:`mocap.neutral.find_neutral`) is then N.
    epsilon, window, estimator, seed
        Of :func:`analyze_gestures`.

    Returns
    -------
    CaptureClip

    Raises
    ------
    InputError
        Two intensity sources, no source and no stand-in landmarks, a neutral
        frame beyond the take, bad options.
    MarkerError
        A marker-set marker absent from the take or a region marker absent from
        the binding.
    FileFormatError
        An unreadable WAV file.

    Warns
    -----
    UserWarning
        S(t) is the lip-opening stand-in.
    """
    for value, kind, label in ((markerset, MarkerSet, "markerset"), (binding, Binding, "binding"),
                               (basis, ArtistBasis, "basis"), (take, Take, "take")):
        if not isinstance(value, kind):
            raise InputError(f"{label} must be a {kind.__name__}, got {type(value).__name__}")
    options = dataclasses.replace(options or IngestOptions(), resample_hz=rate, stabilize=True)
    ingested = ingest(take, markerset=markerset, options=options)
    stab = ingested.stabilization
    labels = tuple(x for members in markerset.regions.values() for x in members)
    found = find_neutral(stab.take, neutral_frame, labels=labels)
    neutral, neutral_frame = found.pose, found.frame
    level, source = _intensity(markerset, ingested.cleaned, stab.take, wav, analog,
                               opening, intensity_window, intensity)
    if source.startswith("stand-in"):
        warnings.warn(f"S(t) is a {source}", stacklevel=2)
    shapes = marker_basis(binding, basis.displacements, labels, mesh=basis.neutral, units="mm")
    analysis = analyze_gestures(stab, neutral, shapes, markerset, labels=labels,
                                names=basis.names, epsilon=epsilon, window=window,
                                estimator=estimator, seed=seed)
    clip = clip_from_analysis(analysis, level, name=name, intensity_source=source)
    message = (f"clip {name!r}: {analysis.message}; neutral frame {neutral_frame}; "
               f"S(t) {source}")
    return CaptureClip(clip, analysis, neutral_frame, message)
