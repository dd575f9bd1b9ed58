"""Marker layouts: named markers placed on a face mesh, evaluated on many frames.

A marker sits on a vertex, or on a triangle at barycentric coordinates, and
optionally a distance off the skin along the (interpolated, area-weighted)
vertex normal. A layout file is TOML::

    name = "ict-layout"
    n_vertices = 9409           # optional, checked against the mesh
    units = "cm"                # optional, checked against the mesh
    offset = 0.2                # default distance off the skin, mesh units
    [markers]                   # in marker order
    head-1 = { vertex = 8254, offset = 0.3 }
    lip-upper-1 = { face = 1234, bary = [0.2, 0.3, 0.5] }

Face ids index :attr:`mocap.mesh.mesh.Mesh.faces` (the fan triangulation of the
file's polygons).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np
import scipy.sparse as sp

from mocap.errors import FileFormatError, InputError, MarkerError
from mocap.mesh.mesh import Mesh
from mocap.util.arrays import read_only
from mocap.util.atomic import atomic_path
from mocap.util.blas import on_one_blas_thread
from mocap.util.optional import compiled
from mocap.util.toml import read_toml
from mocap.util.validation import as_float_array

__all__ = ["MarkerLayout", "PlacementUnderWeights", "make_layout", "load_marker_layout",
           "save_marker_layout"]

_KEYS = {"name", "description", "n_vertices", "units", "offset", "markers"}
_MARKER_KEYS = {"vertex", "face", "bary", "offset"}
_BARY_TOL = 1e-6


#: Frames whose marker positions :class:`PlacementUnderWeights`
#: forms together: few enough that their vertex, edge and normal arrays stay in the
#: core's cache (on one thread, passes four times larger take three times longer), and
#: enough that pieces evaluated on two Python threads (the marker-centre fit) are not
#: held up by each other's NumPy calls, a dozen a pass, under the GIL.
_FRAMES_PER_PASS = 64


@dataclass(frozen=True, eq=False)
class MarkerLayout:
    """Named markers on a mesh topology; build once, evaluate on every frame.

    Attributes
    ----------
    labels : tuple of str
        Marker labels, M of them.
    vertex_ids : ndarray of shape (M, 3), int64
        The three vertices each marker interpolates (a vertex marker repeats its vertex).
    weights : ndarray of shape (M, 3), float64
        Barycentric weights (sum 1; ``(1, 0, 0)`` for a vertex marker).
    face_ids : ndarray of shape (M,), int64
        The triangle of each marker, -1 for a marker placed on a vertex.
    offsets : ndarray of shape (M,), float64
        Distance off the skin along the normal, mesh units.
    faces : ndarray of shape (F, 3), int64
        The mesh's triangles (for normals).
    n_vertices : int
    units : str or None
    name : str
    """

    labels: tuple
    vertex_ids: np.ndarray
    weights: np.ndarray
    face_ids: np.ndarray
    offsets: np.ndarray
    faces: np.ndarray
    n_vertices: int
    units: str | None = None
    name: str = ""
    _normal_op: tuple = field(init=False, repr=False)

    def __post_init__(self):
        m = len(self.labels)
        for attr, shape in (("vertex_ids", (m, 3)), ("weights", (m, 3)), ("face_ids", (m,)),
                            ("offsets", (m,))):
            if np.shape(getattr(self, attr)) != shape:
                raise InputError(f"layout {attr} must have shape {shape}, "
                                 f"got {np.shape(getattr(self, attr))}")
        if len(set(self.labels)) != m:
            dup = next(x for x in self.labels if self.labels.count(x) > 1)
            raise MarkerError(dup, "appears twice in the layout")
        for attr in ("vertex_ids", "weights", "face_ids", "offsets", "faces"):
            object.__setattr__(self, attr, read_only(np.array(getattr(self, attr))))
        object.__setattr__(self, "labels", tuple(self.labels))
        object.__setattr__(self, "_normal_op", self._build_normal_operator())

    def _build_normal_operator(self) -> tuple:
        """What evaluation needs, in ids local to the few vertices it reads.

        ``needed`` lists the vertices the markers and their normals depend on;
        ``local`` the marker corners among them; ``edges`` (2 Fs x K, sparse)
        forms the two edges from the first corner of each face around a
        marker corner, ``incidence`` (corners x Fs) sums those faces' normals
        at the corners, ``slot`` is each marker corner's row among the
        corners, ``faces`` (Fs x 3) are those faces in ids among ``needed``,
        and ``by_face`` (Fs x corners) is ``incidence`` transposed: each face's corners.
        """
        corners = np.unique(self.vertex_ids)
        sub_faces = self.faces[np.isin(self.faces, corners).any(axis=1)]
        needed = np.unique(np.concatenate([self.vertex_ids.ravel(), sub_faces.ravel()]))
        local_faces = np.searchsorted(needed, sub_faces)
        n_sub = len(sub_faces)
        rows = np.tile(np.arange(2 * n_sub), 2)
        cols = np.concatenate([local_faces[:, 1], local_faces[:, 2],
                               local_faces[:, 0], local_faces[:, 0]])
        edges = sp.csr_matrix((np.repeat([1.0, -1.0], 2 * n_sub), (rows, cols)),
                              shape=(2 * n_sub, len(needed)))
        rows, cols = np.nonzero(np.isin(sub_faces, corners))
        incidence = sp.csr_matrix((np.ones(len(rows)), (np.searchsorted(
            corners, sub_faces[rows, cols]), rows)), shape=(len(corners), n_sub))
        return (needed, np.searchsorted(needed, self.vertex_ids), edges, incidence,
                np.searchsorted(corners, self.vertex_ids), local_faces, incidence.T.tocsr())

    @property
    def n_markers(self) -> int:
        """Number of markers M."""
        return len(self.labels)

    def index(self, label: str) -> int:
        """Position of a marker in the layout."""
        try:
            return self.labels.index(label)
        except ValueError:
            raise MarkerError(label, f"not in layout {self.name!r}") from None

    def positions(self, vertices, *, offset: bool = True) -> np.ndarray:
        """Marker positions on one mesh or on many frames of it at once.

        Parameters
        ----------
        vertices : array_like of shape (..., N, 3)
            Vertex positions, mesh units.
        offset : bool
            Add each marker's offset along the normal (False: the skin point).

        Returns
        -------
        ndarray of shape (..., M, 3), mesh units
            NaN where a vertex the marker (or its normal) depends on is NaN.
        """
        try:
            vertices = np.asarray(vertices, dtype=np.float64)  # no copy: we gather a few rows
        except (TypeError, ValueError) as exc:
            raise InputError(f"vertices must be a numeric array: {exc}") from None
        if vertices.ndim < 2 or vertices.shape[-2:] != (self.n_vertices, 3):
            raise InputError(f"vertices must have shape (..., {self.n_vertices}, 3) for layout "
                             f"{self.name!r}, got {vertices.shape}")
        batch = vertices.shape[:-2]
        near = vertices[..., self._normal_op[0], :].reshape(-1, len(self._normal_op[0]), 3)
        if np.isinf(near).any():
            raise InputError("vertices contains infinite values")
        out = np.empty((len(near), self.n_markers, 3))
        for first in range(0, len(near), _FRAMES_PER_PASS):
            part = np.ascontiguousarray(near[first:first + _FRAMES_PER_PASS].transpose(2, 1, 0))
            self._place(part, offset=offset, out=out[first:first + part.shape[-1]])
        return out.reshape(batch + out.shape[1:])

    def positions_under_weights(self, neutral, displacements, weights) -> np.ndarray:
        """Marker positions on ``neutral + Σ_i w_i e_i`` for each row of `weights`.

        Parameters
        ----------
        neutral : array_like of shape (N, 3), mesh units
        displacements : array_like of shape (n, N, 3), mesh units
            The shapes e_i.
        weights : array_like of shape (T, n)

        Returns
        -------
        ndarray of shape (T, M, 3), mesh units
        """
        return self.under_weights(neutral, displacements)(weights)

    def under_weights(self, neutral, displacements) -> "PlacementUnderWeights":
        """:meth:`positions_under_weights` of `neutral` and `displacements` as a function of
        the weights, for many calls: the rows of the vertices the markers read are taken
        once (e.g. 0.9 MB: the 53 ICT shapes at the 722 vertices its 60 markers read).

        Raises
        ------
        InputError
            Shapes that do not match the layout's mesh; NaN in `neutral`.
        """
        needed = self._normal_op[0]
        neutral = as_float_array(neutral, "neutral", shape=(self.n_vertices, 3),
                                 allow_nan=False)
        displacements = np.asarray(displacements, dtype=np.float64)
        if displacements.ndim != 3 or displacements.shape[1:] != (self.n_vertices, 3):
            raise InputError(f"displacements must have shape (n, {self.n_vertices}, 3), got "
                             f"{displacements.shape}")
        shapes = displacements[:, needed].transpose(2, 1, 0).reshape(-1, len(displacements))
        return PlacementUnderWeights(self, np.column_stack([shapes, neutral[needed].T.ravel()]))

    def _place(self, near: np.ndarray, offset: bool = True, *, out: np.ndarray) -> None:
        """Marker positions from the needed vertices ``near``, (3, K, B), into `out`
        (B, M, 3), C-contiguous: compiled when numba is installed
        (:mod:`mocap.mesh._layout_kernel`, the same bits)."""
        kernel = _compiled_place()
        if kernel is not None:
            _, local, _, incidence, slot, faces, by_face = self._normal_op
            kernel(np.ascontiguousarray(near), faces, by_face.indptr, by_face.indices,
                   incidence.shape[0], slot, local, self.weights, self.offsets, offset, out)
            return
        local = self._normal_op[1]
        np.einsum("cmkb,mk->bmc", near[:, local], self.weights, out=out)
        has = self.offsets != 0
        if offset and has.any():
            along = self._normals(near)[:, has]                                # (3, M', B)
            out[:, has] += (self.offsets[has, None] * along).transpose(2, 1, 0)

    def _normals(self, near: np.ndarray) -> np.ndarray:
        """Unit normals at the markers (3, M, B) from the needed vertices ``near``, (3, K, B).

        Each marker's corner normals are the area-weighted sums of the face
        normals around them (edge cross products; edges and sums are sparse
        products, one per coordinate), interpolated by its barycentric weights.
        """
        _, _, edges, incidence, slot, _, _ = self._normal_op
        n_sub = incidence.shape[1]
        uv = [edges @ coordinate for coordinate in near]                        # 3 x (2 Fs, B)
        u, v = [e[:n_sub] for e in uv], [e[n_sub:] for e in uv]
        summed = np.empty((3, incidence.shape[0], near.shape[-1]))
        for c, (a, b) in enumerate(((1, 2), (2, 0), (0, 1))):
            cross = u[a] * v[b]
            cross -= u[b] * v[a]
            summed[c] = incidence @ cross
        summed /= _norm(summed)                                                 # (3, C, B)
        along = np.einsum("cmkb,mk->cmb", summed[:, slot], self.weights)
        along /= _norm(along)
        return along


@dataclass(frozen=True, eq=False)
class PlacementUnderWeights:
    """Marker positions of a layout on ``neutral + Σ_i w_i e_i`` as a function of the
    weights w (:meth:`MarkerLayout.under_weights`).

    Only the vertices the markers and their normals read are formed (no mesh is), by
    one product with the weights and a row of ones, frames ``_FRAMES_PER_PASS`` at a time
    (too small a product to split: on one BLAS thread): the neutral is the operator's
    last column, so that the product adds it (a pass over the vertices less).

    Attributes
    ----------
    layout : MarkerLayout
    operator : ndarray of shape (3 K, n + 1), mesh units
        The shapes at the K vertices the markers read, one column per shape, and those
        vertices of the neutral as the last column; rows coordinate-major.
    """

    layout: MarkerLayout
    operator: np.ndarray

    @property
    def n_shapes(self) -> int:
        """n, the shapes the weights weigh."""
        return self.operator.shape[1] - 1

    @on_one_blas_thread
    def __call__(self, weights) -> np.ndarray:
        """Marker positions (T, M, 3), mesh units, for `weights` (T, n)."""
        n = self.n_shapes
        weights = as_float_array(weights, "weights", shape=(None, n), copy=False)  # only read
        out = np.empty((len(weights), self.layout.n_markers, 3))
        # a pass's weights, as columns, over a row of ones (the neutral's), and its
        # vertices: both made again in the same memory at every pass, which stays in cache
        width = min(len(weights), _FRAMES_PER_PASS)
        augmented = np.empty((n + 1, width))
        augmented[n] = 1.0
        vertices = np.empty((len(self.operator), width))
        for first in range(0, len(weights), _FRAMES_PER_PASS):
            part = weights[first:first + _FRAMES_PER_PASS]
            columns = augmented[:, :len(part)]
            columns[:n] = part.T
            near = np.matmul(self.operator, columns, out=vertices[:, :len(part)])
            self.layout._place(near.reshape(3, -1, len(part)),                # (3, K, B)
                               out=out[first:first + len(part)])
        return out


@functools.cache
def _compiled_place():
    """:func:`mocap.mesh._layout_kernel.place_markers`, or None (NumPy places the markers):
    :func:`mocap.util.optional.compiled`."""
    return compiled("mocap.mesh._layout_kernel", "place_markers", what="marker placement",
                    fallback="NumPy places the markers, about half as fast")


def _norm(v: np.ndarray) -> np.ndarray:
    """Length of the (3, ...) vectors ``v``, with zero lengths as 1 (the vector stays 0)."""
    norm = np.sqrt(np.einsum("c...,c...->...", v, v))
    return np.where(norm > 0, norm, 1.0)


def make_layout(mesh: Mesh, markers: Mapping[str, Mapping], *, offset: float = 0.0,
                name: str = "") -> MarkerLayout:
    """Build a layout from marker specifications.

    Parameters
    ----------
    mesh : Mesh
    markers : mapping of str to mapping
        Label to ``{"vertex": v}`` or ``{"face": f, "bary": (b0, b1, b2)}``, each
        with an optional ``"offset"`` (mesh units) overriding `offset`.
    offset : float
        Default distance off the skin along the normal, mesh units.
    name : str

    Returns
    -------
    MarkerLayout

    Raises
    ------
    MarkerError
        A specification with unknown keys, both or neither of vertex and face,
        ids out of range, barycentric weights negative or not summing to 1.
    """
    n_markers = len(markers)
    ids = np.zeros((n_markers, 3), np.int64)
    weights = np.zeros((n_markers, 3))
    face_ids = np.full(n_markers, -1, np.int64)
    offsets = np.full(n_markers, float(offset))
    for i, (label, spec) in enumerate(markers.items()):
        if not isinstance(spec, Mapping) or set(spec) - _MARKER_KEYS:
            raise MarkerError(label, f"specification must be a table with keys among "
                                     f"{sorted(_MARKER_KEYS)}, got {spec!r}")
        if ("vertex" in spec) == ("face" in spec):
            raise MarkerError(label, "needs exactly one of 'vertex' or 'face' (with 'bary')")
        if "vertex" in spec:
            vertex = _index(label, spec["vertex"], mesh.n_vertices, "vertex")
            ids[i], weights[i] = vertex, (1.0, 0.0, 0.0)
            if "bary" in spec:
                raise MarkerError(label, "'bary' goes with 'face', not with 'vertex'")
        else:
            face_ids[i] = _index(label, spec["face"], mesh.n_faces, "face")
            ids[i] = mesh.faces[face_ids[i]]
            weights[i] = _bary(label, spec.get("bary"))
        if "offset" in spec:
            value = spec["offset"]
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not np.isfinite(value):
                raise MarkerError(label, f"offset must be a finite number, got {value!r}")
            offsets[i] = float(value)
    return MarkerLayout(tuple(markers), ids, weights, face_ids, offsets, mesh.faces,
                        mesh.n_vertices, units=mesh.units, name=name)


def _index(label, value, limit, what) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) \
            or not 0 <= value < limit:
        raise MarkerError(label, f"{what} must be an integer in 0..{limit - 1}, got {value!r}")
    return int(value)


def _bary(label, value) -> np.ndarray:
    try:
        bary = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        bary = np.zeros(0)
    if bary.shape != (3,) or not np.all(np.isfinite(bary)) or np.any(bary < -_BARY_TOL) \
            or abs(bary.sum() - 1) > _BARY_TOL:
        raise MarkerError(label, f"bary must be 3 non-negative weights summing to 1, "
                                 f"got {value!r}")
    return bary / bary.sum()


def load_marker_layout(path, mesh: Mesh) -> MarkerLayout:
    """Read a layout TOML file (see the module docstring) for `mesh`.

    Parameters
    ----------
    path : str or os.PathLike
    mesh : Mesh
        The mesh whose vertex and face ids the file uses.

    Returns
    -------
    MarkerLayout

    Raises
    ------
    FileFormatError
        Unreadable TOML, unknown keys, no markers, a vertex count or unit
        different from the mesh's, or a bad marker specification (named).
    """
    path = Path(path)
    doc = read_toml(path, "layout")
    unknown = set(doc) - _KEYS
    if unknown:
        raise FileFormatError(path, f"unknown keys {sorted(unknown)}; expected {sorted(_KEYS)}")
    if "n_vertices" in doc and doc["n_vertices"] != mesh.n_vertices:
        raise FileFormatError(path, f"written for a mesh of {doc['n_vertices']} vertices, but "
                                    f"the mesh has {mesh.n_vertices}")
    if "units" in doc and mesh.units is not None and doc["units"] != mesh.units:
        raise FileFormatError(path, f"offsets are in {doc['units']!r} but the mesh is in "
                                    f"{mesh.units!r}")
    markers = doc.get("markers")
    if not isinstance(markers, dict) or not markers:
        raise FileFormatError(path, "needs a non-empty [markers] table")
    offset = doc.get("offset", 0.0)
    if isinstance(offset, bool) or not isinstance(offset, (int, float)):
        raise FileFormatError(path, f"offset must be a number, got {offset!r}")
    try:
        return make_layout(mesh, markers, offset=offset, name=str(doc.get("name", path.stem)))
    except MarkerError as exc:
        raise FileFormatError(path, str(exc)) from None


def save_marker_layout(layout: MarkerLayout, path, *, description: str = "") -> None:
    """Write a layout to a TOML file atomically (readable by :func:`load_marker_layout`).

    Offsets equal to the most common one are written as the file's default.
    """
    values, counts = np.unique(layout.offsets, return_counts=True)
    default = float(values[np.argmax(counts)])
    lines = [f"name = {_quote(layout.name)}"]
    if description:
        lines += [f"description = {_quote(description)}"]
    lines += [f"n_vertices = {layout.n_vertices}"]
    if layout.units:
        lines += [f"units = {_quote(layout.units)}"]
    lines += [f"offset = {default!r}", "", "[markers]"]
    for i, label in enumerate(layout.labels):
        if layout.face_ids[i] < 0:
            spec = f"vertex = {layout.vertex_ids[i, 0]}"
        else:
            bary = ", ".join(f"{w:.8f}" for w in layout.weights[i])
            spec = f"face = {layout.face_ids[i]}, bary = [{bary}]"
        if layout.offsets[i] != default:
            spec += f", offset = {float(layout.offsets[i])!r}"
        lines.append(f"{_quote(label)} = {{ {spec} }}")
    with atomic_path(path) as tmp:
        Path(tmp).write_text("\n".join(lines) + "\n", encoding="utf-8")


def _quote(text: str) -> str:
    return '"' + str(text).replace("\\", "\\\\").replace('"', '\\"') + '"'
