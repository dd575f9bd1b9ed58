"""Phone segments of speech: CMU PocketSphinx recognition and forced alignment, CSV files.

The lips of the synthesized face come from the phones of the driving speech
(Ju & Lee 2008, sec. 5: "d̃_l's are determined from the phoneme analysis of the
driving speech signal"). PocketSphinx (``pocketsphinx``, BSD, in the optional
extra ``mocap2mesh[speech]``) ships its US-English acoustic model, pronouncing
dictionary (CMUdict) and language models inside the wheel: nothing is
downloaded at run time. Three ways:

- ``align`` (a transcript is given): forced alignment of its words, each word
  expanded to its dictionary pronunciation, optional silences between words;
- ``words`` (no transcript): large-vocabulary word recognition with the
  model's trigram language model, then forced alignment of the recognized words;
- ``phones`` (no transcript): phone recognition with the model's phonetic
  language model ("allphone" search), ~3x faster than ``words``, more phone errors.

Phones are ARPAbet without stress (CMUdict's 39 phones), ``SIL`` for silence,
``+NSN+``-style labels for the model's noise units.
"""

from __future__ import annotations

import csv
import io
import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.signal

from fit.gestures.speech import read_wav
from mocap.errors import FileFormatError, InputError
from mocap.util.arrays import read_only
from mocap.util.atomic import atomic_path
from mocap.util.optional import require
from mocap.util.validation import as_choice, as_float_array, as_positive_float

__all__ = ["PhoneSegments", "recognize_phones", "phones_from_wav", "write_phones_csv",
           "read_phones_csv", "read_sphinx_alignment", "read_transcript", "RECOGNIZERS",
           "MODEL_RATE", "CSV_COLUMNS"]

#: Recognition without a transcript (see the module docstring).
RECOGNIZERS = ("phones", "words")
#: Sampling rate of PocketSphinx's US-English model, Hz; other rates are resampled.
MODEL_RATE = 16000
#: Columns of a phones CSV: seconds, seconds, ARPAbet label, 0-1.
CSV_COLUMNS = ("start", "end", "phone", "confidence")
#: Beams of the phone search: wider than the word search's, as CMU Sphinx advises for
#: phone recognition (lw: language weight of the phone LM).
_ALLPHONE_OPTIONS = dict(lw=2.0, beam=1e-20, pbeam=1e-20, backtrace=True)
_WORD = re.compile(r"[a-z0-9']+")


@dataclass(frozen=True, eq=False)
class PhoneSegments:
    """Contiguous or gapped phone segments of an utterance.

    Attributes
    ----------
    start, end : ndarray of shape (n,), s
        ``start < end``, segments in time order, not overlapping.
    phone : tuple of str
        ARPAbet label of each segment (upper case), ``SIL`` for silence.
    confidence : ndarray of shape (n,)
        In [0, 1]. From PocketSphinx: the segment's acoustic score relative to
        the best score of its frames, as ``1.0001 ** score`` (what
        ``pocketsphinx align`` reports as ``p``; 1 = nothing scored better). Not
        a calibrated posterior.
    source : str
        How the segments were made, for the record.
    """

    start: np.ndarray
    end: np.ndarray
    phone: tuple
    confidence: np.ndarray
    source: str = ""

    def __post_init__(self):
        start = as_float_array(self.start, "start", ndim=1, allow_nan=False)
        n = len(start)
        end = as_float_array(self.end, "end", shape=(n,), allow_nan=False)
        conf = as_float_array(self.confidence, "confidence", shape=(n,), allow_nan=False)
        phone = tuple(str(p).upper() for p in self.phone)
        if len(phone) != n:
            raise InputError(f"{n} segments but {len(phone)} phone labels")
        bad = np.flatnonzero(end <= start)
        if bad.size:
            i = int(bad[0])
            raise InputError(f"phone segment {i} ({phone[i]}) ends at {end[i]:g} s, not after "
                             f"its start {start[i]:g} s")
        bad = np.flatnonzero(start[1:] < end[:-1] - 1e-9)
        if bad.size:
            i = int(bad[0])
            raise InputError(f"phone segments {i} and {i + 1} overlap or are out of order "
                             f"({start[i]:g}-{end[i]:g} s, {start[i + 1]:g}-{end[i + 1]:g} s)")
        if (start < 0).any() or ((conf < 0) | (conf > 1)).any():
            raise InputError("phone segments need start >= 0 and confidence in [0, 1]")
        if any(not p or p.isspace() for p in phone):
            raise InputError("a phone label is empty")
        object.__setattr__(self, "start", read_only(start))
        object.__setattr__(self, "end", read_only(end))
        object.__setattr__(self, "confidence", read_only(conf))
        object.__setattr__(self, "phone", phone)

    def __len__(self) -> int:
        return len(self.phone)

    def at(self, times) -> np.ndarray:
        """Index of the segment holding each time (``start <= t < end``), -1 for none.

        Examples
        --------
        >>> segs = PhoneSegments([0.0, 0.2], [0.2, 0.5], ["SIL", "AA"], [1.0, 1.0])
        >>> segs.at([0.1, 0.2, 0.49, 0.5]).tolist()
        [0, 1, 1, -1]
        """
        times = as_float_array(times, "times", ndim=1)
        k = np.searchsorted(self.start, times, side="right") - 1
        inside = (k >= 0) & (times < self.end[np.maximum(k, 0)])
        return np.where(inside, k, -1)

    def boundaries(self) -> np.ndarray:
        """Times where one segment ends or another starts, sorted, unique, s.

        The utterance's own ends (the first start, the last end) are left out.
        """
        times = np.concatenate([self.start[1:], self.end[:-1]])
        return np.unique(np.round(times, 6))


def read_transcript(value) -> str:
    """The words of ``--transcript TEXT|FILE``: a file's text if `value` names a file.

    Returns
    -------
    str
        Lower-case words (letters, digits, apostrophes) separated by single
        spaces; punctuation dropped.

    Raises
    ------
    InputError
        No words in it.
    FileFormatError
        A file that is not UTF-8 text.

    Examples
    --------
    >>> read_transcript("He was not an ill-disposed young man.")
    'he was not an ill disposed young man'
    """
    text = str(value)
    path = Path(text)
    where = "the transcript"
    try:
        is_file = "\n" not in text and path.is_file()
    except OSError:                      # a long text is no file name
        is_file = False
    if is_file:
        where = str(path)
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise FileFormatError(path, f"cannot read the transcript as UTF-8 text: {exc}") \
                from None
    words = _WORD.findall(text.lower())
    if not words:
        raise InputError(f"{where} holds no words")
    return " ".join(words)


def _pcm16(samples: np.ndarray, rate: float) -> bytes:
    """The signal at :data:`MODEL_RATE` as 16-bit PCM bytes."""
    if rate != MODEL_RATE:
        up, down = MODEL_RATE, int(round(rate))
        g = np.gcd(up, down)
        samples = scipy.signal.resample_poly(samples, up // g, down // g)
    return (np.clip(samples, -1.0, 1.0 - 2.0 ** -15) * 32768.0).astype("<i2").tobytes()


def _decode(decoder, pcm: bytes) -> None:
    decoder.start_utt()
    decoder.process_raw(pcm, full_utt=True)
    decoder.end_utt()


def _check_words(decoder, text: str) -> None:
    absent = [w for w in dict.fromkeys(text.split()) if decoder.lookup_word(w) is None]
    if absent:
        raise InputError(f"the transcript's words {absent} are not in PocketSphinx's "
                         "pronouncing dictionary (CMUdict): spell them as words it has")


def _aligned(decoder, pcm: bytes, text: str) -> tuple:
    """Phone segments of the forced alignment of `text` (frames of 10 ms)."""
    _check_words(decoder, text)
    decoder.set_align_text(text)
    _decode(decoder, pcm)                    # word alignment, optional silences
    decoder.set_alignment()
    _decode(decoder, pcm)                    # phone and state alignment
    alignment = decoder.get_alignment()
    if alignment is None:
        raise InputError("PocketSphinx could not align the transcript with the speech "
                         "(is it the transcript of this recording?)")
    frate = float(decoder.config["frate"])
    logmath = decoder.get_logmath()
    rows = [(p.start / frate, (p.start + p.duration) / frate, p.name,
             min(1.0, logmath.exp(p.score))) for word in alignment for p in word]
    return tuple(zip(*rows)) if rows else ((), (), (), ())


def recognize_phones(samples, rate: float, *, transcript: str | None = None,
                     recognizer: str = "phones") -> PhoneSegments:
    """Phone segments of a speech signal, with or without its transcript.

    Parameters
    ----------
    samples : array_like of shape (n_samples,)
        Mono speech, full scale 1. No NaN. Resampled to 16 kHz if needed.
    rate : float, Hz
    transcript : str, optional
        The words spoken (:func:`read_transcript`): forced alignment.
    recognizer : {"phones", "words"}
        Without a transcript (:data:`RECOGNIZERS`, the module docstring).

    Returns
    -------
    PhoneSegments
        From the first analysis frame to the last, in 10 ms frames.

    Raises
    ------
    MissingDependencyError
        pocketsphinx is not installed.
    InputError
        Empty or NaN signal, a transcript word not in the dictionary, an
        alignment that fails, nothing recognized.
    """
    ps = require("pocketsphinx", package="pocketsphinx", extra="speech",
                 purpose="phone recognition")
    samples = as_float_array(samples, "samples", ndim=1, allow_nan=False)
    if samples.size == 0:
        raise InputError("samples is empty")
    rate = as_positive_float(rate, "rate")
    recognizer = as_choice(recognizer, "recognizer", RECOGNIZERS)
    pcm = _pcm16(samples, rate)
    if transcript is not None:
        text = read_transcript(transcript)
        decoder = ps.Decoder(samprate=MODEL_RATE, loglevel="FATAL")
        start, end, phone, conf = _aligned(decoder, pcm, text)
        source = f"PocketSphinx forced alignment of the transcript ({len(text.split())} words)"
    elif recognizer == "words":
        decoder = ps.Decoder(samprate=MODEL_RATE, loglevel="FATAL")
        _decode(decoder, pcm)
        hyp = decoder.hyp()
        text = " ".join(w for w in (hyp.hypstr.split() if hyp is not None else [])
                        if decoder.lookup_word(w) is not None)
        if not text:
            raise InputError("PocketSphinx recognized no words in the speech")
        start, end, phone, conf = _aligned(decoder, pcm, text)
        source = f"PocketSphinx word recognition, then forced alignment: {text!r}"
    else:
        decoder = ps.Decoder(samprate=MODEL_RATE, loglevel="FATAL", lm=None,
                             allphone=ps.get_model_path("en-us/en-us-phone.lm.bin"),
                             **_ALLPHONE_OPTIONS)
        _decode(decoder, pcm)
        frate = float(decoder.config["frate"])
        rows = [(s.start_frame / frate, (s.end_frame + 1) / frate, s.word, min(1.0, s.ascore))
                for s in decoder.seg() if s.end_frame >= s.start_frame]
        start, end, phone, conf = tuple(zip(*rows)) if rows else ((), (), (), ())
        source = "PocketSphinx phone recognition (allphone, phonetic language model)"
    if not phone:
        raise InputError("PocketSphinx found no phones in the speech")
    return _merged_silences(PhoneSegments(np.array(start), np.array(end), phone,
                                          np.array(conf), source))


def _merged_silences(segments: PhoneSegments) -> PhoneSegments:
    """Adjacent ``SIL`` segments as one (the aligner's utterance-initial silence and a
    word-level one), with the lower confidence."""
    phone = np.array(segments.phone)
    sil = phone == "SIL"
    join = np.zeros(len(phone), bool)
    join[1:] = sil[1:] & sil[:-1] & np.isclose(segments.start[1:], segments.end[:-1])
    if not join.any():
        return segments
    group = np.cumsum(~join) - 1
    keep = ~join
    end = np.zeros(int(group[-1]) + 1)
    np.maximum.at(end, group, segments.end)
    conf = np.ones_like(end)
    np.minimum.at(conf, group, segments.confidence)
    return PhoneSegments(segments.start[keep], end, tuple(phone[keep]), conf, segments.source)


def phones_from_wav(path, *, transcript: str | None = None,
                    recognizer: str = "phones") -> PhoneSegments:
    """:func:`read_wav` then :func:`recognize_phones`."""
    samples, rate = read_wav(path)
    return recognize_phones(samples, rate, transcript=transcript, recognizer=recognizer)


def write_phones_csv(path, segments: PhoneSegments, *, inputs=()) -> None:
    """Write ``start,end,phone,confidence`` rows (s, s, ARPAbet, 0-1), atomically."""
    if not isinstance(segments, PhoneSegments):
        raise InputError(f"segments must be PhoneSegments, got {type(segments).__name__}")
    buf = io.StringIO()
    out = csv.writer(buf, lineterminator="\n")
    out.writerow(CSV_COLUMNS)
    for a, b, p, c in zip(segments.start, segments.end, segments.phone, segments.confidence):
        out.writerow((f"{a:.3f}", f"{b:.3f}", p, f"{c:.4f}"))
    with atomic_path(path, inputs=inputs) as tmp:
        Path(tmp).write_text(buf.getvalue(), encoding="utf-8")


def read_phones_csv(path) -> PhoneSegments:
    """Read a phones CSV (:func:`write_phones_csv`, or any with those four columns).

    Raises
    ------
    FileFormatError
        Missing file, missing columns, a value that is not a number, segments
        out of order or overlapping (with the line).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FileFormatError(path, "no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise FileFormatError(path, f"cannot read the phones CSV: {exc}") from None
    rows = list(csv.reader(io.StringIO(text)))
    header = [h.strip().lower() for h in rows[0]] if rows else []
    absent = [c for c in CSV_COLUMNS if c not in header]
    if absent:
        raise FileFormatError(path, f"a phones CSV needs the columns {list(CSV_COLUMNS)}; "
                                    f"{absent} are missing", line=1)
    cols = [header.index(c) for c in CSV_COLUMNS]
    start, end, phone, conf = [], [], [], []
    for line, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        try:
            a, b, p, c = (row[i] for i in cols)
            start.append(float(a))
            end.append(float(b))
            conf.append(float(c))
        except (IndexError, ValueError):
            raise FileFormatError(path, f"expected {','.join(CSV_COLUMNS)} with numbers for "
                                        f"the times and the confidence, got {row}",
                                  line=line) from None
        phone.append(p.strip())
    if not phone:
        raise FileFormatError(path, "the phones CSV has no segments")
    try:
        return PhoneSegments(np.array(start), np.array(end), phone, np.array(conf),
                             f"phones CSV {path}")
    except InputError as exc:
        raise FileFormatError(path, str(exc)) from None


def read_sphinx_alignment(path) -> PhoneSegments:
    """Phone segments of a PocketSphinx alignment JSON (``pocketsphinx align`` output).

    The file holds the utterance ``{"b", "d", "t", "w": [words]}``, each word
    ``{"b", "d", "t", "p", "w": [phones]}`` and each phone ``{"b": begin s,
    "d": duration s, "t": ARPAbet, "p": probability}``.

    Raises
    ------
    FileFormatError
        Not JSON, or not of that structure.
    """
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        rows = [(float(p["b"]), float(p["b"]) + float(p["d"]), str(p["t"]), float(p["p"]))
                for word in doc["w"] for p in word["w"]]
    except FileNotFoundError:
        raise FileFormatError(path, "no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FileFormatError(path, f"cannot read the alignment JSON: {exc}") from None
    except (KeyError, TypeError, ValueError):
        raise FileFormatError(path, "not a PocketSphinx alignment: expected words 'w' with "
                                    "phones {'b', 'd', 't', 'p'}") from None
    if not rows:
        raise FileFormatError(path, "the alignment holds no phones")
    start, end, phone, conf = zip(*rows)
    try:
        return PhoneSegments(np.array(start), np.array(end), phone,
                             np.clip(conf, 0.0, 1.0), f"PocketSphinx alignment {path.name}")
    except InputError as exc:
        raise FileFormatError(path, str(exc)) from None
