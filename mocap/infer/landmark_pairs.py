"""Which marker sits on which anatomical point: landmark pairs by geometry and by name.

The binding meets a marker-set landmark with the mesh landmark of the same
name (:func:`mocap.bind.bind_markers`). :func:`pair_landmarks` picks, for each
anatomical point, the marker of the right region nearest to the mesh's point
(or the extreme one: the mouth corners are the lip markers farthest from the
midline, the inner and outer brow markers the brow's ends), and takes a
marker's name when it names the point and sits in the right region.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.anatomy import ANATOMICAL_POINTS
from mocap.infer.mesh_landmarks import MeshLandmarks

__all__ = ["LandmarkPair", "pair_landmarks", "marks_level"]

#: Anatomical point -> (regions it may sit in, mesh point to be near or None
#: for an extreme, how far from it in mouth-eye heights).
_NEAR = {
    "upper_lip_top": (("upper_lip",), "upper_lip_top", 0.25),
    "lower_lip_bottom": (("lower_lip",), "lower_lip_bottom", 0.25),
    "nose_tip": (("nose",), "nose_tip", 0.15),
    "nose_bridge": (("nose", "forehead", "head"), "nose_bridge", 0.12),
    "chin": (("chin",), "chin", 0.25),
}
_MIDLINE = 0.15


@dataclass(frozen=True)
class LandmarkPair:
    """One anatomical point and the marker on it.

    Attributes
    ----------
    point : str
    label : str
    source : {"geometry", "name", "both"}
    how : str
        One sentence: why this marker.
    """

    point: str
    label: str
    source: str
    how: str


def pair_landmarks(labels, regions: dict, xy: np.ndarray, on_mesh: np.ndarray,
                   marks: MeshLandmarks, mesh_vertices: np.ndarray, *, hints=None,
                   height: float) -> list:
    """Marker-set landmarks (anatomical point -> marker) of a capture.

    Parameters
    ----------
    labels : sequence of str
        Markers (face markers, then head markers), M of them.
    regions : mapping of str to str
        Region of each marker (``"head"`` for head markers).
    xy : ndarray of shape (M, 2)
        Normalized face coordinates (:func:`mocap.infer.regions.face_coordinates`).
    on_mesh : ndarray of shape (M, 3), mesh units
        Each marker's closest mesh point.
    marks : MeshLandmarks
    mesh_vertices : ndarray of shape (N, 3)
    hints : mapping of str to NameHint, optional
    height : float
        Mouth-to-eye-corner height, mesh units.

    Returns
    -------
    list of LandmarkPair
        At most one per point, one point per marker.
    """
    labels = list(labels)
    hints = hints or {}
    region = np.array([regions[x] for x in labels])
    x = xy[:, 0]
    pairs, used = {}, set()

    def take(point, index, how):
        label = labels[index]
        named = hints.get(label)
        source = "both" if named is not None and named.point == point else "geometry"
        pairs[point] = LandmarkPair(point, label, source, how)
        used.add(label)

    for point, label in ((h.point, h.label) for h in hints.values() if h.point is not None):
        if label in labels and point not in pairs and label not in used:
            i = labels.index(label)
            if _fits(point, region[i], x[i]):
                pairs[point] = LandmarkPair(point, label, "name",
                                            f"its name {hints[label].name!r} says so")
                used.add(label)
    for side, sign in (("left", 1), ("right", -1)):
        point = f"mouth_corner_{side}"
        if point not in pairs:
            for group, how in ((("mouth_corners",), "the mouth-corner marker farthest out"),
                               (("upper_lip", "lower_lip"), "the lip marker farthest out")):
                pool = [i for i in range(len(labels)) if region[i] in group
                        and sign * x[i] > 0 and labels[i] not in used]
                if pool:
                    take(point, max(pool, key=lambda i: sign * x[i]), how + f" on the {side}")
                    break
        for part in ("brow", "eye"):
            pool = [i for i in range(len(labels)) if region[i] == f"{side}_{part}"
                    and labels[i] not in used]
            for where in ("inner", "outer"):
                point = f"{part}_{where}_{side}"
                if point in pairs or not pool:
                    continue
                if part == "brow":
                    if len(pool) >= 2:
                        inner = where == "inner"
                        pick = (min if inner else max)(pool, key=lambda i: abs(x[i]))
                        take(point, pick, f"the {side} brow marker "
                                          f"{'nearest to' if inner else 'farthest from'} the "
                                          "midline")
                    continue
                mesh_point = mesh_vertices[marks.landmarks[point]] if point in marks.landmarks \
                    else None
                if mesh_point is None:
                    continue
                dist = np.linalg.norm(on_mesh[pool] - mesh_point, axis=1)
                if dist.min() <= 0.12 * height:
                    pick = pool[int(np.argmin(dist))]
                    take(point, pick, f"the {side} eye marker nearest the mesh's {point}")
                    pool = [i for i in pool if i != pick]
        point = f"nose_{side}"
        pool = [i for i in range(len(labels)) if region[i] == "nose" and sign * x[i] > 0.2
                and xy[i, 1] < marks_level(marks, height, "nose_tip") and labels[i] not in used]
        if point not in pairs and pool:
            take(point, max(pool, key=lambda i: sign * x[i]),
                 f"the nose marker farthest out on the {side}, below the tip")
    for point, (allowed, target, tol) in _NEAR.items():
        if point in pairs or target not in marks.landmarks:
            continue
        pool = [i for i in range(len(labels)) if region[i] in allowed
                and abs(x[i]) <= _MIDLINE and labels[i] not in used]
        if not pool:
            continue
        dist = np.linalg.norm(on_mesh[pool] - mesh_vertices[marks.landmarks[target]], axis=1)
        if dist.min() <= tol * height:
            take(point, pool[int(np.argmin(dist))],
                 f"the midline marker nearest the mesh's {target}")
    return [pairs[p] for p in sorted(pairs, key=_order)]


def marks_level(marks: MeshLandmarks, height: float, name: str) -> float:
    """Normalized height (above the mouth corners, in mouth-eye heights) of a mesh landmark."""
    c = marks.coordinates
    mouth = (c["mouth_corner_left"][1] + c["mouth_corner_right"][1]) / 2
    return float((c[name][1] - mouth) / height) if name in c else np.inf


def _fits(point: str, region: str, x: float) -> bool:
    """Whether a marker in `region` at normalized `x` may sit on `point`."""
    side = "left" if x > 0 else "right"
    if point.startswith("mouth_corner"):
        return region in ("mouth_corners", "upper_lip", "lower_lip") and point.endswith(side)
    for part in ("eye", "brow"):
        if point.startswith(part):
            return region == f"{side}_{part}" and point.endswith(side)
    if point in _NEAR:
        return region in _NEAR[point][0]
    return True


def _order(point: str) -> int:
    return ANATOMICAL_POINTS.index(point) if point in ANATOMICAL_POINTS else len(ANATOMICAL_POINTS)
