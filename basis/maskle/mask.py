"""The Maskle asset: a low-resolution mask mesh whose vertices carry painted weights.

A mask lives in its own *template frame*: x towards the subject's left, y up,
z forward (out of the face), centimetres of an average adult face. It holds

* polygons (triangles and quads) over the areas around the lips, eyes and brows,
  with a "tongue": two thin strips that leave the lip-contact line backwards
  (into the mouth) from the upper and from the lower lip band;
* the ten Maskle landmarks (:data:`mocap.anatomy.MASKLE_POINTS`) as vertex ids;
* named weight channels per vertex, each a ``"bone"`` (with an origin, used by
  the envelope baseline) or a ``"region"``.

File format: ``.npz`` with arrays ``vertices (V, 3)``, ``polygons (P, 4)``
(0-based, ``-1`` in the last column of a triangle), ``channel_names (K,)``,
``channel_kinds (K,)``, ``weights (V, K)`` in [0, 1], ``origins (K, 3)`` (NaN for
regions), ``landmark_names (10,)``, ``landmark_vertices (10,)``,
``tongue_root (T,)``, ``tongue_tip (T,)`` and ``format_version ()``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from mocap.anatomy import MASKLE_POINTS
from mocap.errors import FileFormatError, InputError
from mocap.util.arrays import read_only
from mocap.util.atomic import atomic_path
from mocap.util.npz import read_npz
from mocap.util.validation import as_float_array

__all__ = ["Mask", "CHANNEL_KINDS", "load_mask", "save_mask", "load_default_mask",
           "DEFAULT_MASK_PATH"]

#: What a weight channel is.
CHANNEL_KINDS = ("bone", "region")
#: The mask the project ships (written by ``python -m basis.maskle.build_default``).
DEFAULT_MASK_PATH = Path(__file__).resolve().parents[2] / "data" / "default_mask.npz"
_FORMAT_VERSION = 1
_ARRAYS = ("vertices", "polygons", "channel_names", "channel_kinds", "weights", "origins",
           "landmark_names", "landmark_vertices", "tongue_root", "tongue_tip",
           "format_version")


@dataclass(frozen=True, eq=False)
class Mask:
    """A painted low-resolution mask (template frame, cm of an average face).

    Attributes
    ----------
    vertices : ndarray of shape (V, 3)
    polygons : ndarray of int64, shape (P, 4)
        Quads; triangles have -1 as last corner.
    channel_names : tuple of str
        K weight channels (bones and regions).
    channel_kinds : tuple of str
        One of :data:`CHANNEL_KINDS` per channel.
    weights : ndarray of shape (V, K), in [0, 1]
    origins : ndarray of shape (K, 3)
        Bone positions in the template frame (NaN for regions).
    landmarks : dict of str to int
        The ten :data:`~mocap.anatomy.MASKLE_POINTS` as vertex ids.
    tongue_root, tongue_tip : ndarray of int64, shape (T,)
        Tongue edges: the initial tongue direction is ``mean(tip - root)``.

    Raises
    ------
    InputError
        Inconsistent shapes, ids out of range, weights outside [0, 1], an
        unknown channel kind, duplicate channel names, a missing landmark.
    """

    vertices: np.ndarray
    polygons: np.ndarray
    channel_names: tuple
    channel_kinds: tuple
    weights: np.ndarray
    origins: np.ndarray
    landmarks: dict
    tongue_root: np.ndarray
    tongue_tip: np.ndarray

    def __post_init__(self):
        v = as_float_array(self.vertices, "mask vertices", shape=(None, 3), allow_nan=False)
        n = len(v)
        poly = np.array(self.polygons, dtype=np.int64)
        if poly.ndim != 2 or poly.shape[1] != 4 or len(poly) == 0:
            raise InputError(f"mask polygons must have shape (P, 4), P > 0, got {poly.shape}")
        if np.any(poly[:, :3] < 0) or np.any(poly >= n) or np.any(poly[:, 3] < -1):
            raise InputError(f"mask polygons index vertices outside 0..{n - 1}")
        names, kinds = tuple(map(str, self.channel_names)), tuple(map(str, self.channel_kinds))
        if len(set(names)) != len(names) or len(kinds) != len(names) or not names:
            raise InputError("mask channel names must be unique, one kind per channel")
        bad = [k for k in kinds if k not in CHANNEL_KINDS]
        if bad:
            raise InputError(f"mask channel kind {bad[0]!r} unknown; expected one of "
                             f"{CHANNEL_KINDS}")
        w = as_float_array(self.weights, "mask weights", shape=(n, len(names)),
                           allow_nan=False)
        if np.any(w < 0) or np.any(w > 1):
            raise InputError("mask weights must lie in [0, 1]")
        origins = as_float_array(self.origins, "mask origins", shape=(len(names), 3))
        missing = [p for p in MASKLE_POINTS if p not in self.landmarks]
        if missing:
            raise InputError(f"mask lacks landmarks {', '.join(missing)}")
        marks = {p: int(self.landmarks[p]) for p in MASKLE_POINTS}
        if any(not 0 <= i < n for i in marks.values()):
            raise InputError(f"mask landmark vertex ids must lie in 0..{n - 1}")
        root = np.array(self.tongue_root, dtype=np.int64).ravel()
        tip = np.array(self.tongue_tip, dtype=np.int64).ravel()
        if len(root) == 0 or root.shape != tip.shape or np.any(np.r_[root, tip] < 0) \
                or np.any(np.r_[root, tip] >= n):
            raise InputError("mask tongue_root and tongue_tip must be equal-length, "
                             "non-empty vertex id lists")
        for name, arr in (("vertices", v), ("polygons", poly), ("weights", w),
                          ("origins", origins), ("tongue_root", root), ("tongue_tip", tip)):
            object.__setattr__(self, name, read_only(arr))
        object.__setattr__(self, "channel_names", names)
        object.__setattr__(self, "channel_kinds", kinds)
        object.__setattr__(self, "landmarks", marks)

    @property
    def n_vertices(self) -> int:
        """Number of mask vertices V."""
        return len(self.vertices)

    @property
    def triangles(self) -> np.ndarray:
        """Triangles (F, 3): each quad split along its 0-2 diagonal."""
        quads = self.polygons[self.polygons[:, 3] >= 0]
        tris = self.polygons[self.polygons[:, 3] < 0, :3]
        return np.concatenate([tris, quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])

    @property
    def triangle_polygon(self) -> np.ndarray:
        """The polygon each row of :attr:`triangles` comes from (F,)."""
        quad = np.flatnonzero(self.polygons[:, 3] >= 0)
        tri = np.flatnonzero(self.polygons[:, 3] < 0)
        return np.concatenate([tri, quad, quad])

    @property
    def tongue_direction(self) -> np.ndarray:
        """Unit initial tongue direction (3,) in the template frame (the paper's β)."""
        d = (self.vertices[self.tongue_tip] - self.vertices[self.tongue_root]).mean(axis=0)
        return d / np.linalg.norm(d)

    @property
    def sides(self) -> np.ndarray:
        """Polygon sides (S, 2): (a, b) per side of each polygon in corner order.

        A side two polygons share appears once per polygon (once in each
        direction when they are oriented alike).
        """
        poly = self.polygons
        ring = np.where(poly < 0, poly[:, :1], poly)      # a triangle closes on corner 0
        sides = np.stack([ring.ravel(), np.roll(ring, -1, axis=1).ravel()], axis=1)
        return sides[sides[:, 0] != sides[:, 1]]

    @property
    def lip_bands(self) -> tuple[np.ndarray, np.ndarray]:
        """The upper and lower lip bands, bool arrays (V,) each.

        The mouth patch is split along the lip-contact line: the band of each
        lip (with its tongue strip) is the connected piece of the mask holding
        ``upper_lip_bottom``, respectively ``lower_lip_top``.

        Raises
        ------
        InputError
            Both landmarks lie on one connected piece (an unsplit mouth).
        """
        a, b = self.sides.T
        graph = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(self.n_vertices,) * 2)
        piece = connected_components(graph, directed=False)[1]
        upper, lower = (piece[self.landmarks[p]] for p in ("upper_lip_bottom", "lower_lip_top"))
        if upper == lower:
            raise InputError("the mask's mouth is not split along the lip line: "
                             "upper_lip_bottom and lower_lip_top lie on one piece")
        return piece == upper, piece == lower

    @property
    def tongue_seam(self) -> np.ndarray:
        """Pairs (S, 2) of (upper, lower) tongue vertices that sit together across the lip line.

        The two tongue strips are one fold into the mouth, cut along its middle
        so that each lip keeps its own band: a seam pair is a tongue vertex
        (root or tip) of the upper band and one of the lower band that are each
        other's nearest tongue vertex of the other band, closer than a quarter
        of the mask's median edge length.
        """
        upper, lower = self.lip_bands
        tongue = np.zeros(self.n_vertices, bool)
        tongue[self.tongue_root] = tongue[self.tongue_tip] = True
        up, low = np.flatnonzero(upper & tongue), np.flatnonzero(lower & tongue)
        if len(up) == 0 or len(low) == 0:
            return np.zeros((0, 2), np.int64)
        d = np.linalg.norm(self.vertices[up, None] - self.vertices[None, low], axis=2)
        to_low, to_up = d.argmin(axis=1), d.argmin(axis=0)
        a, b = self.sides.T
        edge = np.linalg.norm(self.vertices[a] - self.vertices[b], axis=1)
        keep = (to_up[to_low] == np.arange(len(up))) \
            & (d[np.arange(len(up)), to_low] < 0.25 * np.median(edge[edge > 0]))
        return np.stack([up[keep], low[to_low[keep]]], axis=1)

    def channels(self, kind: str) -> list:
        """Names of the channels of one kind (``"bone"`` or ``"region"``)."""
        if kind not in CHANNEL_KINDS:
            raise InputError(f"kind must be one of {CHANNEL_KINDS}, got {kind!r}")
        return [n for n, k in zip(self.channel_names, self.channel_kinds) if k == kind]

    def with_weights(self, weights) -> "Mask":
        """The same mask with other vertex weights (V, K) in [0, 1]."""
        return replace(self, weights=weights)


def save_mask(mask: Mask, path) -> None:
    """Write a mask to an ``.npz`` file atomically (see the module docstring)."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(
                fh, vertices=mask.vertices, polygons=mask.polygons,
                channel_names=np.array(mask.channel_names),
                channel_kinds=np.array(mask.channel_kinds), weights=mask.weights,
                origins=mask.origins, landmark_names=np.array(list(mask.landmarks)),
                landmark_vertices=np.array(list(mask.landmarks.values()), dtype=np.int64),
                tongue_root=mask.tongue_root, tongue_tip=mask.tongue_tip,
                format_version=np.array(_FORMAT_VERSION))


def load_mask(path) -> Mask:
    """Read a mask written by :func:`save_mask`.

    Raises
    ------
    FileFormatError
        Unreadable file, missing arrays, another format version, or content
        that does not make a valid :class:`Mask`.
    """
    path = Path(path)
    data = read_npz(path, "mask file", required=_ARRAYS,
                    version=("format_version", _FORMAT_VERSION))
    try:
        return Mask(data["vertices"], data["polygons"], tuple(data["channel_names"].tolist()),
                    tuple(data["channel_kinds"].tolist()), data["weights"], data["origins"],
                    dict(zip(data["landmark_names"].tolist(),
                             data["landmark_vertices"].tolist())),
                    data["tongue_root"], data["tongue_tip"])
    except InputError as exc:
        raise FileFormatError(path, str(exc)) from None


def load_default_mask() -> Mask:
    """The mask shipped in ``data/default_mask.npz``."""
    return load_mask(DEFAULT_MASK_PATH)
