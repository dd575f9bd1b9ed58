"""Geodesic distances on a triangle mesh by the heat method (libigl).

The heat method (Crane, Weischedel & Wardetzky 2013) solves a heat step and a
Poisson problem with matrices factorized once per mesh, so each source costs
two back-substitutions. Distances follow the surface: across a mouth opening
(upper and lower lip not connected) they go around the lip corners.
"""

from __future__ import annotations

import functools

import igl
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from mocap.errors import InputError
from mocap.mesh._geodesic_cache import FIELD_CACHE_BYTES, FieldCache, mesh_key
from mocap.mesh._geodesic_helpers import SOURCES_PER_CHUNK, solve_shared
from mocap.util.blas import worker_threads
from mocap.util.validation import as_float_array, as_int, as_positive_float

__all__ = ["HeatGeodesics", "MAX_HELPERS", "SHARED_FROM"]

#: Values of the fields (sources × vertices) from which :meth:`HeatGeodesics.from_vertices`
#: shares its sources with helper processes by default: a helper's start (a fresh
#: interpreter's imports, about 0.4 s of a core) and its own factorization of the mesh then
#: cost less than the sources it takes (the 180 fields of 60 markers' faces on a mesh of
#: about 33,000 vertices or more). The solves stream the mesh's factor from memory: two
#: processes on two cores share its bandwidth, so a helper takes less than half.
SHARED_FROM = 6_000_000
#: Most helper processes by default: each holds its own factorization of the mesh (about
#: 0.5 GB for 150,000 vertices), and they share the memory's bandwidth.
MAX_HELPERS = 3
#: The fields this process keeps for the next geodesics on the same mesh (the next take's).
FIELDS = FieldCache(FIELD_CACHE_BYTES)


def _as_triangles(faces, n_vertices: int) -> np.ndarray:
    try:
        arr = np.array(faces, copy=True)
    except (TypeError, ValueError) as exc:
        raise InputError(f"faces must be an integer array: {exc}") from None
    if arr.ndim != 2 or arr.shape[1] != 3 or len(arr) == 0:
        raise InputError(f"faces must have shape (n_faces, 3) (triangles; split quads "
                         f"first), got {arr.shape}")
    if not np.issubdtype(arr.dtype, np.integer):
        raise InputError(f"faces must hold integer vertex ids, got dtype {arr.dtype}")
    if arr.min() < 0 or arr.max() >= n_vertices:
        raise InputError(f"faces index vertices 0..{n_vertices - 1}, got ids "
                         f"{arr.min()}..{arr.max()}")
    return np.ascontiguousarray(arr, dtype=np.int64)


class HeatGeodesics:
    """Heat-method geodesic distances on one triangle mesh, factorized once (at its first
    solve).

    Parameters
    ----------
    vertices : array_like of shape (n_vertices, 3)
        Vertex positions, mesh units. No NaN.
    faces : array_like of int, shape (n_faces, 3)
        Triangles (split quads first). The mesh must be one connected surface.
    time_factor : float, keyword-only
        Heat time ``t = time_factor * h**2`` with ``h`` the mean edge length;
        1 is libigl's default (smaller: sharper but noisier).
    intrinsic_delaunay : bool, keyword-only
        Use the intrinsic Delaunay Laplacian (more robust on poor triangles).

    Raises
    ------
    InputError
        Bad shapes, face ids out of range, or a mesh in several pieces.

    Notes
    -----
    Accuracy is that of the heat method, typically a few percent of the
    distance on a regular mesh (more near the source). Meshes with boundaries
    use libigl's average of Neumann and Dirichlet heat solutions.

    Examples
    --------
    >>> import numpy as np
    >>> v = np.array([[0., 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    >>> f = np.array([[0, 1, 2], [0, 2, 3]])
    >>> HeatGeodesics(v, f).from_vertices([0]).shape
    (1, 4)
    """

    def __init__(self, vertices, faces, *, time_factor: float = 1.0,
                 intrinsic_delaunay: bool = False):
        vertices = as_float_array(vertices, "vertices", shape=(None, 3), allow_nan=False)
        faces = _as_triangles(faces, len(vertices))
        time_factor = as_positive_float(time_factor, "time_factor")
        edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        adjacency = sp.coo_array((np.ones(len(edges)), (edges[:, 0], edges[:, 1])),
                                 shape=(len(vertices), len(vertices)))
        n_parts, _ = connected_components(adjacency, directed=False)
        if n_parts != 1:
            raise InputError(f"mesh has {n_parts} connected pieces (counting unused "
                             "vertices): geodesic distances need one connected surface")
        h = float(np.mean(np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]],
                                         axis=1)))
        self.vertices = vertices
        self.faces = faces
        self._heat_time = time_factor * h * h
        self._options = (time_factor, bool(intrinsic_delaunay))

    @functools.cached_property
    def _factorized(self) -> igl.HeatGeodesicsData:
        """libigl's factorizations of the mesh, made at the first solve (so that helper
        processes started for the solves factorize beside this one)."""
        data = igl.HeatGeodesicsData()
        data.use_intrinsic_delaunay = self._options[1]
        igl.heat_geodesics_precompute(self.vertices, self.faces, self._heat_time, data)
        return data

    @functools.cached_property
    def _key(self) -> bytes:
        """What its fields depend on (:func:`mocap.mesh._geodesic_cache.mesh_key`)."""
        return mesh_key(self.vertices, self.faces, self._options)

    @property
    def n_vertices(self) -> int:
        """Number of mesh vertices."""
        return len(self.vertices)

    def from_vertices(self, sources, *, processes: int | None = None) -> np.ndarray:
        """Distance fields from each source vertex.

        Parameters
        ----------
        sources : array_like of int, shape (n_sources,)
            Vertex ids.
        processes : int, optional
            Helper processes that solve a share of the sources (libigl's solve holds the
            GIL: threads of this process cannot share it); each factorizes the mesh once
            more. Default: one per spare core of this process's share
            (:func:`mocap.util.blas.worker_threads` less one), at most
            :data:`MAX_HELPERS`, when the fields hold at least :data:`SHARED_FROM` values,
            else none. The fields are the same, bit for bit, however many there are.

        Returns
        -------
        ndarray of shape (n_sources, n_vertices)
            Row ``i``: geodesic distance from ``sources[i]`` to every vertex,
            mesh units (0 at the source).

        Notes
        -----
        The fields solved are kept for the next call on the same mesh, by this object or
        another (:data:`FIELDS`: a session's next take), which solves only the sources it
        does not find there.
        """
        sources = np.asarray(sources)
        if sources.ndim != 1 or not np.issubdtype(sources.dtype, np.integer):
            raise InputError(f"sources must be a 1-D array of vertex ids, got "
                             f"shape {sources.shape} dtype {sources.dtype}")
        if len(sources) and (sources.min() < 0 or sources.max() >= self.n_vertices):
            raise InputError(f"sources must be vertex ids in 0..{self.n_vertices - 1}")
        if processes is not None:
            processes = as_int(processes, "processes", minimum=0)
        unique, inverse = np.unique(sources.astype(np.int64), return_inverse=True)
        kept = FIELDS.take(self._key, unique)
        missing = np.array([v for v in unique.tolist() if v not in kept], dtype=np.int64)
        solved = self._solve_all(missing, processes)
        FIELDS.keep(self._key, missing, solved)
        fields = solved
        if kept:                        # the unique sources' fields, kept or solved, in order
            fields = np.empty((len(unique), self.n_vertices))
            solved_rows = dict(zip(missing.tolist(), solved))
            for row, vertex in enumerate(unique.tolist()):
                fields[row] = kept[vertex] if vertex in kept else solved_rows[vertex]
        return fields if np.array_equal(unique, sources) else fields[inverse.reshape(-1)]

    def _solve_all(self, sources: np.ndarray, processes: int | None) -> np.ndarray:
        """The fields of the vertices `sources` (S,) int64, (S, n_vertices), solved here and
        by `processes` helper processes (see :meth:`from_vertices`)."""
        if processes is None:
            processes = min(worker_threads() - 1, MAX_HELPERS) \
                if sources.size * self.n_vertices >= SHARED_FROM else 0
        processes = min(processes, -(-len(sources) // SOURCES_PER_CHUNK) - 1)
        if processes <= 0:
            return self._solve(sources)
        out = np.empty((len(sources), self.n_vertices))
        solve_shared(self._solve, (self.vertices, self.faces, *self._options), sources, out,
                     processes)
        return out

    def _solve(self, sources: np.ndarray) -> np.ndarray:
        """The fields of the vertices `sources` (S,) int64 here, (S, n_vertices)."""
        out = np.empty((len(sources), self.n_vertices))
        for row, vertex in enumerate(sources):
            out[row] = igl.heat_geodesics_solve(self._factorized, np.array([vertex]))
        return out

    def from_surface_points(self, face_ids, bary, *, symmetric: bool = False) -> np.ndarray:
        """Distance fields from points on the surface (face id + barycentric).

        The field of a point is the barycentric blend of the fields of its
        face's three vertices, exact at the vertices and second-order accurate
        in the edge length away from the point.

        Parameters
        ----------
        face_ids : array_like of int, shape (n_points,)
            Triangle of each point.
        bary : array_like of shape (n_points, 3)
            Barycentric coordinates in that triangle (non-negative, sum 1).
        symmetric : bool, keyword-only
            Make the fields consistent with :meth:`between_surface_points`:
            the heat method is not exactly symmetric (field ``i`` at point
            ``j`` differs from field ``j`` at point ``i`` by a few percent),
            so each field is corrected, on the corners of the points' faces
            only (least-norm correction), to equal the symmetrized distance
            at every point and 0 at its own point.

        Returns
        -------
        ndarray of shape (n_points, n_vertices)
            Geodesic distance from each point to every vertex, mesh units.
        """
        face_ids, bary = self._as_surface_points(face_ids, bary)
        corners = self.faces[face_ids]
        unique, inverse = np.unique(corners, return_inverse=True)
        inverse = inverse.reshape(corners.shape)
        fields = np.einsum("pk,pkn->pn", bary, self.from_vertices(unique)[inverse])
        if symmetric:
            raw = self.at_surface_points(fields, face_ids, bary)
            target = 0.5 * (raw + raw.T)
            np.fill_diagonal(target, 0.0)
            # blend (P, U): field values on the corner vertices -> values at the points.
            blend = np.zeros((len(face_ids), len(unique)))
            np.add.at(blend, (np.repeat(np.arange(len(face_ids)), 3), inverse.ravel()),
                      bary.ravel())
            correction = np.linalg.lstsq(blend, (target - raw).T, rcond=None)[0]
            fields[:, unique] += correction.T
        return fields

    def between_surface_points(self, face_ids, bary) -> np.ndarray:
        """Symmetric (n_points, n_points) geodesic distances between surface points.

        ``(D + D.T) / 2`` with a zero diagonal, where ``D[i, j]`` is the field
        of point ``i`` (:meth:`from_surface_points`) blended at point ``j``.
        """
        face_ids, bary = self._as_surface_points(face_ids, bary)
        fields = self.from_surface_points(face_ids, bary, symmetric=True)
        return self.at_surface_points(fields, face_ids, bary)

    def at_surface_points(self, fields, face_ids, bary) -> np.ndarray:
        """Values (n_fields, n_points) of per-vertex fields (n_fields, n_vertices) at surface
        points."""
        face_ids, bary = self._as_surface_points(face_ids, bary)
        fields = as_float_array(fields, "fields", shape=(None, self.n_vertices))
        return np.einsum("jk,ijk->ij", bary, fields[:, self.faces[face_ids]])

    def _as_surface_points(self, face_ids, bary):
        face_ids = np.asarray(face_ids)
        if face_ids.ndim != 1 or not np.issubdtype(face_ids.dtype, np.integer):
            raise InputError(f"face_ids must be a 1-D array of face ids, got shape "
                             f"{face_ids.shape} dtype {face_ids.dtype}")
        if len(face_ids) and (face_ids.min() < 0 or face_ids.max() >= len(self.faces)):
            raise InputError(f"face_ids must be in 0..{len(self.faces) - 1}")
        bary = as_float_array(bary, "bary", shape=(len(face_ids), 3), allow_nan=False)
        bad = np.flatnonzero((bary < -1e-9).any(axis=1)
                             | (np.abs(bary.sum(axis=1) - 1.0) > 1e-6))
        if len(bad):
            raise InputError(f"bary of point {bad[0]} is {bary[bad[0]].tolist()}: "
                             "expected non-negative weights summing to 1")
        return face_ids.astype(np.int64), bary

    def locate(self, points) -> tuple[np.ndarray, np.ndarray]:
        """Closest surface point of each point, as (face_ids (P,), bary (P, 3)).

        Parameters
        ----------
        points : array_like of shape (n_points, 3)
            Positions, mesh units. No NaN.
        """
        points = as_float_array(points, "points", shape=(None, 3), allow_nan=False)
        _, face_ids, closest = igl.point_mesh_squared_distance(points, self.vertices,
                                                               self.faces)
        face_ids = np.asarray(face_ids, dtype=np.int64)
        tri = self.vertices[self.faces[face_ids]]
        bary = igl.barycentric_coordinates(closest, np.ascontiguousarray(tri[:, 0]),
                                           np.ascontiguousarray(tri[:, 1]),
                                           np.ascontiguousarray(tri[:, 2]))
        bary = np.clip(np.asarray(bary, dtype=np.float64), 0.0, None)
        return face_ids, bary / bary.sum(axis=1, keepdims=True)
