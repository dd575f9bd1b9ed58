"""Marker sets: which markers are head markers, which facial region each face
marker belongs to, rigid clusters, and the anatomical landmarks markers sit on.

A marker set is a TOML file::

    name = "facial-sing"
    prefix = ""            # optional: a subject prefix ("Subject:") of the capture's labels
    head = ["root-1", "root-2", "root-3", "root-4"]   # rigid head markers: none or >= 3
    stabilization = []     # optional: face markers that stand in for a head
                           # (stabilize = "auto"; empty: found in each take)

    [regions]              # every face marker in exactly one region
    upper_lip = ["UL1", "UL2"]
    lower_lip = ["LL1", "LL2"]
    left_brow = []
    right_brow = []
    left_eye = []
    right_eye = []
    other = ["Chin"]       # extra region names (nose, jaw, ...) are allowed

    [clusters]             # optional rigid clusters besides the head
    # nose = ["N1", "N2", "N3"]

    [landmarks]            # anatomical point (mocap.anatomy) = marker label
    mouth_corner_left = "UL1"

    [open_questions]       # written by `mocap2mesh init`: what it could not decide
    # name = "the question"   (answer it in the file, then delete the line)

Left and right are the subject's own. A capture without head markers (``head =
[]``) is stabilized on face markers (``stabilize = "auto"``) or taken as it is
(``stabilize = "none"``, for takes already in the head frame); see
:func:`mocap.head_frame.find_head_frame`. A file with an unanswered open
question is refused.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

from mocap.anatomy import ANATOMICAL_POINTS
from mocap.errors import FileFormatError, MarkerError
from mocap.util.toml import check_open_questions, read_toml

__all__ = ["MarkerSet", "load_markerset", "REQUIRED_REGIONS"]

#: Regions every marker set names (possibly empty): the retargeting stage keeps
#: the upper lip from driving the lower lip, and the gestures stage takes the
#: brows, eyes and lips as separate detail groups.
REQUIRED_REGIONS = ("upper_lip", "lower_lip", "left_brow", "right_brow",
                    "left_eye", "right_eye", "other")

_KEYS = {"name", "prefix", "head", "stabilization", "regions", "clusters", "landmarks",
         "description", "open_questions"}


@dataclass(frozen=True)
class MarkerSet:
    """The roles of the markers of a capture.

    Attributes
    ----------
    name : str
    head : tuple of str
        Rigid head markers: none, or at least three.
    regions : mapping of str to tuple of str
        Face markers by facial region; every face marker in exactly one region.
    clusters : mapping of str to tuple of str
        Rigid clusters, the head (as ``"head"``, when it has markers) included.
    landmarks : mapping of str to str
        Anatomical point name (see :mod:`mocap.anatomy`) to marker label.
    path : str or None
        The file it was read from.
    stabilization : tuple of str
        Face markers that stand in for a head when there are no head markers
        (``stabilize = "auto"`` fits them; empty: it finds them in each take).
    prefix : str
        Subject prefix of the capture's labels (Vicon's ``"Subject:"``): the
        set names markers without it, :meth:`own_labels` strips it from a take.
    """

    name: str
    head: tuple
    regions: Mapping[str, tuple]
    clusters: Mapping[str, tuple] = field(default_factory=dict)
    landmarks: Mapping[str, str] = field(default_factory=dict)
    path: str | None = None
    stabilization: tuple = ()
    prefix: str = ""

    @property
    def face_markers(self) -> tuple:
        """All face markers, region by region in file order."""
        return tuple(label for labels in self.regions.values() for label in labels)

    @property
    def markers(self) -> tuple:
        """Head markers, then face markers."""
        return self.head + self.face_markers

    def region_of(self, label: str) -> str:
        """The region of a face marker (``"head"`` for a head marker)."""
        if label in self.head:
            return "head"
        for region, labels in self.regions.items():
            if label in labels:
                return region
        raise MarkerError(label, f"not in marker set {self.name!r}")

    def own_labels(self, take):
        """The take with this set's subject prefix stripped from its labels (itself without one).

        Raises
        ------
        MarkerError
            A label without the prefix equals one stripped of it.
        """
        if not self.prefix or not any(x.startswith(self.prefix) for x in take.labels):
            return take
        labels = tuple(x[len(self.prefix):] if x.startswith(self.prefix) else x
                       for x in take.labels)
        seen = set()
        for original, label in zip(take.labels, labels):
            if label in seen:
                raise MarkerError(original, f"is {label!r} without the prefix "
                                            f"{self.prefix!r}, and the take has that label too")
            seen.add(label)
        return take.replace(labels=labels)

    def check_labels(self, labels, *, source: str = "the take") -> None:
        """Raise MarkerError if a marker of this set is absent from `labels`."""
        present = set(labels)
        absent = [label for label in self.markers if label not in present]
        if absent:
            raise MarkerError(absent[0], f"marker set {self.name!r} names it but {source} "
                                         f"has no such marker (absent: {', '.join(absent)})")


def _labels(value, path, what) -> tuple:
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise FileFormatError(path, f"{what} must be a list of marker labels")
    return tuple(value)


def _table(doc: dict, key: str, path) -> dict:
    value = doc.get(key, {})
    if not isinstance(value, dict):
        raise FileFormatError(path, f"[{key}] must be a table, got {value!r}")
    return value


def load_markerset(path) -> MarkerSet:
    """Read and validate a marker-set TOML file.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    MarkerSet

    Raises
    ------
    FileFormatError
        Unreadable TOML, unknown keys, one or two head markers, a marker in
        two regions, a missing required region, an unknown anatomical point, a
        landmark on a marker the set does not name, stabilization markers that
        are not 3 or more face markers of the set, or an open question not answered.
    """
    path = Path(path)
    doc = read_toml(path, "marker set")
    unknown = set(doc) - _KEYS
    if unknown:
        raise FileFormatError(path, f"unknown keys {sorted(unknown)}; expected {sorted(_KEYS)}")
    check_open_questions(doc, path, "marker set")
    head = _labels(doc.get("head", []), path, "head")
    if 0 < len(head) < 3:
        raise FileFormatError(path, f"head names {len(head)} markers; a rigid head fit needs "
                                    "at least 3 (or list none, and stabilize on face markers "
                                    "with stabilize = 'auto')")
    raw_regions = _table(doc, "regions", path)
    absent = [r for r in REQUIRED_REGIONS if r not in raw_regions]
    if absent:
        raise FileFormatError(path, f"[regions] lacks {', '.join(absent)} (list them, empty if "
                                    "the capture has no such markers)")
    regions, owner = {}, {label: "head" for label in head}
    for region, value in raw_regions.items():
        labels = _labels(value, path, f"region {region!r}")
        for label in labels:
            if label in owner:
                raise FileFormatError(path, f"marker {label!r} is in both {owner[label]!r} "
                                            f"and {region!r}")
            owner[label] = region
        regions[region] = labels
    stabilization = _labels(doc.get("stabilization", []), path, "stabilization")
    not_face = [label for label in stabilization if owner.get(label, "head") == "head"]
    if not_face or 0 < len(stabilization) < 3:
        raise FileFormatError(path, f"stabilization must name 3 or more face markers of the set "
                                    f"(not face markers: {not_face})")
    clusters = {"head": head} if head else {}
    for cluster, value in _table(doc, "clusters", path).items():
        labels = _labels(value, path, f"cluster {cluster!r}")
        unknown_labels = [label for label in labels if label not in owner]
        if unknown_labels or len(labels) < 3:
            raise FileFormatError(path, f"cluster {cluster!r} must name at least 3 markers of "
                                        f"the set (unknown: {unknown_labels})")
        clusters[cluster] = labels
    landmarks = {}
    for point, label in _table(doc, "landmarks", path).items():
        if not isinstance(label, str):
            raise FileFormatError(path, f"landmark {point!r} must name one marker (a string), "
                                        f"got {label!r}")
        if point not in ANATOMICAL_POINTS:
            raise FileFormatError(path, f"unknown anatomical point {point!r} in [landmarks]; "
                                        f"known: {', '.join(ANATOMICAL_POINTS)}")
        if label not in owner:
            raise FileFormatError(path, f"landmark {point!r} names marker {label!r}, which "
                                        "the set does not list")
        landmarks[point] = label
    prefix = doc.get("prefix", "")
    if not isinstance(prefix, str):
        raise FileFormatError(path, f"prefix must be a string (such as 'Subject:'), got "
                                    f"{prefix!r}")
    name = doc.get("name", path.stem)
    if not isinstance(name, str):
        raise FileFormatError(path, f"name must be a string, got {name!r}")
    return MarkerSet(name=name, head=head, regions=regions, clusters=clusters,
                     landmarks=landmarks, path=str(path), stabilization=stabilization,
                     prefix=prefix)
