"""Expressive facial gestures (Ju & Lee 2008): decomposition of takes and speech-driven synthesis.

- :mod:`.analysis`: F = R N + Σ c_i B_i + P + Σ D_j + T from a stabilized take;
- :mod:`.speech`: speech intensity S(t) (RMS) from a WAV file or an analog channel;
- :mod:`.prosody`: Praat's intensity and pitch (the ``speech`` extra), RMS as the fallback;
- :mod:`.phones`: phone segments by PocketSphinx (recognition, forced alignment), CSV;
- :mod:`.visemes`: phones to viseme classes, viseme weights with coarticulation;
- :mod:`.viseme_basis`: the viseme shapes on the target face (OBJs, ARKit combinations);
- :mod:`.lipsync`: the lip region from the visemes, the rest from the MRF;
- :mod:`.talking`: the driving speech analysed once (prosody, phones, visemes);
- :mod:`.video`, :mod:`.page`: the talking video with its sound, its HTML page;
- :mod:`.features`: the features, each synthesized by its own chain;
- :mod:`.clip`: reference clips (the palette of styles);
- :mod:`.reference`: reference clips from captures (``mocap2mesh gestures analyze``);
- :mod:`.timeline`: styles painted on time segments, per feature;
- :mod:`.mrf`: the Markov random field synthesis;
- :mod:`.transfer`: details moved to a target face by compact RBFs, mesh outputs.
"""

import functools

from mocap.util.deprecation import moved_names
from mocap.util.lazy import lazy_names

#: Each module's public names, imported when one is first read (:mod:`mocap.util.lazy`): the
#: reconstruction needs :mod:`.transfer` alone, without the speech analysis' imports.
_NAMES = {
    "analysis": ["GestureAnalysis", "analyze_gestures", "DETAIL_GROUPS", "LIP_REGIONS",
                 "ESTIMATORS"],
    "clip": ["GestureClip", "clip_from_analysis", "clip_from_performance", "load_clip",
             "save_clip"],
    "reference": ["CaptureClip", "clip_from_capture"],
    "mrf": ["GestureSynthesis", "synthesize_gestures", "candidate_distances", "pick_candidate"],
    "speech": ["speech_intensity", "read_wav", "wav_intensity", "analog_intensity",
               "opening_intensity"],
    "features": ["FEATURES", "WEIGHT_FEATURES", "DETAIL_FEATURES", "WEIGHT_PATTERNS",
                 "weight_columns"],
    "timeline": ["Segment", "Timeline", "load_timeline", "parse_timeline"],
    "prosody": ["Prosody", "praat_prosody", "rms_prosody", "speech_prosody"],
    "phones": ["PhoneSegments", "recognize_phones", "phones_from_wav", "read_phones_csv",
               "write_phones_csv", "read_sphinx_alignment"],
    "visemes": ["VISEMES", "PHONE_VISEMES", "VisemeCurves", "viseme_curves"],
    "viseme_basis": ["VisemeBasis", "ARKIT_VISEMES", "viseme_basis_from_shapes",
                     "load_viseme_basis"],
    "lipsync": ["TalkingFace", "lip_region", "talking_face"],
    "talking": ["SpeechAnalysis", "analyze_speech"],
}

__all__ = [name for names in _NAMES.values() for name in names]


def _marker_basis_in_mm():
    from fit.solve.marker_basis import marker_basis

    return functools.partial(marker_basis, units="mm")


__getattr__, __dir__ = lazy_names(__name__, _NAMES, otherwise=moved_names(__name__, {
    "marker_basis": ("fit.solve.marker_basis:marker_basis(..., units='mm')",
                     _marker_basis_in_mm)}, wrapped=True))
