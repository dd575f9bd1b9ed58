"""Visemes: ARPAbet phones to the paper's viseme classes, weight curves with coarticulation.

Ju & Lee (2008, Fig. 7) animate the lips with a basis of visemes P̃_l: the
vowels /a/ /e/ /i/ /o/ /u/ /eu/ /eo/ (Korean ㅏ ㅔ ㅣ ㅗ ㅜ ㅡ ㅓ), a consonant
with open lips, a consonant with closed lips, and the neutral face. English
needs one class more, the labiodental /f v/ (lower lip under the upper teeth),
so the classes are :data:`VISEMES`. :data:`PHONE_VISEMES` maps each ARPAbet
phone (CMUdict's 39, stress digits ignored) to one class, or to two for the
diphthongs, whose segment is split in halves:

============  ==========================================  =======================
viseme        phones                                      lips
============  ==========================================  =======================
``a``         AA AE, the first half of AW AY              jaw wide open
``e``         EH, the first half of EY                    open, spread
``i``         IH IY Y, the second half of AY EY OY        nearly closed, spread
``o``         AO, the first half of OW OY                 open, rounded
``u``         UH UW W, the second half of AW OW           rounded, protruded
``eu``        ER                                          narrow, unrounded
``eo``        AH                                          half open, relaxed
``open``      T D N L S Z TH DH K G NG HH R SH ZH CH JH   teeth apart, lips follow
                                                          the neighbouring vowels
``closed``    P B M                                       lips pressed together
``labiodental`` F V                                       lower lip to upper teeth
``neutral``   SIL and the recognizer's noise units        at rest
============  ==========================================  =======================

Coarticulation: dominance functions (Cohen & Massaro 1993). Each segment s
has a dominance over time, ``D_s(t) = α_s exp(−θ_s δ_s(t))`` with δ_s the
distance in s from t to the segment (0 inside it), and the weight of viseme l
at t is the share of the dominance of the segments of class l,
``d_l(t) = Σ_{s ∈ l} D_s(t) / Σ_s D_s(t)``: the weights sum to 1. Vowels and
the lip consonants dominate strongly (α = 1); the other consonants weakly
(α = 0.4), so that the lips keep the shape of the neighbouring vowels through
a /t/ or an /n/, as real lips do. Bilabial closure is a hard constraint of
speech, which a blend of dominances does not guarantee: frames inside a
/p b m/ segment are set to ``closed`` (a segment holding no frame time closes
its nearest frame, so that no closure is skipped at the frame rate).
"""

from __future__ import annotations

import csv
import io
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fit.gestures.phones import PhoneSegments
from mocap.errors import InputError
from mocap.util.arrays import read_only
from mocap.util.atomic import atomic_path
from mocap.util.validation import as_int, as_positive_float

__all__ = ["VISEMES", "PHONE_VISEMES", "DOMINANCE", "VisemeCurves", "phone_visemes",
           "viseme_curves", "write_visemes_csv", "NEUTRAL", "CLOSED"]

#: Viseme classes: the paper's ten and the labiodental.
VISEMES = ("a", "e", "i", "o", "u", "eu", "eo", "open", "closed", "labiodental", "neutral")
NEUTRAL, CLOSED = "neutral", "closed"
_V = {  # one class per phone, or two (the halves of a diphthong)
    "AA": "a", "AE": "a", "AH": "eo", "AO": "o", "AW": "a u", "AY": "a i", "EH": "e",
    "ER": "eu", "EY": "e i", "IH": "i", "IY": "i", "OW": "o u", "OY": "o i", "UH": "u",
    "UW": "u", "B": "closed", "M": "closed", "P": "closed", "F": "labiodental",
    "V": "labiodental", "W": "u", "Y": "i", "SIL": "neutral",
    **{p: "open" for p in "T D N L S Z TH DH K G NG HH R SH ZH CH JH".split()},
}
#: ARPAbet phone to its viseme classes (see the module docstring).
PHONE_VISEMES = {p: tuple(v.split()) for p, v in _V.items()}
#: Dominance of each class: magnitude α and rate θ, 1/s (``exp(−θ δ)``: θ = 15 falls
#: to a third 75 ms from the segment, about a syllable's reach of anticipation).
DOMINANCE = {
    **{v: (1.0, 15.0) for v in ("a", "e", "i", "o", "u", "eu", "eo")},
    "open": (0.4, 25.0),
    "closed": (1.0, 30.0),
    "labiodental": (1.0, 30.0),
    "neutral": (0.7, 10.0),
}
#: Segments farther than this from a frame have no dominance over it, s
#: (exp(−10 · 1.2) < 1e-5 of the weakest rate's dominance).
_REACH_S = 1.2
_NOISE = re.compile(r"^\+.*\+$|^<.*>$")


def phone_visemes(phone: str) -> tuple:
    """The viseme classes of one ARPAbet phone (stress digits ignored).

    Examples
    --------
    >>> phone_visemes("AY1"), phone_visemes("m"), phone_visemes("+NSN+")
    (('a', 'i'), ('closed',), ('neutral',))
    """
    label = str(phone).strip().upper().rstrip("012")
    if _NOISE.match(label):
        return (NEUTRAL,)
    if label not in PHONE_VISEMES:
        raise InputError(f"unknown phone {phone!r}: expected an ARPAbet phone of CMUdict "
                         f"({' '.join(sorted(PHONE_VISEMES))}) or a noise unit like +NSN+")
    return PHONE_VISEMES[label]


@dataclass(frozen=True, eq=False)
class VisemeCurves:
    """Viseme weights d̃_l(t) at a frame rate.

    Attributes
    ----------
    weights : ndarray of shape (n_frames, n_visemes)
        Non-negative, each row sums to 1 (``neutral`` included).
    names : tuple of str
        :data:`VISEMES`.
    rate : float, Hz
        Frame k is at ``k / rate`` s.
    closed : ndarray of shape (n_frames,), bool
        Frames held closed by the bilabial constraint.
    """

    weights: np.ndarray
    names: tuple
    rate: float
    closed: np.ndarray

    @property
    def n_frames(self) -> int:
        """Number of frames T."""
        return len(self.weights)


def _units(segments: PhoneSegments) -> tuple:
    """Viseme-class segments: diphthongs split in halves. Returns start, end, class index."""
    start, end, cls = [], [], []
    for a, b, p in zip(segments.start, segments.end, segments.phone):
        classes = phone_visemes(p)
        cuts = np.linspace(a, b, len(classes) + 1)
        for k, c in enumerate(classes):
            start.append(cuts[k])
            end.append(cuts[k + 1])
            cls.append(VISEMES.index(c))
    return np.array(start), np.array(end), np.array(cls, dtype=np.int64)


def viseme_curves(segments: PhoneSegments, *, rate: float, n_frames: int | None = None,
                  dominance=None) -> VisemeCurves:
    """Viseme weights at the frames of a take from phone segments, with coarticulation.

    Parameters
    ----------
    segments : PhoneSegments
        ARPAbet phones (:func:`fit.gestures.phones.recognize_phones`, a phones CSV).
    rate : float, Hz
    n_frames : int, optional
        Default: every frame time up to the last segment's end.
    dominance : mapping of str to (float, float), optional
        α and θ (1/s) per viseme class, overriding :data:`DOMINANCE`.

    Returns
    -------
    VisemeCurves
        Frames beyond every segment's reach are ``neutral``.

    Raises
    ------
    InputError
        An unknown phone, a class of `dominance` not in :data:`VISEMES`, α or θ
        not positive.

    Notes
    -----
    See the module docstring. Vectorized over frames: each frame sees the
    segments within 1.2 s of it (a band of the frame × segment matrix).

    Examples
    --------
    >>> segs = PhoneSegments([0.0, 0.3, 0.4], [0.3, 0.4, 0.8], ["AA", "M", "AA"],
    ...                      [1.0, 1.0, 1.0])
    >>> d = viseme_curves(segs, rate=10)
    >>> d.weights[[3, 4, 6], d.names.index("closed")].round(2).tolist()   # 0.3, 0.4, 0.6 s
    [1.0, 0.45, 0.0]
    >>> bool(np.allclose(d.weights.sum(axis=1), 1))
    True
    """
    if not isinstance(segments, PhoneSegments):
        raise InputError(f"segments must be PhoneSegments, got {type(segments).__name__}")
    rate = as_positive_float(rate, "rate")
    params = dict(DOMINANCE)
    for name, value in (dominance or {}).items():
        if name not in VISEMES:
            raise InputError(f"dominance: unknown viseme {name!r}; expected one of "
                             f"{list(VISEMES)}")
        alpha, theta = (float(x) for x in value)
        if not (alpha > 0 and theta > 0 and np.isfinite(alpha + theta)):
            raise InputError(f"dominance of {name!r}: alpha and theta must be positive, got "
                             f"{value!r}")
        params[name] = (alpha, theta)
    if n_frames is None:
        n_frames = max(1, int(np.floor(segments.end[-1] * rate + 1e-9)) + 1) if len(segments) \
            else 1
    n_frames = as_int(n_frames, "n_frames", minimum=1)
    times = np.arange(n_frames) / rate
    names = VISEMES
    weights = np.zeros((n_frames, len(names)))
    closed = np.zeros(n_frames, bool)
    if len(segments) == 0:
        weights[:, names.index(NEUTRAL)] = 1.0
        return VisemeCurves(read_only(weights), names, rate, read_only(closed))
    start, end, cls = _units(segments)
    alpha = np.array([params[v][0] for v in names])[cls]
    theta = np.array([params[v][1] for v in names])[cls]
    # The band of segments each frame sees: [lo, hi) by the reach.
    lo = np.searchsorted(end, times - _REACH_S, side="left")
    hi = np.searchsorted(start, times + _REACH_S, side="right")
    width = max(1, int((hi - lo).max()))
    idx = lo[:, None] + np.arange(width)[None]
    valid = idx < hi[:, None]
    idx = np.minimum(idx, len(cls) - 1)
    gap = np.maximum(np.maximum(start[idx] - times[:, None], times[:, None] - end[idx]), 0.0)
    dom = np.where(valid, alpha[idx] * np.exp(-theta[idx] * gap), 0.0)
    np.add.at(weights, (np.repeat(np.arange(n_frames), width), cls[idx].ravel()), dom.ravel())
    total = weights.sum(axis=1)
    weights[total == 0, names.index(NEUTRAL)] = 1.0
    weights /= weights.sum(axis=1, keepdims=True)
    closed = _closure(start, end, cls == names.index(CLOSED), times, rate)
    weights[closed] = 0.0
    weights[closed, names.index(CLOSED)] = 1.0
    return VisemeCurves(read_only(weights), names, rate, read_only(closed))


def _closure(start, end, bilabial, times, rate) -> np.ndarray:
    """Frames inside a bilabial segment, and the nearest frame of those holding none."""
    closed = np.zeros(len(times), bool)
    a, b = start[bilabial], end[bilabial]
    first = np.ceil(a * rate - 1e-9).astype(np.int64)      # first frame at or after a
    last = np.ceil(b * rate - 1e-9).astype(np.int64) - 1   # last frame before b
    n = len(times)
    inside = first <= last
    marks = np.zeros(n + 1, np.int64)
    np.add.at(marks, np.clip(first[inside], 0, n), 1)
    np.add.at(marks, np.clip(last[inside] + 1, 0, n), -1)
    closed |= np.cumsum(marks)[:n] > 0
    nearest = np.clip(np.round((a[~inside] + b[~inside]) / 2 * rate).astype(np.int64), 0, n - 1)
    closed[nearest] = True
    return closed


def write_visemes_csv(path, curves: VisemeCurves, *, inputs=()) -> None:
    """Write ``frame,time,<viseme>...`` rows (time in s, weights 0-1), atomically."""
    if not isinstance(curves, VisemeCurves):
        raise InputError(f"curves must be VisemeCurves, got {type(curves).__name__}")
    buf = io.StringIO()
    out = csv.writer(buf, lineterminator="\n")
    out.writerow(("frame", "time", *curves.names))
    for k, row in enumerate(curves.weights):
        out.writerow((k, f"{k / curves.rate:.4f}", *(f"{w:.5f}" for w in row)))
    with atomic_path(path, inputs=inputs) as tmp:
        Path(tmp).write_text(buf.getvalue(), encoding="utf-8")
