"""The demo face: a procedural face mask with eye and mouth openings, in millimetres.

The surface is a height field ``z = h(x, y)`` over an egg-shaped outline in
the x-y plane (x the subject's left, y up, z towards the viewer, as the ICT
face): an ellipsoid cap with a nose, brow ridge, eye sockets, cheekbones,
lips and chin added as smooth bumps. The outline is cut by two almond eye
openings and a thin mouth slit, so that the lips are separate like on a
real face model: four boundary loops (rim, two eyes, mouth).

Triangulation: the outline and the openings are sampled at the mesh spacing,
rings of points are laid parallel to them, a hexagonal grid fills the rest,
and a 2-D Delaunay triangulation keeps the triangles inside the outline and
outside the openings; the points are then lifted onto the height field.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from matplotlib.path import Path as _Polygon
from scipy.spatial import Delaunay, cKDTree

from mocap.mesh.mesh import Mesh, boundary_loops

__all__ = ["FaceModel", "make_face", "MOUTH", "EYES", "height", "mouth_line", "eye_line"]

#: Mouth slit: centre (x, y) mm, half-width, half-gap at the midline and how
#: far the corners sit above the midline of the lip contact line, mm.
MOUTH = {"center": (0.0, -38.0), "half_width": 24.0, "half_gap": 1.2, "corner_lift": 1.0}
#: Eye openings, subject's left then right: centre, half-width, upper and
#: lower half-heights, outer-corner lift, mm.
EYES = ({"center": (33.0, 30.0), "half_width": 13.0, "upper": 5.5, "lower": 4.0, "tilt": 1.5},
        {"center": (-33.0, 30.0), "half_width": 13.0, "upper": 5.5, "lower": 4.0, "tilt": 1.5})

#: Outline: half-width, top and bottom half-heights about ``y = 8``, jaw taper.
_RIM = {"half_width": 72.0, "top": 102.0, "bottom": 103.0, "y0": 8.0, "taper": 0.35}

# Smooth bumps of the height field: (cx, cy, sx, sy, height mm); x mirrored when cx != 0.
_BUMPS = (
    (33.0, 30.0, 15.0, 10.0, -10.0),   # eye socket
    (30.0, 46.0, 18.0, 5.0, 5.0),      # brow ridge
    (0.0, 43.0, 10.0, 5.0, 3.0),       # glabella
    (45.0, 12.0, 13.0, 10.0, 7.0),     # cheekbone
    (38.0, -18.0, 14.0, 14.0, 4.0),    # cheek
    (62.0, 40.0, 10.0, 15.0, -5.0),    # temple
    (15.0, -6.0, 5.0, 4.5, 7.0),       # nose wing (ala)
    (0.0, 0.0, 7.0, 6.0, 4.0),         # nose tip
    (0.0, -38.0, 28.0, 14.0, 6.0),     # mouth mound
    (0.0, -34.0, 20.0, 3.5, 4.0),      # upper lip
    (0.0, -42.5, 17.0, 3.5, 4.5),      # lower lip
    (0.0, -52.0, 15.0, 3.0, -2.0),     # mentolabial sulcus
    (0.0, -72.0, 16.0, 10.0, 8.0),     # chin
)


@dataclass(frozen=True, eq=False)
class FaceModel:
    """The demo face mesh and where its features are.

    Attributes
    ----------
    mesh : Mesh
        The neutral face, N vertices, ``units="mm"``.
    landmarks : dict of str to int
        Anatomical point (:mod:`mocap.anatomy`) to vertex id.
    rim, mouth, eye_left, eye_right : ndarray of int
        Vertex ids of the four boundary loops, in polygon order. The mouth loop
        runs from the right corner along the upper lip to the left corner and
        back along the lower lip.
    upper_lip, lower_lip : ndarray of int
        The mouth loop's upper-lip and lower-lip vertices (corners excluded).
    """

    mesh: Mesh
    landmarks: dict = field(repr=False)
    rim: np.ndarray = field(repr=False)
    mouth: np.ndarray = field(repr=False)
    eye_left: np.ndarray = field(repr=False)
    eye_right: np.ndarray = field(repr=False)
    upper_lip: np.ndarray = field(repr=False)
    lower_lip: np.ndarray = field(repr=False)


def _bump(x, y, cx, cy, sx, sy):
    return np.exp(-0.5 * (((x - cx) / sx) ** 2 + ((y - cy) / sy) ** 2))


def height(x, y) -> np.ndarray:
    """Height of the face surface ``z = h(x, y)``, mm, for arrays of points (mm)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    cap = 1.0 - (x / 85.0) ** 2 - ((y - 5.0) / 135.0) ** 2
    z = 90.0 * np.sqrt(np.clip(cap, 0.05, None))
    for cx, cy, sx, sy, h in _BUMPS:
        z = z + h * _bump(x, y, cx, cy, sx, sy)
        if cx:
            z = z + h * _bump(x, y, -cx, cy, sx, sy)
    # the nose: a ridge from the bridge (y = 32) growing to the tip (y = 0), then cut under it
    sy = np.where(y > 0, 17.0, 5.0)
    ridge = 22.0 * np.exp(-0.5 * (y / sy) ** 2) + 4.0 * np.exp(-0.5 * ((y - 22) / 10) ** 2)
    width = 5.0 + 4.0 * np.exp(-0.5 * (y / 12.0) ** 2)
    return z + ridge * np.exp(-0.5 * (x / width) ** 2)


def mouth_line(x) -> np.ndarray:
    """y of the lip contact line (the slit's midline) at x, mm."""
    cx, cy = MOUTH["center"]
    return cy + MOUTH["corner_lift"] * ((np.asarray(x, float) - cx) / MOUTH["half_width"]) ** 2


def _mouth_half_gap(x):
    t = np.clip(1.0 - ((x - MOUTH["center"][0]) / MOUTH["half_width"]) ** 2, 0.0, None)
    return MOUTH["half_gap"] * np.sqrt(t)


def eye_line(x, eye) -> np.ndarray:
    """y of the midline of an eye opening (see :data:`EYES`) at x, mm."""
    cx, cy = eye["center"]
    return cy + eye["tilt"] * (np.asarray(x, float) - cx) / eye["half_width"] * np.sign(cx)


def _closed_resample(points, spacing):
    """Points every `spacing` mm (about) along a closed polyline (K, 2)."""
    loop = np.vstack([points, points[:1]])
    s = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(loop, axis=0), axis=1))])
    n = max(8, int(round(s[-1] / spacing)))
    t = np.linspace(0, s[-1], n, endpoint=False)
    return np.column_stack([np.interp(t, s, loop[:, 0]), np.interp(t, s, loop[:, 1])])


def _open_resample(points, spacing):
    """Points every `spacing` mm (about) along an open polyline, both ends kept."""
    s = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    n = max(2, int(round(s[-1] / spacing)))
    t = np.linspace(0, s[-1], n + 1)
    return np.column_stack([np.interp(t, s, points[:, 0]), np.interp(t, s, points[:, 1])])


def _rim_outline(spacing):
    th = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
    s = np.sin(th)
    x = _RIM["half_width"] * np.cos(th) * (1 - _RIM["taper"] * np.clip(-s, 0, None) ** 2)
    y = _RIM["y0"] + np.where(s > 0, _RIM["top"], _RIM["bottom"]) * s
    return _closed_resample(np.column_stack([x, y]), spacing)


def _mouth_outline(spacing):
    """Mouth polygon: right corner, upper lip to the left corner, lower lip back (CCW hole)."""
    cx, w = MOUTH["center"][0], MOUTH["half_width"]
    x = cx - w * np.cos(np.linspace(0, np.pi, 1000))
    upper = _open_resample(np.column_stack([x, mouth_line(x) + _mouth_half_gap(x)]),
                           spacing)
    x = upper[:, 0]
    lower = np.column_stack([x, mouth_line(x) - _mouth_half_gap(x)])  # mirrored samples
    ring = np.vstack([upper, lower[-2:0:-1]])
    n_upper = len(upper)
    return ring, np.arange(1, n_upper - 1), np.arange(n_upper, len(ring)), (0, n_upper - 1)


def _eye_outline(eye, spacing):
    cx, cy = eye["center"]
    t = np.linspace(0, 2 * np.pi, 1000, endpoint=False)
    x = cx + eye["half_width"] * np.cos(t)
    half = np.where(np.sin(t) > 0, eye["upper"], eye["lower"])
    lift = eye["tilt"] * np.cos(t) * np.sign(cx)          # outer corner up
    return _closed_resample(np.column_stack([x, cy + lift + half * np.sin(t)]), spacing)


def _offset(ring, distance, spacing):
    """A closed polyline moved `distance` mm along its left normals, resampled."""
    tangent = np.roll(ring, -1, axis=0) - np.roll(ring, 1, axis=0)
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    return _closed_resample(ring + distance * normal, spacing)


def _orient(ring, ccw):
    area = 0.5 * np.sum(ring[:, 0] * np.roll(ring[:, 1], -1) - np.roll(ring[:, 0], -1) * ring[:, 1])
    return ring if (area > 0) == ccw else ring[::-1]


def make_face(*, spacing: float = 2.0) -> FaceModel:
    """Build the demo face mesh.

    Parameters
    ----------
    spacing : float, default 2
        Edge length of the triangulation in the x-y plane, mm (2 mm gives
        about 6,000 vertices).

    Returns
    -------
    FaceModel
        A connected surface with four boundary loops (rim, two eyes, mouth),
        triangles facing +z, ``units="mm"``; deterministic.
    """
    h = float(spacing)
    rim = _orient(_rim_outline(h), ccw=True)
    mouth, upper_idx, lower_idx, corners = _mouth_outline(h)
    eyes = [_orient(_eye_outline(eye, h), ccw=True) for eye in EYES]
    holes = [mouth] + eyes
    # rings: offsets of the outline inwards, of the holes outwards (left normal of a CW loop)
    rings = [_offset(rim, 0.9 * h, h)]
    for hole in holes:
        cw = _orient(hole, ccw=False)
        rings += [_offset(cw, 0.9 * h, h), _offset(cw, 1.8 * h, h)]
    fixed = np.vstack([rim, *holes, *rings])
    xs = np.arange(-80.0, 80.0, h)
    ys = np.arange(-100.0, 115.0, h * np.sqrt(3) / 2)
    gx, gy = np.meshgrid(xs, ys)
    gx = gx + (np.arange(len(ys))[:, None] % 2) * h / 2
    grid = np.column_stack([gx.ravel(), gy.ravel()])
    outline, hole_paths = _Polygon(rim), [_Polygon(p) for p in holes]
    dense = np.vstack([_closed_resample(r, h / 4) for r in [rim, *holes, *rings]])
    far = cKDTree(dense).query(grid)[0] > 0.75 * h
    keep = far & outline.contains_points(grid)
    for path in hole_paths:
        keep &= ~path.contains_points(grid)
    points = np.vstack([fixed, grid[keep]])

    tri = Delaunay(points).simplices
    corners_xy = points[tri]                                            # (F, 3, 2)
    probes = [corners_xy.mean(axis=1)] + [
        0.8 * 0.5 * (corners_xy[:, i] + corners_xy[:, (i + 1) % 3]) + 0.2 * corners_xy.mean(axis=1)
        for i in range(3)]
    inside = np.ones(len(tri), bool)
    for probe in probes:
        inside &= outline.contains_points(probe)
        for path in hole_paths:
            inside &= ~path.contains_points(probe)
    faces = tri[inside]
    a, b, c = (points[faces[:, k]] for k in range(3))
    ccw = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    faces = np.where((ccw > 0)[:, None], faces, faces[:, ::-1])

    vertices = np.column_stack([points, height(points[:, 0], points[:, 1])])
    mesh = Mesh(vertices, faces, units="mm")
    starts = np.cumsum([0, len(rim), len(mouth), len(eyes[0]), len(eyes[1])])
    ids = [np.arange(starts[i], starts[i + 1]) for i in range(4)]
    mouth_ids = ids[1]
    _check_loops(mesh, ids)
    return FaceModel(mesh=mesh, landmarks=_landmarks(vertices, mouth_ids, upper_idx,
                                                     lower_idx, corners, ids[2], ids[3]),
                     rim=ids[0], mouth=mouth_ids, eye_left=ids[2], eye_right=ids[3],
                     upper_lip=mouth_ids[upper_idx], lower_lip=mouth_ids[lower_idx])


def _check_loops(mesh, expected):
    """The triangulation must have exactly the four sampled polygons as boundary."""
    loops = boundary_loops(mesh)
    found = sorted(tuple(sorted(loop.tolist())) for loop in loops)
    wanted = sorted(tuple(ids.tolist()) for ids in expected)
    if found != wanted:  # pragma: no cover - a geometry bug, not an input error
        raise RuntimeError(f"demo face triangulation has {len(loops)} boundary loops "
                           f"of sizes {[len(x) for x in loops]}, expected 4 "
                           f"({[len(x) for x in expected]})")


def _nearest(vertices, xy):
    return int(np.argmin(np.sum((vertices[:, :2] - np.asarray(xy, float)) ** 2, axis=1)))


def _landmarks(vertices, mouth_ids, upper_idx, lower_idx, corners, eye_left, eye_right):
    mid_upper = mouth_ids[upper_idx][np.argmin(np.abs(vertices[mouth_ids[upper_idx], 0]))]
    mid_lower = mouth_ids[lower_idx][np.argmin(np.abs(vertices[mouth_ids[lower_idx], 0]))]
    right_corner, left_corner = mouth_ids[corners[0]], mouth_ids[corners[1]]

    def eye_corner(ids, inner):
        x = vertices[ids, 0]
        return int(ids[np.argmin(np.abs(x)) if inner else np.argmax(np.abs(x))])

    lm = {"mouth_corner_left": int(left_corner), "mouth_corner_right": int(right_corner),
          "upper_lip_top": _nearest(vertices, (0.0, mouth_line(0.0) + 7.0)),
          "upper_lip_bottom": int(mid_upper), "lower_lip_top": int(mid_lower),
          "lower_lip_bottom": _nearest(vertices, (0.0, mouth_line(0.0) - 8.0)),
          "eye_inner_left": eye_corner(eye_left, True),
          "eye_outer_left": eye_corner(eye_left, False),
          "eye_inner_right": eye_corner(eye_right, True),
          "eye_outer_right": eye_corner(eye_right, False)}
    points = {"nose_tip": (0, 0), "nose_bridge": (0, 34), "nose_left": (16, -7),
              "nose_right": (-16, -7), "subnasale": (0, -12), "chin": (0, -78),
              "jaw_left": (60, -50), "jaw_right": (-60, -50),
              "brow_inner_left": (14, 46), "brow_mid_left": (30, 49),
              "brow_outer_left": (46, 46), "brow_inner_right": (-14, 46),
              "brow_mid_right": (-30, 49), "brow_outer_right": (-46, 46),
              "cheek_left": (45, 2), "cheek_right": (-45, 2), "forehead": (0, 80)}
    lm.update({name: _nearest(vertices, xy) for name, xy in points.items()})
    return lm
