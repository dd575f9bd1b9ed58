"""What marker names say: subject prefixes, unlabeled markers, and common naming conventions.

Labs name face markers in many ways (``LMouth``, ``Mouth_Lend``,
``mouth-corner-L``, ``LCRN``, ``Leye_Inside``, ``section11-1``). A name is
split into words (case changes, separators, a side letter glued to a word),
abbreviations are expanded by :data:`WORDS`, and the words give a side, a
region and sometimes an anatomical point (:func:`parse_name`). Names only
help: regions come from geometry (:mod:`mocap.infer.regions`), and a name
that contradicts the geometry is reported, not trusted.
"""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass

__all__ = ["NameHint", "parse_name", "split_prefix", "is_unlabeled", "WORDS",
           "NAMING_CONVENTIONS", "REGIONS"]

#: The regions inference assigns (a marker set may add others). Sides are the
#: subject's own.
REGIONS = ("upper_lip", "lower_lip", "mouth_corners", "left_brow", "right_brow", "left_eye",
           "right_eye", "left_cheek", "right_cheek", "nose", "chin", "jaw", "forehead", "other")

#: Word (lower case) -> canonical word. Abbreviations of the naming conventions in use.
WORDS = {
    "l": "left", "lt": "left", "lf": "left", "lft": "left", "left": "left",
    "r": "right", "rt": "right", "rgt": "right", "right": "right",
    "mouth": "mouth", "mth": "mouth", "lip": "lip", "lips": "lip", "ulip": "upper_lip",
    "llip": "lower_lip", "ul": "upper_lip", "ll": "lower_lip", "philtrum": "upper_lip",
    "mentolabial": "lower_lip", "corner": "corner", "crn": "corner", "cnr": "corner",
    "end": "corner", "commissure": "corner", "cheilion": "corner",
    "upper": "upper", "up": "upper", "upr": "upper", "top": "upper", "sup": "upper",
    "lower": "lower", "low": "lower", "lwr": "lower", "bottom": "lower", "bot": "lower",
    "inf": "lower",
    "brow": "brow", "eyebrow": "brow", "bro": "brow", "brw": "brow",
    "eye": "eye", "lid": "eye", "eyelid": "eye", "canthus": "eye", "orbit": "eye",
    "cheek": "cheek", "chk": "cheek", "malar": "cheek", "zyg": "cheek",
    "nose": "nose", "nasal": "nose", "nos": "nose", "ala": "nose", "alar": "nose",
    "nostril": "nose", "nasion": "nasion", "bridge": "nasion", "dorsum": "nose",
    "chin": "chin", "mentum": "chin", "pogonion": "chin",
    "jaw": "jaw", "mandible": "jaw", "jowl": "jaw",
    "forehead": "forehead", "frhd": "forehead", "glabella": "forehead", "gla": "forehead",
    "temple": "forehead",
    "head": "head", "hd": "head", "root": "head", "skull": "head", "band": "head",
    "headband": "head", "helmet": "head", "hat": "head", "cap": "head",
    "fhd": "head", "bhd": "head", "lfhd": "head", "rfhd": "head", "lbhd": "head",
    "rbhd": "head",
    "inner": "inner", "inside": "inner", "in": "inner", "medial": "inner", "inn": "inner",
    "outer": "outer", "outside": "outer", "out": "outer", "lateral": "outer",
    "mid": "mid", "middle": "mid", "center": "mid", "centre": "mid", "c": "mid",
    "tip": "tip",
}

#: Naming conventions the parser reads, as examples (what ``init`` prints).
NAMING_CONVENTIONS = (
    ("LMouth, RMouth", "mouth corner, side first, CamelCase"),
    ("Mouth_Lend, Mouth_Rend", "mouth corner, side glued to 'end'"),
    ("mouth-corner-L, lip-upper3", "words and side with hyphens"),
    ("LCRN, RCRN, ULIP, LLIP", "four-letter abbreviations"),
    ("Leye_Inside, REyeOuter", "eye corners, side glued to 'eye'"),
    ("LBrowIn, brow-R4", "brows"),
    ("NoseTip, Nasion, LNostril", "nose"),
    ("LFHD, RBHD, Head1, root-3", "head markers (headband, helmet)"),
    ("Subject:Marker", "Vicon subject prefix (stripped)"),
    ("Unlabeled1, *12, Marker7", "unlabeled markers (not kept)"),
)

_UNLABELED = re.compile(r"^(\*|unlabel+ed|unknown|unnamed|noname|marker|pt|point|virtual)"
                        r"[\s_\-.]*\d*$", re.IGNORECASE)
_CAMEL = re.compile(r"(?<=[a-z])(?=[A-Z])|(?<=[A-Z])(?=[A-Z][a-z])|(?<=[A-Za-z])(?=\d)|"
                    r"(?<=\d)(?=[A-Za-z])")


@dataclass(frozen=True)
class NameHint:
    """What a marker's name says.

    Attributes
    ----------
    label : str
        The label in the capture.
    name : str
        The label without its subject prefix.
    words : tuple of str
        Canonical words found (:data:`WORDS`).
    side : {"left", "right"} or None
    region : str or None
        A region of :data:`REGIONS`, ``"head"``, or None when the name says none.
    point : str or None
        An anatomical point (:mod:`mocap.anatomy`) the name names, if any.
    """

    label: str
    name: str
    words: tuple
    side: str | None
    region: str | None
    point: str | None


def is_unlabeled(name: str) -> bool:
    """Whether a name is a capture system's placeholder (``Unlabeled1``, ``*12``, ``Marker7``).

    Examples
    --------
    >>> is_unlabeled("Unlabeled1"), is_unlabeled("*12"), is_unlabeled("LMouth")
    (True, True, False)
    """
    return bool(_UNLABELED.match(name.strip()))


def split_prefix(labels) -> tuple:
    """The subject prefix shared by the labels (``"Subject:"``), and each label without it.

    Parameters
    ----------
    labels : sequence of str

    Returns
    -------
    prefix : str
        The text up to and including the last ``:`` that most labels share
        ("" when none do).
    names : tuple of str
        Every label without that prefix (labels without it unchanged).
    others : tuple of str
        Labels with another prefix (another subject's markers).

    Examples
    --------
    >>> split_prefix(["Subject:LMouth", "Subject:RMouth", "Unlabeled1"])
    ('Subject:', ('LMouth', 'RMouth', 'Unlabeled1'), ())
    """
    prefixes = Counter(label[:label.rindex(":") + 1] for label in labels if ":" in label)
    if not prefixes:
        return "", tuple(labels), ()
    prefix, _ = prefixes.most_common(1)[0]
    names = tuple(label[len(prefix):] if label.startswith(prefix) else label
                  for label in labels)
    others = tuple(label for label in labels if ":" in label and not label.startswith(prefix))
    return prefix, names, others


def _words(name: str) -> list:
    """Canonical words of a name: split at separators and case changes, side letters unglued."""
    raw = []
    for part in re.split(r"[^A-Za-z0-9]+", name):
        letters = part.rstrip("0123456789").lower()
        if letters in WORDS:                       # a word as written: ULip, LLIP, LCRN
            raw.append(letters)
        else:
            raw += [t.lower() for t in _CAMEL.split(part) if t and not t.isdigit()]
    words = []
    for token in raw:
        if token in WORDS:
            words.append(WORDS[token])
        elif len(token) > 2 and token[0] in "lr" and token[1:] in WORDS:
            words += [WORDS[token[0]], WORDS[token[1:]]]            # Leye, Lend, RCRN
        elif len(token) > 2 and token[-1] in "lr" and token[:-1] in WORDS:
            words += [WORDS[token[:-1]], WORDS[token[-1]]]          # EyeL, browR
    return words


def _region(words: list, side: str | None) -> str | None:
    has = set(words).__contains__
    if has("head"):
        return "head"
    if has("upper_lip") or (has("lip") and has("upper")):
        return "upper_lip"
    if has("lower_lip") or (has("lip") and has("lower")):
        return "lower_lip"
    if (has("mouth") or has("lip")) and (has("corner") or side is not None):
        return "mouth_corners"
    if has("corner") and not (has("eye") or has("brow")):
        return "mouth_corners"
    sided = {"brow": "brow", "eye": "eye", "cheek": "cheek"}
    for word, region in sided.items():
        if has(word):
            return f"{side}_{region}" if side else None
    for word in ("nose", "nasion", "chin", "jaw", "forehead"):
        if has(word):
            return "nose" if word == "nasion" else word
    return None


def _point(words: list, side: str | None, region: str | None) -> str | None:
    has = set(words).__contains__
    if region == "mouth_corners" and side:
        return f"mouth_corner_{side}"
    if has("nasion"):
        return "nose_bridge"
    if region == "nose" and has("tip"):
        return "nose_tip"
    if region == "chin" and side is None:
        return "chin"
    for part in ("eye", "brow"):
        if has(part) and side:
            for where in ("inner", "outer"):
                if has(where):
                    return f"{part}_{where}_{side}"
    return None


def parse_name(label: str, prefix: str = "") -> NameHint:
    """Side, region and anatomical point a marker name states.

    Parameters
    ----------
    label : str
        The marker label as in the capture.
    prefix : str
        Subject prefix to strip first (:func:`split_prefix`).

    Returns
    -------
    NameHint

    Examples
    --------
    >>> hint = parse_name("Subject:Mouth_Lend", "Subject:")
    >>> hint.name, hint.side, hint.region, hint.point
    ('Mouth_Lend', 'left', 'mouth_corners', 'mouth_corner_left')
    >>> parse_name("Leye_Inside").point, parse_name("LCRN").point, parse_name("brow-R4").region
    ('eye_inner_left', 'mouth_corner_left', 'right_brow')
    >>> parse_name("ULip_L").region, parse_name("LLip3").region
    ('upper_lip', 'lower_lip')
    >>> parse_name("section11-1").region is None
    True
    """
    name = label[len(prefix):] if prefix and label.startswith(prefix) else label
    words = _words(name)
    sides = {w for w in words if w in ("left", "right")}
    side = sides.pop() if len(sides) == 1 else None
    region = _region(words, side)
    return NameHint(label=label, name=name, words=tuple(words), side=side, region=region,
                    point=_point(words, side, region))
