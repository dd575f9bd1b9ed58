"""Facial regions of markers from where they sit on the face mesh, and from their names.

Each marker's closest point on the mesh (after :func:`mocap.infer.alignment.align_to_mesh`)
is expressed in face coordinates normalized by the face itself: ``x`` is the
distance from the symmetry plane over half the distance between the outer
eye corners (positive on the subject's left), ``y`` the height above the
mouth corners over the mouth-to-eye-corner height. The levels of the
mesh's profile and loops (:class:`mocap.infer.mesh_landmarks.MeshLandmarks`)
bound the regions:

=============  ==============================================================
region         where (first rule that holds)
=============  ==============================================================
forehead       above the brow band (eye opening top + 0.45), or in it within
               half the inner eye corner of the midline (glabella)
brows          the brow band: eye opening top + 0.15 to + 0.45
eyes           eye opening bottom - 0.12 up to the brow band, from the inner
               eye corner - 0.2 to 1.25 from the midline (lids and canthi)
nose           subnasale up to the brow band, within the inner eye corners
               (the alae are about as wide as the eyes are apart)
mouth corners  within 0.15 of the lips' contact, beyond 0.8 of a mouth corner
upper lip      lips' contact (the mouth loop's middle line) up to the
               subnasale, within 0.8 of a mouth corner
lower lip      labiomental fold up to the lips' contact, within the same
chin           below the labiomental fold, within a mouth corner + 0.1
jaw            below the labiomental fold beyond that, or below 0.1 beyond
               1.15 (the mandible behind the cheek)
cheeks         the rest of the face (side by x)
other          beyond 1.6 from the midline, or far above or below the face
=============  ==============================================================

Names (:func:`mocap.infer.names.parse_name`) are taken where the geometry
agrees or is next door (a lower-lid marker a lab calls cheek); a name that
puts a marker on the other side or in a region far from where it sits is
left as an open question.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.infer.mesh_landmarks import MeshLandmarks
from mocap.infer.names import NameHint

__all__ = ["RegionGuess", "classify_markers", "face_coordinates", "ADJACENT"]

#: Regions that share a border (without side): a name naming a neighbour of
#: the region the geometry finds is trusted.
ADJACENT = {
    "upper_lip": {"lower_lip", "mouth_corners", "nose", "cheek"},
    "lower_lip": {"upper_lip", "mouth_corners", "chin", "jaw", "cheek"},
    "mouth_corners": {"upper_lip", "lower_lip", "cheek", "jaw"},
    "nose": {"upper_lip", "cheek", "eye", "forehead"},
    "eye": {"brow", "cheek", "nose", "forehead"},
    "brow": {"eye", "forehead"},
    "forehead": {"brow", "nose", "eye"},
    "cheek": {"eye", "nose", "upper_lip", "lower_lip", "mouth_corners", "jaw"},
    "chin": {"lower_lip", "jaw"},
    "jaw": {"chin", "cheek", "lower_lip", "mouth_corners"},
    "other": set(),
}
#: Levels used when the mesh landmarks came from a file without them, in the
#: normalized heights above (typical adult proportions).
_DEFAULT_LEVELS = {"stomion": 0.0, "subnasale": 0.32, "labiomental": -0.25, "nasion": 1.0,
                   "eye_top": 1.1, "eye_bottom": 0.9}
#: Within this (normalized units) of a region border, a name decides.
_BORDER = 0.1


@dataclass(frozen=True)
class RegionGuess:
    """The region inferred for one marker.

    Attributes
    ----------
    label : str
    region : str
        A region of :data:`mocap.infer.names.REGIONS`.
    geometry : str
        The region from geometry alone.
    source : {"geometry", "name", "both"}
        What decided.
    x, y : float
        Normalized face coordinates of the marker's point on the mesh.
    question : str or None
        Set when name and geometry disagree beyond doubt.
    """

    label: str
    region: str
    geometry: str
    source: str
    x: float
    y: float
    question: str | None = None


def _base(region: str) -> str:
    for side in ("left_", "right_"):
        if region.startswith(side):
            return region[len(side):]
    return region


def face_coordinates(points_on_mesh, marks: MeshLandmarks) -> tuple:
    """Normalized face coordinates (M, 2) of mesh points, and the levels (normalized).

    Returns
    -------
    xy : ndarray of shape (M, 2)
        x: from the symmetry plane over half the outer-eye-corner distance
        (positive on the subject's left); y: height above the mouth corners
        over the mouth-corner-to-eye-corner height.
    levels : dict of str to float
        stomion, subnasale, labiomental, nasion, eye_top, eye_bottom (y
        units), mouth (the mouth corners' x), inner_eye (the inner eye
        corners' x) and mouth_line (k, 2): the lips' contact from corner to
        corner (the stomion's level across, without a mouth loop).
    """
    c = marks.coordinates
    mouth = (c["mouth_corner_left"] + c["mouth_corner_right"]) / 2
    corners = [c[p] for p in ("eye_inner_left", "eye_outer_left", "eye_inner_right",
                              "eye_outer_right")]
    eye_y = float(np.mean([p[1] for p in corners]))
    height = eye_y - mouth[1]
    width = (c["eye_outer_left"][0] - c["eye_outer_right"][0]) / 2
    coords = marks.axes.coordinates(points_on_mesh)
    xy = np.c_[coords[:, 0] / width, (coords[:, 1] - mouth[1]) / height]
    levels = {name: (marks.levels[name] - mouth[1]) / height if name in marks.levels else value
              for name, value in _DEFAULT_LEVELS.items()}
    levels["mouth"] = float((c["mouth_corner_left"][0] - c["mouth_corner_right"][0]) / 2 / width)
    line = marks.mouth_line
    levels["mouth_line"] = (np.c_[line[:, 0] / width, (line[:, 1] - mouth[1]) / height]
                            if len(line) else np.array([[-1.0, levels["stomion"]],
                                                        [1.0, levels["stomion"]]]))
    levels["inner_eye"] = float((c["eye_inner_left"][0] - c["eye_inner_right"][0]) / 2 / width)
    return xy, levels


def _geometry(x: float, y: float, lv: dict) -> str:
    """The region of one marker from its normalized coordinates (the table of the module)."""
    ax = abs(x)
    side = "left" if x >= 0 else "right"
    brow_lo, brow_hi = lv["eye_top"] + 0.15, lv["eye_top"] + 0.45
    if ax > 1.6 or y > brow_hi + 1.0 or y < lv["labiomental"] - 1.0:
        return "other"
    if y > brow_hi or (y > brow_lo and ax < 0.5 * lv["inner_eye"]):
        return "forehead"
    if y > brow_lo:
        return f"{side}_brow"
    if y >= lv["eye_bottom"] - 0.12 and lv["inner_eye"] - 0.2 <= ax <= 1.25:
        return f"{side}_eye"
    if y >= lv["subnasale"] and ax <= lv["inner_eye"]:
        return "nose"
    if abs(y - lv["stomion"]) <= 0.15 and ax >= 0.8 * lv["mouth"] and ax <= lv["mouth"] + 0.3:
        return "mouth_corners"
    if lv["labiomental"] <= y < lv["subnasale"] and ax < 0.8 * lv["mouth"]:
        line = lv["mouth_line"]
        contact = float(np.interp(x, line[:, 0], line[:, 1]))
        return "upper_lip" if y >= contact else "lower_lip"
    if y < lv["labiomental"]:
        return "chin" if ax <= lv["mouth"] + 0.1 else "jaw"
    if y < 0.1 and ax > 1.15:
        return "jaw"
    return f"{side}_cheek"


def _near_border(x: float, y: float, lv: dict, region: str) -> bool:
    """Whether moving the point by at most _BORDER puts it in `region` (side ignored)."""
    for dx in (-_BORDER, 0.0, _BORDER):
        for dy in (-_BORDER, 0.0, _BORDER):
            if _base(_geometry(x + dx, y + dy, lv)) == _base(region):
                return True
    return False


def classify_markers(labels, points_on_mesh, marks: MeshLandmarks, hints=None) -> list:
    """Regions of face markers from their points on the mesh, helped by their names.

    Parameters
    ----------
    labels : sequence of str
        The M face markers.
    points_on_mesh : array_like of shape (M, 3), mesh units
        Their closest points on the mesh.
    marks : MeshLandmarks
    hints : mapping of str to NameHint, optional
        What each marker's name says.

    Returns
    -------
    list of RegionGuess
        In the order of `labels`.

    Notes
    -----
    A name's region is taken when the geometry finds the same region, or
    when the marker lies within 0.1 (normalized) of the named region, or in a
    neighbouring region (:data:`ADJACENT`) on the same side. A name naming
    the other side (more than 0.1 from the midline) or a region far from
    the marker leaves the geometry's region in place with an open question.
    """
    xy, levels = face_coordinates(np.asarray(points_on_mesh, dtype=float), marks)
    hints = hints or {}
    out = []
    for label, (x, y) in zip(labels, xy):
        geo = _geometry(float(x), float(y), levels)
        hint: NameHint | None = hints.get(label)
        named = hint.region if hint is not None else None
        if named is None or named == "head":
            out.append(RegionGuess(label, geo, geo, "geometry", float(x), float(y)))
            continue
        if named == geo:
            out.append(RegionGuess(label, geo, geo, "both", float(x), float(y)))
            continue
        wrong_side = (hint.side is not None and abs(x) > _BORDER
                      and (hint.side == "left") != (x > 0))
        close = _near_border(float(x), float(y), levels, named) or \
            _base(named) in ADJACENT.get(_base(geo), set())
        if close and not wrong_side:
            out.append(RegionGuess(label, named, geo, "name", float(x), float(y)))
            continue
        why = ("on the subject's other side" if wrong_side else f"far from {named}")
        question = (f"marker {label!r}: its name says {named}, but it sits at the {geo} "
                    f"({why}; face coordinates x = {x:+.2f}, y = {y:.2f}): move it to the "
                    "right list of [regions]")
        out.append(RegionGuess(label, geo, geo, "geometry", float(x), float(y), question))
    return out
