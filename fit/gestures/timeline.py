"""Timeline of gesture styles: which reference clip drives which feature, when.

A TOML file paints styles (names of palette clips) on time segments, for all
features at once or per feature (Ju & Lee 2008, sec. 6: "the eyebrows can
imitate the gestures of subject A, while the head motion is simulating the
style of subject B")::

    default = "calm"            # optional: style where no segment says otherwise

    [[segment]]
    start = 0.0                 # s, inclusive
    end = 4.5                   # s, exclusive
    style = "lively"            # every feature not named below
    head = "nodding"            # per-feature styles: see FEATURES
    blinks = "calm"

Where neither a segment nor ``default`` names a style, every clip of the
palette is a candidate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

from fit.gestures.features import FEATURES
from mocap.errors import FileFormatError, InputError
from mocap.util.toml import read_toml
from mocap.util.validation import as_int, as_positive_float

__all__ = ["Segment", "Timeline", "load_timeline", "parse_timeline", "FEATURES"]

_SEGMENT_KEYS = {"start", "end", "style", *FEATURES}


@dataclass(frozen=True)
class Segment:
    """One painted stretch of the timeline.

    Attributes
    ----------
    start, end : float, s
        ``start <= t < end``.
    styles : mapping of str to str
        Feature (:data:`FEATURES`) to clip name; features absent use ``style``.
    style : str or None
        Clip of every feature not in `styles`.
    """

    start: float
    end: float
    styles: Mapping[str, str] = field(default_factory=dict)
    style: str | None = None

    def style_of(self, feature: str) -> str | None:
        """The clip driving `feature` in this segment (None: not painted)."""
        return self.styles.get(feature, self.style)


@dataclass(frozen=True)
class Timeline:
    """Segments in time order, non-overlapping, and the default style.

    Attributes
    ----------
    segments : tuple of Segment
    default : str or None
        Style where no segment paints a feature; None: every palette clip.
    path : str or None
    """

    segments: tuple = ()
    default: str | None = None
    path: str | None = None

    def styles(self) -> set:
        """Every clip name the timeline uses."""
        names = {s for seg in self.segments for s in (seg.style, *seg.styles.values())}
        return {s for s in names | {self.default} if s is not None}

    def spans(self, feature: str, n_frames: int, rate: float) -> list:
        """Frame runs of one feature: ``[(start, stop, style or None), ...]`` covering 0..n_frames.

        Segment bounds fall on frame ``ceil(t * rate)``; adjacent runs of the same
        style are merged.
        """
        if feature not in FEATURES:
            raise InputError(f"feature must be one of {list(FEATURES)}, got {feature!r}")
        n_frames = as_int(n_frames, "n_frames", minimum=1)
        rate = as_positive_float(rate, "rate")
        cuts = []
        for seg in self.segments:
            a = min(n_frames, math.ceil(seg.start * rate - 1e-9))
            b = min(n_frames, math.ceil(seg.end * rate - 1e-9))
            if b > a:
                cuts.append((a, b, seg.style_of(feature) or self.default))
        runs, t = [], 0
        for a, b, style in cuts:
            if a > t:
                runs.append((t, a, self.default))
            runs.append((a, b, style))
            t = b
        if t < n_frames:
            runs.append((t, n_frames, self.default))
        merged = []
        for a, b, style in runs:
            if merged and merged[-1][2] == style and merged[-1][1] == a:
                merged[-1] = (merged[-1][0], b, style)
            else:
                merged.append((a, b, style))
        return merged


def _style(value, path, where) -> str:
    if not isinstance(value, str) or not value:
        raise FileFormatError(path, f"{where} must be a clip name (a non-empty string), "
                                    f"got {value!r}")
    return value


def _time(value, path, where) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or value < 0:
        raise FileFormatError(path, f"{where} must be a time in seconds >= 0, got {value!r}")
    return float(value)


def parse_timeline(doc: Mapping, *, path=None) -> Timeline:
    """Validate a parsed timeline document (see the module docstring).

    Parameters
    ----------
    doc : mapping
        The TOML document as a dict.
    path : str or os.PathLike, optional
        Named in the errors (default ``"<timeline>"``).

    Returns
    -------
    Timeline

    Raises
    ------
    FileFormatError
        Unknown keys, a segment without start or end, ``end <= start``,
        overlapping segments, a style that is not a non-empty string.
    """
    path = str(path) if path is not None else "<timeline>"
    unknown = set(doc) - {"default", "segment"}
    if unknown:
        raise FileFormatError(path, f"unknown keys {sorted(unknown)}; expected 'default' and "
                                    "[[segment]] tables")
    default = None if doc.get("default") is None else _style(doc["default"], path, "default")
    raw = doc.get("segment", [])
    if not isinstance(raw, list) or not all(isinstance(s, dict) for s in raw):
        raise FileFormatError(path, "segment must be an array of tables ([[segment]])")
    segments = []
    for i, seg in enumerate(raw):
        where = f"segment {i + 1}"
        bad = set(seg) - _SEGMENT_KEYS
        if bad:
            raise FileFormatError(path, f"{where}: unknown keys {sorted(bad)}; expected start, "
                                        f"end, style and features {list(FEATURES)}")
        for key in ("start", "end"):
            if key not in seg:
                raise FileFormatError(path, f"{where} has no {key!r} time")
        start = _time(seg["start"], path, f"{where} start")
        end = _time(seg["end"], path, f"{where} end")
        if end <= start:
            raise FileFormatError(path, f"{where} ends at {end:g} s, not after its start "
                                        f"{start:g} s")
        style = None if "style" not in seg else _style(seg["style"], path, f"{where} style")
        styles = {f: _style(seg[f], path, f"{where} {f}") for f in FEATURES if f in seg}
        if style is None and not styles:
            raise FileFormatError(path, f"{where} names no style (give 'style' or a feature)")
        segments.append(Segment(start, end, styles, style))
    segments.sort(key=lambda s: s.start)
    for before, after in zip(segments, segments[1:]):
        if after.start < before.end:
            raise FileFormatError(path, f"segments {before.start:g}-{before.end:g} s and "
                                        f"{after.start:g}-{after.end:g} s overlap")
    return Timeline(tuple(segments), default, path)


def load_timeline(path) -> Timeline:
    """Read a timeline TOML file; errors as :func:`parse_timeline`, plus unreadable TOML."""
    path = Path(path)
    doc = read_toml(path, "timeline")
    return parse_timeline(doc, path=path)
