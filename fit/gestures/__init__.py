"""Expressive facial gestures (Ju & Lee 2008): decomposition of takes and speech-driven synthesis.

- :mod:`.analysis`: F = R N + Σ c_i B_i + P + Σ D_j + T from a stabilized take;
- :mod:`.speech`: speech intensity S(t) from a WAV file or an analog channel;
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
from fit.gestures.timeline import Segment, Timeline, load_timeline, parse_timeline
from mocap.util.deprecation import moved_names

__all__ = ["GestureAnalysis", "analyze_gestures", "DETAIL_GROUPS",
           "LIP_REGIONS", "ESTIMATORS",
           "GestureClip", "clip_from_analysis", "clip_from_performance", "load_clip", "save_clip",
           "CaptureClip", "clip_from_capture",
           "GestureSynthesis", "synthesize_gestures", "candidate_distances", "pick_candidate",
           "speech_intensity", "read_wav", "wav_intensity", "analog_intensity",
           "opening_intensity",
           "FEATURES", "WEIGHT_FEATURES", "DETAIL_FEATURES", "WEIGHT_PATTERNS", "weight_columns",
           "Segment", "Timeline", "load_timeline", "parse_timeline"]



def _marker_basis_in_mm():
    from fit.solve.marker_basis import marker_basis

    return functools.partial(marker_basis, units="mm")


__getattr__ = moved_names(__name__, {
    "marker_basis": ("fit.solve.marker_basis:marker_basis(..., units='mm')",
                     _marker_basis_in_mm)})
