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

from fit.gestures.analysis import (
    DETAIL_GROUPS,
    ESTIMATORS,
    LIP_REGIONS,
    GestureAnalysis,
    analyze_gestures,
)
from fit.gestures.clip import (
    GestureClip,
    clip_from_analysis,
    clip_from_performance,
    load_clip,
    save_clip,
)
from fit.gestures.features import (
    DETAIL_FEATURES,
    FEATURES,
    WEIGHT_FEATURES,
    WEIGHT_PATTERNS,
    weight_columns,
)
from fit.gestures.mrf import (
    GestureSynthesis,
    candidate_distances,
    pick_candidate,
    synthesize_gestures,
)
from fit.gestures.reference import CaptureClip, clip_from_capture
from fit.gestures.speech import (
    analog_intensity,
    opening_intensity,
    read_wav,
    speech_intensity,
    wav_intensity,
)
from fit.gestures.lipsync import TalkingFace, lip_region, talking_face
from fit.gestures.phones import (
    PhoneSegments,
    phones_from_wav,
    read_phones_csv,
    read_sphinx_alignment,
    recognize_phones,
    write_phones_csv,
)
from fit.gestures.prosody import Prosody, praat_prosody, rms_prosody, speech_prosody
from fit.gestures.talking import SpeechAnalysis, analyze_speech
from fit.gestures.timeline import Segment, Timeline, load_timeline, parse_timeline
from fit.gestures.viseme_basis import (
    ARKIT_VISEMES,
    VisemeBasis,
    load_viseme_basis,
    viseme_basis_from_shapes,
)
from fit.gestures.visemes import PHONE_VISEMES, VISEMES, VisemeCurves, viseme_curves
from mocap.util.deprecation import moved_names

__all__ = ["GestureAnalysis", "analyze_gestures", "DETAIL_GROUPS",
           "LIP_REGIONS", "ESTIMATORS",
           "GestureClip", "clip_from_analysis", "clip_from_performance", "load_clip", "save_clip",
           "CaptureClip", "clip_from_capture",
           "GestureSynthesis", "synthesize_gestures", "candidate_distances", "pick_candidate",
           "speech_intensity", "read_wav", "wav_intensity", "analog_intensity",
           "opening_intensity",
           "FEATURES", "WEIGHT_FEATURES", "DETAIL_FEATURES", "WEIGHT_PATTERNS", "weight_columns",
           "Segment", "Timeline", "load_timeline", "parse_timeline",
           "Prosody", "praat_prosody", "rms_prosody", "speech_prosody",
           "PhoneSegments", "recognize_phones", "phones_from_wav", "read_phones_csv",
           "write_phones_csv", "read_sphinx_alignment",
           "VISEMES", "PHONE_VISEMES", "VisemeCurves", "viseme_curves",
           "VisemeBasis", "ARKIT_VISEMES", "viseme_basis_from_shapes", "load_viseme_basis",
           "TalkingFace", "lip_region", "talking_face", "SpeechAnalysis", "analyze_speech"]



def _marker_basis_in_mm():
    from fit.solve.marker_basis import marker_basis

    return functools.partial(marker_basis, units="mm")


__getattr__ = moved_names(__name__, {
    "marker_basis": ("fit.solve.marker_basis:marker_basis(..., units='mm')",
                     _marker_basis_in_mm)})
