"""Foreign-looking captures made from the shared data, with their known answers.

A stranger's take has another lab's names, a subject prefix and often no head
markers. These builders make such takes from ``facial-sing.c3d`` and from
simulated ICT captures (the answers known: the marker sets and landmarks
written for the data, the head motion of the head markers or of the
simulation). Used by the tests and by ``bench/bench_any_capture.py``; nothing
here tunes the tool, it only renames, prefixes and removes.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from mocap.stabilize import stabilize
from mocap.synth.capture import simulate_capture
from mocap.take import Take

PREFIX = "Subject:"

#: facial-sing.c3d in a lab convention like ``Subject:Mouth_Lend``, ``Subject:Leye_Inside``
#: (from tests/facial_sing_markerset.toml: left is +x, the section*-1 of a pair).
FACIAL_SING_NAMES = {
    "root-1": "Head_1", "root-2": "Head_2", "root-3": "Head_3", "root-4": "Head_4",
    "root-5": "Head_5", "root-6": "Head_6",
    "section10-1": "ULip_L", "section10-2": "ULip_Mid", "section10-3": "ULip_R",
    "section13-1": "LLip_L", "section13-2": "LLip_Mid", "section13-3": "LLip_R",
    "section1-1": "LBrow_In", "section1-2": "LBrow_Out",
    "section2-1": "RBrow_In", "section2-2": "RBrow_Out",
    "section3-1": "Leye_Lid1", "section3-2": "Leye_Lid2",
    "section4-1": "Reye_Lid1", "section4-2": "Reye_Lid2",
    "section7-1": "Nose_Bridge", "section7-2": "Nose_Tip",
    "section8-1": "LNostril", "section9-1": "RNostril",
    "section5-1": "LCheek_Up", "section5-2": "LCheek_Out", "section8-2": "LCheek_In",
    "section11-2": "LCheek_Low", "section6-1": "RCheek_Up", "section6-2": "RCheek_Out",
    "section9-2": "RCheek_In", "section12-2": "RCheek_Low",
    "section11-1": "Mouth_Lend", "section12-1": "Mouth_Rend",
    "section14-1": "Chin_L", "section14-2": "Chin_Mid", "section14-3": "Chin_R",
    "Unlabeled1": "Unlabeled1",
}


def ict_name(label: str) -> str:
    """The ICT layout's ``mouth-corner-L`` style as side-first CamelCase (``LMouthCorner``).

    Examples
    --------
    >>> ict_name("mouth-corner-L"), ict_name("lip-upper3"), ict_name("eye-R-lower2")
    ('LMouthCorner', 'ULip3', 'REyeLower2')
    >>> ict_name("brow-L1"), ict_name("head-6"), ict_name("nose-tip")
    ('LBrow1', 'Head6', 'NoseTip')
    """
    side, words = "", []
    for part in label.split("-"):
        if part in ("L", "R") or (part[:1] in ("L", "R") and part[1:].isdigit()):
            side = part[0]                                # -L, -L1 (brow-L1 -> LBrow1)
            words.append(part[1:])
        else:
            words.append(part[:1].upper() + part[1:])
    if words[0] == "Lip":                                 # lip-upper3 -> ULip3
        return ("U" if words[1].lower().startswith("upper") else "L") + "Lip" + words[1][5:]
    return side + "".join(words)


@dataclass(frozen=True, eq=False)
class Foreign:
    """A foreign-looking take and what is known about it.

    Attributes
    ----------
    take : Take
        As a stranger's system would give it (prefixed, renamed, maybe no head).
    regions : dict of str to str
        Face marker (its name in `take`) -> the region of the data's marker set.
    landmarks : dict of str to str
        Anatomical point -> marker (names in `take`) of the data's marker set,
        for the markers still in the take.
    head : tuple of str
        Head markers still in the take.
    rotation, translation : ndarray or None
        The true head motion, ``world = R(t) @ head + t(t)`` (mm), when known.
    """

    take: Take
    regions: dict
    landmarks: dict
    head: tuple
    rotation: np.ndarray | None = None
    translation: np.ndarray | None = None


def rename(take: Take, mapping, prefix: str = PREFIX) -> Take:
    """`take` with every label renamed by `mapping` (unchanged if absent) and prefixed."""
    return take.replace(labels=tuple(prefix + mapping.get(x, x) for x in take.labels))


def anonymous_names(labels, seed: int = 0) -> dict:
    """Label -> ``M01``, ``M02``, ... in a shuffled order: names that say nothing."""
    order = np.random.default_rng(seed).permutation(len(labels))
    return {label: f"M{k + 1:02d}" for label, k in zip(labels, order)}


def _known(markerset, mapping, labels, prefix) -> tuple:
    name = {x: prefix + mapping.get(x, x) for x in markerset.markers}
    regions = {name[x]: markerset.region_of(x) for x in markerset.face_markers if x in labels}
    landmarks = {p: name[x] for p, x in markerset.landmarks.items() if x in labels}
    return regions, landmarks


def facial_sing(take: Take, markerset, *, mapping=None, keep_head: bool = True,
                prefix: str = PREFIX) -> Foreign:
    """facial-sing.c3d renamed (by `mapping`, default :data:`FACIAL_SING_NAMES`) and prefixed.

    With ``keep_head=False`` the head markers are removed after the take was
    stabilized on them: their head motion is the truth kept in the result.
    """
    mapping = FACIAL_SING_NAMES if mapping is None else mapping
    truth = stabilize(take, markerset.head)
    labels = [x for x in take.labels if keep_head or x not in markerset.head]
    regions, landmarks = _known(markerset, mapping, labels, prefix)
    head = tuple(prefix + mapping.get(x, x) for x in markerset.head) if keep_head else ()
    return Foreign(rename(take.select(labels), mapping, prefix), regions, landmarks, head,
                   np.asarray(truth.rotation), np.asarray(truth.translation))


def ict_capture(basis, performance, layout, markerset, *, head_motion: bool = True,
                keep_head: bool = True, duration: float = 30.0, rate: float = 60.0,
                mapping=None, seed: int = 0, prefix: str = PREFIX) -> Foreign:
    """A simulated ICT capture (0.2 mm noise, a few short gaps) in another naming scheme.

    Head motion as in the issue's real takes from another lab: up to 3 deg
    per axis and 10 mm; ``head_motion=False``: none. ``keep_head=False``
    removes the head markers (the simulation's head motion stays the truth).
    """
    with warnings.catch_warnings():         # ARKit's TongueOut has no ICT shape: known
        warnings.filterwarnings("ignore", ".*1 weight columns match no shape", UserWarning)
        sim = simulate_capture(basis, performance, layout, markerset.head, rate=rate,
                               duration=duration, noise_mm=0.2, n_gaps=8, max_gap_s=0.3,
                               head_rotation_deg=3.0 if head_motion else 0.0,
                               head_translation_mm=10.0 if head_motion else 0.0, seed=seed)
    mapping = {x: ict_name(x) for x in layout.labels} if mapping is None else mapping
    labels = [x for x in sim.take.labels if keep_head or x not in markerset.head]
    regions, landmarks = _known(markerset, mapping, labels, prefix)
    head = tuple(prefix + mapping[x] for x in markerset.head) if keep_head else ()
    return Foreign(rename(sim.take.select(labels), mapping, prefix), regions, landmarks, head,
                   np.asarray(sim.truth.rotation), np.asarray(sim.truth.translation))


def head_frame_error(rotation, translation, true_rotation, true_translation, centre) -> tuple:
    """Median rotation (deg) and translation (mm) error of a head frame against the truth.

    Two head frames of one take differ by a constant rigid motion (each puts
    its origin and axes where it likes); the error is what is left once that
    constant is removed: ``G(t) = truth(t)^-1 o found(t)`` should not vary.
    The rotation error is the angle of ``G(t)`` from its mean, the
    translation error the displacement of `centre` (a head-frame point, mm,
    e.g. the face's centroid) from its median position under ``G(t)``.

    Returns
    -------
    rotation_deg, translation_mm : float
        Medians over the frames where both transforms exist.
    """
    from scipy.spatial.transform import Rotation

    relative = np.swapaxes(true_rotation, 1, 2) @ rotation
    shift = np.einsum("tji,tj->ti", true_rotation, translation - true_translation)
    ok = ~(np.isnan(relative).any(axis=(1, 2)) | np.isnan(shift).any(axis=1))
    rot = Rotation.from_matrix(relative[ok])
    angle = np.degrees((rot.mean().inv() * rot).magnitude())
    moved = rot.apply(np.asarray(centre, dtype=float)) + shift[ok]
    off = np.linalg.norm(moved - np.median(moved, axis=0), axis=1)
    return float(np.median(angle)), float(np.median(off))
