"""Fitting the Maskle to a face: landmark placement, then active-surface shrinking.

Placement: a similarity (Umeyama) maps the mask's ten landmark vertices onto
the face's; the landmarks' in-plane residuals (template x, y) are spread over
the mask by a linear RBF so that the tongue meets the lip-contact line, aimed
at the midpoint of the two lip-contact landmarks (the paper's manual fine
adjustment), and the mask is pushed forward (``standoff``)
until it touches nothing. Shrinking, per iteration t (paper eq. 1-3)::

    x_i(t+1) = x_i(t) + a (c_i - x_i(t)) + b s β

with c_i the mean of v_i's edge neighbours, β the unit initial tongue
direction and s the placement scale (b is in template cm per iteration).
The tongue is one fold cut along its middle (a strip per lip band): while
both vertices of a seam pair (:attr:`~basis.maskle.mask.Mask.tongue_seam`)
move, each takes the mean of the pair's neighbours, as if uncut; once either
is stopped, the other follows its own band onto its lip. (Cut from the start,
each band's lip row is pulled into its own band, away from the other one:
the rows parted by 1.3 mm on the demo face, and a lower-lip vertex by the
mouth corner, seeing neither band through the parting, read the upper
tongue strip behind it. Welded to the end, a band's row is held where the
other lip stopped it: on ICT's corners, upper-lip vertices facing down then
read the lower band.)
Vertices of every mask triangle that intersects the face mesh freeze, except
the tongue's: it slides between the lips, even closed ones, and its tips
freeze with their roots on the lip line. (Were the tongue stopped by the lips,
it would hold the whole lip row a tongue's depth in front of the mouth: on the
closed ICT lips it did, 1 cm in front, and the rays of the lips near the
contact line read the other lip's band.)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np
import scipy.sparse as sp
from scipy.interpolate import RBFInterpolator
from scipy.spatial import cKDTree

from basis.maskle._geometry import TriangleIndex, triangles_intersect
from basis.maskle.mask import Mask
from mocap.anatomy import MASKLE_POINTS
from mocap.errors import InputError
from mocap.mesh.landmarks import check_mesh_landmarks
from mocap.mesh.mesh import Mesh
from mocap.rigid import fit_rigid
from mocap.util.validation import as_int, as_positive_float

__all__ = ["MaskFit", "FIT_STATUSES", "fit_mask", "landmark_points", "neighbour_mean"]

#: How a shrinking run ended.
FIT_STATUSES = ("all_frozen", "iteration_limit")
#: Standoff increments (template cm) tried when the placed mask touches the face.
_STANDOFF_STEP, _STANDOFF_TRIES = 0.5, 12
#: The two lip-contact landmarks: the tongue is aimed at their midpoint, the
#: mask's own spacing kept, so that it enters the mouth between the lips.
_LIP_CONTACT = ("upper_lip_bottom", "lower_lip_top")
#: Face landmarks whose second singular value is below this fraction of the
#: first are collinear (or coincident): no placement.
_COLLINEAR_RTOL = 1e-6


@dataclass(frozen=True)
class MaskFit:
    """A mask fitted to a face.

    Attributes
    ----------
    vertices : ndarray of shape (V, 3), mesh units
        Mask vertices after shrinking.
    placed : ndarray of shape (V, 3), mesh units
        Mask vertices after placement, before shrinking.
    frozen : ndarray of bool, shape (V,)
        Vertices stopped by a collision.
    n_iterations : int
    status : str
        One of :data:`FIT_STATUSES`.
    message : str
    scale : float
        Mesh units per template cm.
    rotation : ndarray of shape (3, 3)
        Template frame to mesh (``mesh = scale * rotation @ template + translation``).
    translation : ndarray of shape (3,)
    standoff : float
        Distance the placed mask was pushed forward, template cm.
    """

    vertices: np.ndarray
    placed: np.ndarray
    frozen: np.ndarray
    n_iterations: int
    status: str
    message: str
    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    standoff: float

    @property
    def forward(self) -> np.ndarray:
        """Unit forward direction of the face (template +z) in mesh coordinates."""
        return self.rotation[:, 2].copy()

    def to_mesh(self, template_points) -> np.ndarray:
        """Map template-frame points (..., 3) to mesh coordinates (no warp, no standoff)."""
        return self.scale * np.asarray(template_points, float) @ self.rotation.T \
            + self.translation


def landmark_points(mesh: Mesh, landmarks: Mapping) -> np.ndarray:
    """Positions (10, 3) of the :data:`~mocap.anatomy.MASKLE_POINTS` on a mesh.

    Raises
    ------
    InputError
        A Maskle point is missing, an id is out of range, or the landmarks
        are degenerate (coincident or collinear).
    """
    marks = check_mesh_landmarks(landmarks, mesh.n_vertices, where="face landmarks")
    missing = [p for p in MASKLE_POINTS if p not in marks]
    if missing:
        raise InputError(f"face landmarks lack {', '.join(missing)}: the Maskle is placed "
                         f"with all ten of {', '.join(MASKLE_POINTS)}")
    return mesh.vertices[[marks[p] for p in MASKLE_POINTS]]


def neighbour_mean(mask: Mask, *, welded: bool = False) -> sp.csr_matrix:
    """Row-stochastic (V, V) matrix averaging each vertex's edge neighbours.

    ``welded``: both vertices of a :attr:`~basis.maskle.mask.Mask.tongue_seam`
    pair average the neighbours of the pair, as if the mask were not cut
    along the lip line.
    """
    a, b = mask.sides.T
    adj = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(mask.n_vertices,) * 2).tocsr()
    adj = ((adj + adj.T) > 0).astype(float)
    if welded:
        seam = mask.tongue_seam
        pair = sp.coo_matrix((np.ones(2 * len(seam)), (seam.ravel(), seam[:, ::-1].ravel())),
                             shape=adj.shape)
        adj = (sp.identity(mask.n_vertices) + pair) @ adj
    deg = np.asarray(adj.sum(axis=1)).ravel()
    return sp.diags(1.0 / np.maximum(deg, 1)) @ adj


def _place(mask: Mask, face_points: np.ndarray):
    """Similarity template -> mesh and the in-plane-warped template vertices."""
    src = mask.vertices[[mask.landmarks[p] for p in MASKLE_POINTS]]
    spread = np.linalg.svd(face_points - face_points.mean(axis=0), compute_uv=False)
    sim = fit_rigid(src[None], face_points[None], scale=True)
    if not bool(sim.valid[0]) or spread[1] <= _COLLINEAR_RTOL * spread[0]:
        raise InputError("face landmarks are collinear or coincident: cannot place the mask")
    s, rot, t = float(sim.scale[0]), sim.rotation[0], sim.translation[0]
    back = (face_points - t) @ rot / s               # face landmarks in the template frame
    pair = [MASKLE_POINTS.index(p) for p in _LIP_CONTACT]
    back[pair] = back[pair].mean(axis=0) + src[pair] - src[pair].mean(axis=0)
    resid = np.zeros_like(src)
    resid[:, :2] = back[:, :2] - src[:, :2]
    warp = RBFInterpolator(src[:, :2], resid, kernel="linear", degree=1)
    return s, rot, t, mask.vertices + warp(mask.vertices[:, :2])


class _Face:
    """The face mesh for collision tests: an R-tree and a nearest-vertex bound."""

    def __init__(self, mesh: Mesh):
        self.index = TriangleIndex(mesh.vertices[mesh.faces])
        self.vertices = cKDTree(mesh.vertices)
        tri = self.index.tri
        self.longest_edge = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max()

    def colliding(self, x: np.ndarray, tri: np.ndarray, which: np.ndarray) -> np.ndarray:
        """The triangles among `which` (ids into `tri`) that intersect the face.

        A triangle farther from every face vertex than its own radius plus the
        longest face edge cannot touch the face and is not tested.
        """
        corners = x[tri[which]]
        centre = corners.mean(axis=1)
        radius = np.linalg.norm(corners - centre[:, None], axis=2).max(axis=1)
        gap = self.vertices.query(centre)[0]
        near = gap <= radius + self.longest_edge
        which, corners = which[near], corners[near]
        q, f = self.index.pairs(corners.min(axis=1), corners.max(axis=1))
        return which[np.unique(q[triangles_intersect(corners[q], self.index.tri[f])])]




def fit_mask(mask: Mask, mesh: Mesh, landmarks: Mapping, *, a: float = 0.005,
             b: float = 0.05, max_iterations: int = 600, standoff: float = 1.0,
             max_travel: float = 6.0) -> MaskFit:
    """Place the mask in front of a face and shrink it onto the face.

    Parameters
    ----------
    mask : Mask
    mesh : Mesh
        The target face (any units, any topology).
    landmarks : mapping of str to int
        Vertex ids of at least the ten :data:`~mocap.anatomy.MASKLE_POINTS`.
    a, b : float
        Neighbour-mean pull (fraction per iteration) and tongue-direction step
        (template cm per iteration); paper: 0.005 and 0.05.
    max_iterations : int
    standoff : float
        Initial distance in front of the face, template cm (raised by 0.5 cm
        steps while the placed mask intersects the face).
    max_travel : float
        A vertex that has moved this far (template cm) without touching the
        face stops too (a tongue tip that went through the mouth opening,
        a vertex over an eye hole); they are counted in the message.

    Returns
    -------
    MaskFit

    Raises
    ------
    InputError
        Missing or degenerate landmarks, bad options, a mask that cannot be
        placed without touching the face.
    """
    a = as_positive_float(a, "a")
    b = as_positive_float(b, "b")
    max_iterations = as_int(max_iterations, "max_iterations", minimum=1)
    standoff = as_positive_float(standoff, "standoff")
    max_travel = as_positive_float(max_travel, "max_travel")
    s, rot, t, warped = _place(mask, landmark_points(mesh, landmarks))
    forward = rot[:, 2]
    base = s * warped @ rot.T + t
    tri = mask.triangles
    face = _Face(mesh)
    tip = np.zeros(mask.n_vertices, bool)
    tip[mask.tongue_tip] = True
    solid = ~tip[tri].any(axis=1)                  # the tongue's triangles never collide
    everything = np.flatnonzero(solid)
    for _ in range(_STANDOFF_TRIES):
        x = base + s * standoff * forward
        if len(face.colliding(x, tri, everything)) == 0:
            break
        standoff += _STANDOFF_STEP
    else:
        raise InputError(f"the mask still intersects the face {standoff:g} template cm in "
                         "front of it: check the landmarks")
    placed = x.copy()
    beta = rot @ (warped[mask.tongue_tip] - warped[mask.tongue_root]).mean(axis=0)
    push = b * s * beta / np.linalg.norm(beta)
    average = neighbour_mean(mask)
    seam = mask.tongue_seam
    seam_rows = seam.ravel()
    seam_average = neighbour_mean(mask, welded=True)[seam_rows]
    frozen = np.zeros(mask.n_vertices, dtype=bool)
    status, it, n_far = FIT_STATUSES[1], 0, 0
    for it in range(1, max_iterations + 1):
        moving = ~frozen
        pull = average @ x - x
        joint = np.repeat(~frozen[seam].any(axis=1), 2)
        pull[seam_rows[joint]] = seam_average[joint] @ x - x[seam_rows[joint]]
        x[moving] += a * pull[moving] + push
        active = np.flatnonzero(~frozen[tri].all(axis=1) & solid)
        frozen[tri[face.colliding(x, tri, active)].ravel()] = True
        frozen[mask.tongue_tip] = frozen[mask.tongue_root]
        far = ~frozen & (np.linalg.norm(x - placed, axis=1) >= max_travel * s)
        frozen |= far
        n_far += int(far.sum())
        if frozen.all():
            status = FIT_STATUSES[0]
            break
    message = (f"all {mask.n_vertices} mask vertices frozen after {it} iterations "
               f"({n_far} by the travel limit {max_travel:g} cm)"
               if status == FIT_STATUSES[0] else
               f"iteration limit {max_iterations} reached with {int((~frozen).sum())} of "
               f"{mask.n_vertices} mask vertices still moving")
    return MaskFit(x, placed, frozen, it, status, message, s, rot, t, standoff)
