"""The demo's marker layout, marker set and mesh landmarks.

60 face markers following facial-capture practice (lips, philtrum and
mentolabial fold, mouth corners, brows, lids and lower eye rims, nose,
cheeks, forehead, chin, jaw line) and 5 head markers on the parts no shape
moves (upper forehead, temples), all 2 mm off the skin. Positions are given
in the front view (x, y) mm and dropped onto the surface.
"""

from __future__ import annotations

import matplotlib.tri as mtri
import numpy as np

from fit.demo.face import EYES, MOUTH, FaceModel, mouth_line
from mocap.mesh.layout import MarkerLayout, make_layout

__all__ = ["HEAD_MARKERS", "MARKER_OFFSET_MM", "marker_regions", "demo_layout",
           "markerset_toml", "landmarks_toml"]

#: Distance of every marker off the skin, mm.
MARKER_OFFSET_MM = 2.0
#: Head markers (front-view x, y mm): upper forehead and temples.
HEAD_MARKERS = {"head-1": (-24.0, 98.0), "head-2": (0.0, 103.0), "head-3": (24.0, 98.0),
                "head-4": (-64.0, 22.0), "head-5": (64.0, 22.0)}

#: Anatomical point -> marker label, for the marker set's [landmarks].
_LANDMARK_MARKERS = {
    "mouth_corner_left": "mouth-corner-L", "mouth_corner_right": "mouth-corner-R",
    "upper_lip_top": "lip-upper3", "lower_lip_bottom": "lip-lower3",
    "eye_inner_left": "eye-L-inner", "eye_outer_left": "eye-L-outer",
    "eye_inner_right": "eye-R-inner", "eye_outer_right": "eye-R-outer",
    "nose_tip": "nose-tip", "nose_left": "nose-L", "nose_right": "nose-R", "chin": "chin",
    "brow_inner_left": "brow-L1", "brow_outer_left": "brow-L4",
    "brow_inner_right": "brow-R1", "brow_outer_right": "brow-R4"}


def _mirror(markers: dict) -> dict:
    """Right-side copies of left-side markers: ``-L`` -> ``-R``, x -> -x."""
    return {label.replace("-L", "-R"): (-x, y) for label, (x, y) in markers.items()}


def marker_regions() -> dict:
    """Face markers by region: region -> {label: (x, y) mm in the front view}."""
    gap = MOUTH["half_gap"]
    lip_x = (-16.0, -8.0, 0.0, 8.0, 16.0)
    taper = [np.sqrt(1 - (x / MOUTH["half_width"]) ** 2) for x in lip_x]
    upper = {f"lip-upper{i + 1}": (x, float(mouth_line(x)) + gap * k + 2.5)
             for i, (x, k) in enumerate(zip(lip_x, taper))}
    lower = {f"lip-lower{i + 1}": (x, float(mouth_line(x)) - gap * k - 3.0)
             for i, (x, k) in enumerate(zip(lip_x, taper))}
    corner_x = MOUTH["half_width"] + 3.0
    (ex, ey), hw = EYES[0]["center"], EYES[0]["half_width"]
    left = {
        "brow": {"brow-L1": (12.0, 45.0), "brow-L2": (24.0, 48.0), "brow-L3": (36.0, 48.0),
                 "brow-L4": (48.0, 45.0)},
        "eye": {"eye-L-inner": (ex - hw - 3.0, ey - 1.0), "eye-L-outer": (ex + hw + 3.0, ey + 2.0),
                "eye-L-upper": (ex, ey + 9.0), "eye-L-lower1": (ex - 8.0, ey - 7.0),
                "eye-L-lower2": (ex, ey - 7.5), "eye-L-lower3": (ex + 8.0, ey - 6.5)},
        "cheek": {"cheek-L1": (45.0, 10.0), "cheek-L2": (55.0, -6.0), "cheek-L3": (38.0, -12.0),
                  "cheek-L4": (44.0, -30.0), "cheek-L5": (58.0, -26.0)},
    }
    return {
        "upper_lip": {**upper, "philtrum-L": (5.0, -27.0), "philtrum-R": (-5.0, -27.0)},
        "lower_lip": {**lower, "mentolabial-L": (9.0, -52.0), "mentolabial-R": (-9.0, -52.0)},
        "left_brow": left["brow"], "right_brow": _mirror(left["brow"]),
        "left_eye": left["eye"], "right_eye": _mirror(left["eye"]),
        "other": {},
        "mouth_corners": {"mouth-corner-L": (corner_x, float(mouth_line(corner_x))),
                          "mouth-corner-R": (-corner_x, float(mouth_line(-corner_x)))},
        "nose": {"nose-tip": (0.0, 0.0), "nose-dorsum": (0.0, 18.0), "nose-L": (16.0, -7.0),
                 "nose-R": (-16.0, -7.0)},
        "left_cheek": left["cheek"], "right_cheek": _mirror(left["cheek"]),
        "forehead": {"forehead-L": (22.0, 68.0), "forehead-R": (-22.0, 68.0),
                     "glabella": (0.0, 42.0)},
        "chin": {"chin": (0.0, -75.0), "chin-L": (16.0, -70.0), "chin-R": (-16.0, -70.0)},
        "jaw": {"jaw-L1": (50.0, -40.0), "jaw-L2": (34.0, -66.0), "jaw-R1": (-50.0, -40.0),
                "jaw-R2": (-34.0, -66.0)},
    }


def demo_layout(face: FaceModel) -> MarkerLayout:
    """Head and face markers on the demo face (:data:`MARKER_OFFSET_MM` off the skin).

    Each front-view point is dropped on the triangle under it (the face is a
    height field over x-y) at its barycentric coordinates.

    Returns
    -------
    MarkerLayout
        Head markers first, then the face markers region by region; units mm.
    """
    points = dict(HEAD_MARKERS)
    for markers in marker_regions().values():
        points.update(markers)
    xy = np.array(list(points.values()))
    v, faces = face.mesh.vertices, face.mesh.faces
    tri = mtri.Triangulation(v[:, 0], v[:, 1], faces)
    face_ids = tri.get_trifinder()(xy[:, 0], xy[:, 1])
    if np.any(face_ids < 0):  # pragma: no cover - a layout bug, not an input error
        raise RuntimeError(f"demo markers off the face: {np.array(list(points))[face_ids < 0]}")
    corners = v[faces[face_ids], :2]                                     # (M, 3, 2)
    edges = np.stack([corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]], axis=2)
    b12 = np.linalg.solve(edges, (xy - corners[:, 0])[..., None])[..., 0]
    bary = np.column_stack([1 - b12.sum(axis=1), b12]).clip(0, 1)
    bary /= bary.sum(axis=1, keepdims=True)
    specs = {label: {"face": int(f), "bary": tuple(b)}
             for label, f, b in zip(points, face_ids, bary)}
    return make_layout(face.mesh, specs, offset=MARKER_OFFSET_MM, name="demo")


def _toml_list(labels) -> str:
    return "[" + ", ".join(f'"{label}"' for label in labels) + "]"


def markerset_toml() -> str:
    """The demo marker set as TOML text (:func:`mocap.markerset.load_markerset`)."""
    lines = ["# Marker set of the mocap2mesh demo session: 5 head markers, 60 face markers.",
             "# Left and right are the subject's own (+x on the demo mesh).",
             'name = "demo"', f"head = {_toml_list(HEAD_MARKERS)}", "", "[regions]"]
    lines += [f"{region} = {_toml_list(markers)}" for region, markers in marker_regions().items()]
    lines += ["", "[landmarks]"]
    lines += [f'{point} = "{label}"' for point, label in _LANDMARK_MARKERS.items()]
    return "\n".join(lines) + "\n"


def landmarks_toml(face: FaceModel) -> str:
    """The demo face's mesh landmarks as TOML text.

    Read back by :func:`mocap.mesh.landmarks.load_mesh_landmarks`.
    """
    lines = ["# Anatomical points of the demo face (neutral.obj) by 0-based vertex id.",
             'mesh = "mocap2mesh demo face (neutral.obj)"',
             f"n_vertices = {face.mesh.n_vertices}", "", "[landmarks]"]
    lines += [f"{point} = {vertex}" for point, vertex in face.landmarks.items()]
    return "\n".join(lines) + "\n"
