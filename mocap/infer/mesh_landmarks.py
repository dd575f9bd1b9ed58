"""Landmarks of a face mesh found from the mesh itself: the Maskle's ten points and a few more.

The ten points the Maskle places its mask with (Maskle paper: the lateral
ends of the lips, the highest and lowest points of both lips on the central
axis, the inner and outer corners of both eyes) come from the mesh's
boundary loops and its symmetry plane:

- the mouth opening and the two eye holes are boundary loops (a face cut
  out of a head has one more, its outer rim): the mouth corners and the eye
  corners are their extremes along the left-right axis, the lips' contact
  points (``upper_lip_bottom``, ``lower_lip_top``) where the mouth loop
  crosses the symmetry plane;
- the midline profile (the surface cut by the symmetry plane) gives the
  rest: the vermilion borders (``upper_lip_top``, ``lower_lip_bottom``) are
  the lips' most forward points on it, with the nose tip, the subnasale, the
  nasion (``nose_bridge``), the labiomental fold and the chin (pogonion).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import median_filter
from scipy.signal import find_peaks

from mocap.anatomy import MASKLE_POINTS
from mocap.errors import InputError
from mocap.infer.axes import FaceAxes, symmetry_plane
from mocap.mesh.mesh import Mesh, boundary_loops

__all__ = ["MeshLandmarks", "find_mesh_landmarks", "mesh_axes_from_landmarks",
           "FOUND_POINTS"]

#: The points :func:`find_mesh_landmarks` finds: the Maskle's ten, then the
#: midline points that place markers (nose, chin).
FOUND_POINTS = MASKLE_POINTS + ("nose_tip", "subnasale", "nose_bridge", "chin")


@dataclass(frozen=True, eq=False)
class MeshLandmarks:
    """Landmarks of a mesh and the face frame they define.

    Attributes
    ----------
    landmarks : dict of str to int
        Anatomical point -> vertex id.
    axes : FaceAxes
        The mesh's face axes (mesh units): left from the symmetry plane,
        up from the mouth to the eyes, forward out of the face.
    levels : dict of str to float
        Heights along ``axes.up`` (mesh units, about ``axes.origin``) of the
        profile points: ``nose_tip``, ``subnasale``, ``nasion``,
        ``labiomental``, ``chin``, ``eye_top``, ``eye_bottom``.
    mouth : ndarray of int
        Vertex ids of the mouth loop (empty when the landmarks were given).
    eyes : tuple of ndarray of int
        Vertex ids of the left and the right eye loop.
    coordinates : dict of str to ndarray of shape (3,)
        Face coordinates (left, up, forward) of each landmark, mesh units.
    mouth_line : ndarray of shape (k, 2)
        The lips' contact line from corner to corner: (left, up) face
        coordinates, mesh units, midway between the mouth loop's upper and
        lower arcs (empty when the landmarks were given).
    found : bool
        Found from the mesh (False: read from a landmark file).
    notes : tuple of str
        How each point was found.
    """

    landmarks: dict
    axes: FaceAxes
    levels: dict
    coordinates: dict
    mouth_line: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    mouth: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    eyes: tuple = ()
    found: bool = True
    notes: tuple = ()


def _perimeter(points: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(np.vstack([points, points[:1]]), axis=0), axis=1).sum())


def _pick_loops(vertices, loops) -> tuple:
    """(mouth, eye_a, eye_b) among the inner loops: two alike, mirrored about the third."""
    rim = int(np.argmax([_perimeter(vertices[lp]) for lp in loops])) if loops else -1
    inner = [lp for k, lp in enumerate(loops) if k != rim]
    if len(inner) < 3:
        raise InputError(f"the mesh has {len(loops)} boundary loops; finding its landmarks "
                         "needs a mouth opening and two eye holes besides the outer rim (a "
                         "face whose lips are not joined, with open eyes): give its landmarks "
                         "as a file (--landmarks)")
    stats = [(vertices[lp].mean(axis=0), _perimeter(vertices[lp])) for lp in inner]
    best, choice = np.inf, None
    for m, (cm, _) in enumerate(stats):
        for a in range(len(inner)):
            for b in range(a + 1, len(inner)):
                if m in (a, b):
                    continue
                (ca, pa), (cb, pb) = stats[a], stats[b]
                gap = np.linalg.norm(ca - cb)
                # eyes alike in size, the mouth equidistant from them
                cost = (abs(pa - pb) / max(pa, pb)
                        + abs(np.linalg.norm(cm - ca) - np.linalg.norm(cm - cb)) / gap)
                if cost < best:
                    best, choice = cost, (inner[m], inner[a], inner[b])
    return loops[rim], *choice


def _profile(vertices, faces, normal, offset, samples: int = 12) -> np.ndarray:
    """Points (k, 3) of the curve where the surface crosses the plane ``normal . p = offset``.

    Each triangle that straddles the plane contributes its segment, sampled
    at `samples` points, so that the curve is dense wherever the mesh is coarse.
    """
    side = vertices @ normal - offset
    scale = np.abs(side).max()
    side = np.where(np.abs(side) < 1e-9 * scale, 1e-9 * scale, side)   # no vertex on the plane
    s = side[faces]                                                    # (F, 3)
    ends = []
    for k in range(3):                                                 # the 3 edges of a face
        a, b = s[:, k], s[:, (k + 1) % 3]
        t = np.where(a * b < 0, a / np.where(a == b, 1.0, a - b), np.nan)
        p, q = vertices[faces[:, k]], vertices[faces[:, (k + 1) % 3]]
        ends.append(p + t[:, None] * (q - p))
    ends = np.stack(ends, axis=1)                                      # (F, 3 edges, 3)
    crossing = ~np.isnan(ends[..., 0])
    straddle = crossing.sum(axis=1) == 2
    pairs = ends[straddle][crossing[straddle]].reshape(-1, 2, 3)
    u = np.linspace(0.0, 1.0, samples)[None, :, None]
    return (pairs[:, :1] * (1 - u) + pairs[:, 1:] * u).reshape(-1, 3)


def _front(coords, step):
    """The front of the profile: the most forward point per height bin, median-smoothed.

    Returns heights (k,) and forward coordinates (k,); the inside of the mouth
    and nostrils lies behind the front and does not count.
    """
    grid = np.arange(coords[:, 1].min(), coords[:, 1].max() + step, step)
    bins = np.clip(np.digitize(coords[:, 1], grid) - 1, 0, len(grid) - 1)
    front = np.full(len(grid), -np.inf)
    np.maximum.at(front, bins, coords[:, 2])
    good = np.isfinite(front)
    front = np.interp(grid, grid[good], front[good])
    return grid, median_filter(front, size=5, mode="nearest")


def _peaks(front, prominence) -> tuple:
    """Indices of the bulges and of the hollows of the front."""
    return (find_peaks(front, prominence=prominence)[0],
            find_peaks(-front, prominence=prominence)[0])


def _between(indices, grid, lo, hi) -> np.ndarray:
    return np.array([i for i in indices if min(lo, hi) < grid[i] < max(lo, hi)], dtype=int)


def _mouth_line(loop: np.ndarray, n: int = 41) -> np.ndarray:
    """Points (n, 2) midway between the upper and lower arcs of the mouth loop (x, y)."""
    left, right = int(np.argmax(loop[:, 0])), int(np.argmin(loop[:, 0]))
    a, b = sorted((left, right))
    arcs = [loop[a:b + 1], np.vstack([loop[b:], loop[:a + 1]])]
    xs = np.linspace(loop[right, 0], loop[left, 0], n)
    ys = []
    for arc in arcs:
        order = np.argsort(arc[:, 0])
        ys.append(np.interp(xs, arc[order, 0], arc[order, 1]))
    return np.c_[xs, (ys[0] + ys[1]) / 2]


def _nearest_vertex(vertices, coords_of_vertices, target, candidates=None) -> int:
    ids = np.arange(len(vertices)) if candidates is None else np.asarray(candidates)
    return int(ids[np.argmin(((coords_of_vertices[ids] - target) ** 2).sum(axis=1))])


def _profile_levels(grid, front, bulges, hollows, y_arc, y_eyes, height) -> dict:
    """Heights of the profile points, walking out from the lips' contact.

    The contact (stomion) is the deepest hollow between the mouth loop's two
    crossings of the midline (``y_arc``: upper, lower); above it come the
    upper lip's bulge, the subnasale hollow and the nose tip (the highest
    bulge below the eyes); below, the lower lip's bulge, the labiomental
    hollow and the chin; the nasion is the first hollow above the nose tip
    (the eyes' height if there is none).
    """
    def deepest(lo, hi):
        inside = (grid > min(lo, hi)) & (grid < max(lo, hi))
        return float(grid[np.flatnonzero(inside)[np.argmin(front[inside])]]) if inside.any() \
            else float((lo + hi) / 2)

    def highest(lo, hi):
        inside = (grid > min(lo, hi)) & (grid < max(lo, hi))
        return float(grid[np.flatnonzero(inside)[np.argmax(front[inside])]]) if inside.any() \
            else float((lo + hi) / 2)

    def first(indices, start, direction, limit):
        ahead = [i for i in indices if 0 < (grid[i] - start) * direction < abs(limit - start)]
        return float(grid[min(ahead, key=lambda i: abs(grid[i] - start))]) if ahead else None

    top, bottom = y_arc
    levels = {"stomion": deepest(bottom - 0.02 * height, top + 0.02 * height)}
    stomion = levels["stomion"]
    levels["nose_tip"] = highest(stomion + 0.3 * height, y_eyes)
    ls = first(bulges, stomion, 1, levels["nose_tip"] - 0.1 * height)
    levels["upper_lip_top"] = ls if ls is not None else highest(stomion, stomion + 0.2 * height)
    levels["subnasale"] = deepest(levels["upper_lip_top"], levels["nose_tip"])
    nasion = first(hollows, levels["nose_tip"], 1, y_eyes + 0.4 * height)
    levels["nasion"] = nasion if nasion is not None else float(y_eyes)
    li = first(bulges, stomion, -1, stomion - 0.4 * height)
    levels["lower_lip_bottom"] = li if li is not None else highest(stomion - 0.2 * height,
                                                                    stomion)
    chin = first(bulges, levels["lower_lip_bottom"], -1, stomion - 1.0 * height)
    levels["chin"] = chin if chin is not None else highest(stomion - 0.9 * height,
                                                           levels["lower_lip_bottom"])
    levels["labiomental"] = deepest(levels["chin"], levels["lower_lip_bottom"])
    return levels


def find_mesh_landmarks(mesh: Mesh) -> MeshLandmarks:
    """The ten Maskle landmarks and four midline points of a face mesh, from its shape alone.

    Parameters
    ----------
    mesh : Mesh
        A face with open eyes and parted lips (its mouth and eye holes are
        boundary loops), in any units, any orientation.

    Returns
    -------
    MeshLandmarks
        :data:`FOUND_POINTS`, each the vertex nearest the point found.

    Raises
    ------
    InputError
        Fewer than three boundary loops besides the outer rim.

    Notes
    -----
    Axes: left is the normal of the symmetry plane through the mouth and
    between the eyes (refined by :func:`mocap.infer.axes.symmetry_plane` on
    the vertices), up goes from the mouth to the eyes, forward is
    ``left x up`` and is flipped (with left) so that the mouth lies in front
    of the rim. The profile is the set of points where edges cross the
    symmetry plane; its front (the most forward point per 0.5 % of the
    mouth-eye height) is searched for the extremes named in the module docstring.
    """
    if not isinstance(mesh, Mesh):
        raise InputError(f"mesh must be a mocap.mesh.mesh.Mesh, got {type(mesh).__name__}")
    vertices = mesh.vertices
    rim, mouth, eye_a, eye_b = _pick_loops(vertices, boundary_loops(mesh))
    c_mouth, c_a, c_b = (vertices[x].mean(axis=0) for x in (mouth, eye_a, eye_b))
    c_eyes = (c_a + c_b) / 2
    # the symmetry plane of the vertices, started between the eyes
    normal, offset, _ = symmetry_plane(vertices[np.unique(np.concatenate([mouth, eye_a,
                                                                          eye_b]))])
    origin = c_mouth - (c_mouth @ normal - offset) * normal     # on the plane, at the mouth
    faces = mesh.faces
    area = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]],
                    vertices[faces[:, 2]] - vertices[faces[:, 0]]).sum(axis=0)
    forward = area - (area @ normal) * normal               # the facial plane's normal
    forward /= np.linalg.norm(forward)
    if np.dot(c_mouth - vertices[rim].mean(axis=0), forward) < 0:
        forward = -forward
    up = np.cross(forward, normal)
    if np.dot(up, c_eyes - c_mouth) < 0:
        up = -up
    left = np.cross(up, forward)
    axes = FaceAxes(left=left, up=up, forward=forward, origin=origin, symmetry_rms=0.0,
                    evidence=("mesh: up from the mouth loop to the eye loops, forward along "
                              "the mean surface normal, out of the rim",))
    coords = axes.coordinates(vertices)
    eye_left, eye_right = (eye_a, eye_b) if coords[eye_a, 0].mean() > 0 else (eye_b, eye_a)

    marks, notes = {}, []
    mx = coords[mouth, 0]
    marks["mouth_corner_left"] = int(mouth[np.argmax(mx)])
    marks["mouth_corner_right"] = int(mouth[np.argmin(mx)])
    notes.append("mouth corners: the ends of the mouth opening (its loop's extremes from "
                 "left to right)")
    for side, loop in (("left", eye_left), ("right", eye_right)):
        lateral = np.abs(coords[loop, 0])
        marks[f"eye_inner_{side}"] = int(loop[np.argmin(lateral)])
        marks[f"eye_outer_{side}"] = int(loop[np.argmax(lateral)])
    notes.append("eye corners: each eye loop's points nearest to and farthest from the midline")

    y_mouth, y_eyes = coords[mouth, 1].mean(), coords[eye_left, 1].mean()
    height = y_eyes - y_mouth
    centre = coords[mouth, 1].mean()
    arcs = [mouth[(coords[mouth, 1] > centre) == upper] for upper in (True, False)]
    y_arc = [coords[arc[np.argmin(np.abs(coords[arc, 0]))], 1] for arc in arcs]
    grid, front = _front(axes.coordinates(_profile(vertices, faces, left, left @ origin)),
                         0.01 * height)
    bulges, hollows = _peaks(front, 0.005 * height)
    levels = _profile_levels(grid, front, bulges, hollows, y_arc, y_eyes, height)
    levels["eye_top"] = float(max(coords[eye_left, 1].max(), coords[eye_right, 1].max()))
    levels["eye_bottom"] = float(min(coords[eye_left, 1].min(), coords[eye_right, 1].min()))
    midline = np.flatnonzero(np.abs(coords[:, 0]) < 0.02 * height)
    for name, level in (("upper_lip_top", "upper_lip_top"), ("upper_lip_bottom", "stomion"),
                        ("lower_lip_top", "stomion"), ("lower_lip_bottom", "lower_lip_bottom"),
                        ("nose_tip", "nose_tip"), ("subnasale", "subnasale"),
                        ("nose_bridge", "nasion"), ("chin", "chin")):
        y = levels[level]
        z = float(np.interp(y, grid, front))
        ids = midline
        if name in ("upper_lip_bottom", "lower_lip_top"):     # the side of the lip it is on
            upper = name == "upper_lip_bottom"
            ids = midline[(coords[midline, 1] >= y) == upper]
        marks[name] = _nearest_vertex(vertices, coords, np.array([0.0, y, z]),
                                      ids if len(ids) else None)
    notes.append("midline points: the bulges of the front of the symmetry-plane profile (nose "
                 "tip, the lips' vermilion borders, chin) and its hollows (nasion, subnasale, "
                 "the lips' contact, the labiomental fold)")
    ordered = {name: marks[name] for name in FOUND_POINTS}
    return MeshLandmarks(landmarks=ordered, axes=axes, levels=levels,
                         coordinates={n: coords[v] for n, v in ordered.items()},
                         mouth_line=_mouth_line(coords[mouth, :2]), mouth=mouth,
                         eyes=(eye_left, eye_right), found=True, notes=tuple(notes))


def mesh_axes_from_landmarks(mesh: Mesh, landmarks) -> MeshLandmarks:
    """The face frame of a mesh from landmarks given in a file.

    Needs the mouth corners and the four eye corners (or, failing the eye
    corners, the nose tip) to set the axes; the levels come from the
    landmarks present.

    Raises
    ------
    InputError
        The landmarks lack the mouth corners or both the eye corners and the nose tip.
    """
    need = ("mouth_corner_left", "mouth_corner_right")
    absent = [p for p in need if p not in landmarks]
    eyes = [f"eye_{w}_{s}" for w in ("inner", "outer") for s in ("left", "right")]
    if absent or not (all(e in landmarks for e in eyes) or "nose_tip" in landmarks):
        raise InputError("the mesh landmarks must name both mouth corners and the four eye "
                         "corners (or the nose tip) to place the face's axes")
    v = mesh.vertices
    mouth = (v[landmarks["mouth_corner_left"]] + v[landmarks["mouth_corner_right"]]) / 2
    left = v[landmarks["mouth_corner_left"]] - v[landmarks["mouth_corner_right"]]
    if all(e in landmarks for e in eyes):
        top = np.mean([v[landmarks[e]] for e in eyes], axis=0)
    else:
        top = v[landmarks["nose_tip"]]
    left /= np.linalg.norm(left)
    up = top - mouth
    up -= (up @ left) * left
    up /= np.linalg.norm(up)
    forward = np.cross(left, up)
    axes = FaceAxes(left=left, up=up, forward=forward, origin=mouth, symmetry_rms=0.0,
                    evidence=("mesh: the landmark file's mouth and eye corners",))
    levels = {}
    names = {"nose_tip": "nose_tip", "subnasale": "subnasale", "nasion": "nose_bridge",
             "chin": "chin", "upper_lip_top": "upper_lip_top",
             "lower_lip_bottom": "lower_lip_bottom"}
    for level, point in names.items():
        if point in landmarks:
            levels[level] = float(axes.coordinates(v[landmarks[point]])[1])
    return MeshLandmarks(landmarks=dict(landmarks), axes=axes, levels=levels,
                         coordinates={n: axes.coordinates(v[i]) for n, i in landmarks.items()},
                         found=False, notes=("given in a landmark file",))
