"""Gold-standard bone weights from an artist's expression shapes (for tests and the bench).

The weight of a vertex for a bone is the length of its displacement in the
bone's expression shape(s), divided by the largest over the mesh (the largest
over several shapes when a bone has more than one): 1 where the bone moves the
skin most, 0 where it does not move it.

A lip bone means "this lip": the artist shapes do not respect that (ICT's
``mouthLowerDown_*`` also drags the inner upper lip and the cheeks above the
mouth, ``mouthUpperUp_*`` the top of the lower lip), so the lip bones are
restricted to their side of the mouth opening. The sides come from the
mesh's mouth boundary loop (the loop nearest the lip-contact landmarks), split
into an upper and a lower arc at its points farthest towards the mouth
corners. A vertex's score is how much nearer the upper arc is than the lower
along the mesh's edges (the lips and their inner surfaces: clearly one side),
plus its height above the line through the loop's corners (what decides
beside the corners, where both arcs are about as near); the side is a smooth
step of the score, 0 to 1 over :data:`SIDE_RAMP` mouth widths either side of
0 (the mouth's "up" is from the lower arc's mean to the upper's). The Maskle
itself never uses the loop; only this reference does.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from basis.artist import ArtistBasis
from mocap.errors import InputError
from mocap.mesh.landmarks import check_mesh_landmarks
from mocap.mesh.mesh import Mesh, boundary_loops

__all__ = ["GOLD_SHAPES", "DEMO_GOLD_SHAPES", "LIP_SIDES", "SIDE_RAMP", "gold_weights",
           "mouth_sides"]

#: The ICT-FaceKit (ARKit-named) expression shapes that define each bone of
#: the default rig (:data:`basis.maskle.build_default.BONES`).
GOLD_SHAPES = {
    "jaw": ("jawOpen",),
    "upper_lip_left": ("mouthUpperUp_L",),
    "upper_lip_right": ("mouthUpperUp_R",),
    "lower_lip_left": ("mouthLowerDown_L",),
    "lower_lip_right": ("mouthLowerDown_R",),
    "brow_left": ("browOuterUp_L", "browInnerUp_L"),
    "brow_right": ("browOuterUp_R", "browInnerUp_R"),
}
#: The demo face's muscles (:mod:`fit.demo.muscles`) that match bones of the
#: default rig. It has no muscle of one side of the lower lip (its lip
#: depressor is one central muscle, its corner depressors act below the
#: corners), so the lower-lip bones have no gold there.
DEMO_GOLD_SHAPES = {
    "jaw": ("jaw_open",),
    "upper_lip_left": ("levator_labii_superioris_L",),
    "upper_lip_right": ("levator_labii_superioris_R",),
    "brow_left": ("frontalis_inner_L", "frontalis_outer_L"),
    "brow_right": ("frontalis_inner_R", "frontalis_outer_R"),
}
#: The side of the mouth opening each lip bone is restricted to.
LIP_SIDES = {"upper_lip_left": "upper", "upper_lip_right": "upper",
             "lower_lip_left": "lower", "lower_lip_right": "lower"}
#: Half-width of the ramp between the sides, as a fraction of the mouth width.
SIDE_RAMP = 0.1
_MOUTH_MARKS = ("mouth_corner_left", "mouth_corner_right", "upper_lip_top", "upper_lip_bottom",
                "lower_lip_top", "lower_lip_bottom")


def mouth_sides(mesh: Mesh, landmarks) -> np.ndarray:
    """How much each vertex belongs to the upper side of the mouth opening.

    Parameters
    ----------
    mesh : Mesh
        A face with an open mouth boundary loop.
    landmarks : mapping of str to int
        Vertex ids of at least the mouth corners and the four lip points
        (``upper_lip_top`` ... ``lower_lip_bottom``) of :data:`mocap.anatomy.MASKLE_POINTS`.

    Returns
    -------
    ndarray of shape (N,), in [0, 1]
        1 on the upper side, 0 on the lower side (see the module docstring).

    Raises
    ------
    InputError
        A mouth landmark is missing, or the mesh has no boundary loop.
    """
    marks = check_mesh_landmarks(landmarks, mesh.n_vertices, where="face landmarks")
    missing = [p for p in _MOUTH_MARKS if p not in marks]
    if missing:
        raise InputError(f"face landmarks lack {', '.join(missing)}: the gold lip sides need "
                         f"{', '.join(_MOUTH_MARKS)}")
    loops = boundary_loops(mesh)
    if not loops:
        raise InputError("the face mesh has no boundary loop: no mouth opening to split the "
                         "lips at")
    v = mesh.vertices
    lips = v[[marks[p] for p in _MOUTH_MARKS]]
    loop = min(loops, key=lambda lp: np.linalg.norm(v[lp] - lips.mean(axis=0), axis=1).min())
    lr = v[loop] @ (v[marks["mouth_corner_left"]] - v[marks["mouth_corner_right"]])
    i_l, i_r = int(np.argmax(lr)), int(np.argmin(lr))
    lo, hi = sorted((i_l, i_r))
    arc_a, arc_b = loop[lo + 1:hi], np.r_[loop[hi + 1:], loop[:lo]]
    if len(arc_a) == 0 or len(arc_b) == 0:
        raise InputError("the mouth loop's corner points are neighbours: cannot split the lips")
    up = v[arc_a].mean(axis=0) - v[arc_b].mean(axis=0)
    if up @ (v[marks["upper_lip_top"]] - v[marks["lower_lip_bottom"]]) < 0:
        arc_a, arc_b, up = arc_b, arc_a, -up
    end_l, end_r = v[loop[i_l]], v[loop[i_r]]
    width = np.linalg.norm(end_l - end_r)
    along = (end_l - end_r) / width
    up -= (up @ along) * along
    height = (v - (end_l + end_r) / 2) @ up / np.linalg.norm(up)
    e = mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    length = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
    graph = sp.coo_matrix((length, (e[:, 0], e[:, 1])), shape=(mesh.n_vertices,) * 2).tocsr()
    graph = graph.maximum(graph.T)
    d_up = dijkstra(graph, indices=arc_a, min_only=True)
    d_low = dijkstra(graph, indices=arc_b, min_only=True)
    lead = np.nan_to_num(d_low - d_up, nan=0.0, posinf=0.0, neginf=0.0)
    return _step((lead + height) / (SIDE_RAMP * width))


def _step(x):
    """Smooth step from 0 (x <= -1) to 1 (x >= 1)."""
    s = np.clip(0.5 + np.asarray(x) / 2, 0.0, 1.0)
    return s * s * (3 - 2 * s)


def gold_weights(basis: ArtistBasis, landmarks, bones=tuple(GOLD_SHAPES), *,
                 shapes=GOLD_SHAPES, lip_sides: bool = True) -> np.ndarray:
    """Per-vertex gold weights (N, B) in [0, 1] of the named bones.

    Parameters
    ----------
    basis : ArtistBasis
        Holding every shape of ``shapes[bone]`` for the requested bones.
    landmarks : mapping of str to int
        Mouth landmarks of ``basis.neutral`` (see :func:`mouth_sides`).
    bones : sequence of str
        Keys of `shapes`.
    shapes : mapping of str to tuple of str
        The expression shapes of each bone: :data:`GOLD_SHAPES` (ICT-FaceKit)
        or :data:`DEMO_GOLD_SHAPES` (the demo face's muscles).
    lip_sides : bool
        Restrict the lip bones to their side of the mouth (:data:`LIP_SIDES`);
        False gives the raw displacement magnitudes (to show how they cross).

    Returns
    -------
    ndarray of shape (N, B)
    """
    unknown = [b for b in bones if b not in shapes]
    if unknown:
        raise InputError(f"no gold shapes for bone {', '.join(unknown)}; known: "
                         f"{', '.join(shapes)}")
    upper = mouth_sides(basis.neutral, landmarks) \
        if lip_sides and any(b in LIP_SIDES for b in bones) else None
    out = []
    for bone in bones:
        mags = [np.linalg.norm(basis.displacements[basis.index(s)], axis=1)
                for s in shapes[bone]]
        w = np.max([m / m.max() for m in mags], axis=0)
        if upper is not None and bone in LIP_SIDES:
            w = w * (upper if LIP_SIDES[bone] == "upper" else 1 - upper)
        out.append(w)
    return np.stack(out, axis=1)
