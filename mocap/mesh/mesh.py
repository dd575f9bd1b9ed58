"""Face meshes: vertices in the mesh's own units, triangulated polygon faces.

A :class:`Mesh` keeps the vertex order of its file and triangulates each
polygon as a fan from its first corner, ``(a, b, c, d) -> (a, b, c), (a, c, d)``,
polygon after polygon, so that every mesh of one topology (a neutral and its
expression shapes) gets the same triangles in the same order.
"""

from __future__ import annotations

import functools
import io
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from mocap.errors import FileFormatError, InputError
from mocap.units import mm_per_unit
from mocap.util.arrays import read_only
from mocap.util.atomic import atomic_path
from mocap.util.files import open_input, read_input_bytes
from mocap.util.optional import compiled, compiled_if_worth
from mocap.util.validation import as_float_array

__all__ = ["Mesh", "MESH_FORMATS", "load_mesh", "load_shape_vertices", "save_obj",
           "vertex_normals", "face_normals", "boundary_loops", "degenerate_faces", "mesh_edges"]

#: File extensions :func:`load_mesh` reads.
MESH_FORMATS = (".obj", ".ply", ".gltf", ".glb")

#: A triangle is degenerate when its doubled area is below this fraction of the
#: squared bounding-box diagonal.
_DEGENERATE_REL_AREA = 1e-12
#: Largest vertex coordinate magnitude (areas and normals stay far from overflow).
_MAX_COORDINATE = 1e15
#: Bytes of shape OBJs (estimated as the neutral's size a shape) for which loading numba
#: (about half a second, once a process) pays for itself in :func:`load_shape_vertices`
#: (about 18 ns saved a byte of vertex lines, about half an OBJ's bytes); a process that
#: has loaded it (``mocap2mesh run``) parses any shapes compiled.
_OBJ_BYTES_WORTH_COMPILING = 56 << 20


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangulated surface mesh.

    Attributes
    ----------
    vertices : ndarray of shape (N, 3), float64
        Vertex positions in the mesh's own units (read-only).
    faces : ndarray of shape (F, 3), int64
        Triangles as 0-based vertex ids (read-only).
    face_polygon : ndarray of shape (F,), int64
        The polygon of the file each triangle comes from (``arange(F)`` by default).
    polygon_sizes : ndarray of shape (P,), int64
        Number of corners of each polygon of the file (all 3 by default).
    units : str or None
        Length unit of the vertices (``"cm"`` for the ICT face), None if unknown.
    path : str or None
        The file read, None for a mesh made in memory.

    Raises
    ------
    InputError
        Non-finite vertices or beyond ±1e15, faces out of range, no vertices or
        no faces, a face-to-polygon map inconsistent with the polygon sizes, an
        unknown unit.
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_polygon: np.ndarray | None = None
    polygon_sizes: np.ndarray | None = None
    units: str | None = None
    path: str | None = None

    def __post_init__(self):
        where = self.path or "mesh"
        vertices = as_float_array(self.vertices, "vertices", shape=(None, 3))
        try:
            faces = np.array(self.faces, dtype=np.int64, copy=True)
        except (TypeError, ValueError):
            raise InputError(f"{where}: faces must be an integer array") from None
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise InputError(f"{where}: faces must have shape (F, 3), got {faces.shape}")
        if self.face_polygon is None:
            face_polygon = np.arange(len(faces), dtype=np.int64)
            sizes = np.full(len(faces), 3, dtype=np.int64)
        else:
            face_polygon = np.array(self.face_polygon, dtype=np.int64)
            sizes = np.array(self.polygon_sizes, dtype=np.int64)
            counts = np.bincount(face_polygon, minlength=len(sizes)) if len(faces) else sizes * 0
            if face_polygon.shape != (len(faces),) or len(counts) != len(sizes) \
                    or np.any(counts != sizes - 2):
                raise InputError(f"{where}: face_polygon does not match polygon_sizes "
                                 "(a polygon of k corners gives k - 2 triangles)")
        message = _topology_problem(vertices, faces)
        if message:
            raise InputError(f"{where}: {message}")
        if self.units is not None:
            mm_per_unit(self.units, where=f"{where}: units")
        for name, arr in (("vertices", vertices), ("faces", faces),
                          ("face_polygon", face_polygon), ("polygon_sizes", sizes)):
            object.__setattr__(self, name, read_only(arr))

    @property
    def n_vertices(self) -> int:
        """Number of vertices N."""
        return len(self.vertices)

    @property
    def n_faces(self) -> int:
        """Number of triangles F."""
        return len(self.faces)

    @property
    def polygon_corners(self) -> np.ndarray:
        """Flat 0-based corner ids of the file's polygons, polygon after polygon."""
        first = np.ones(len(self.faces), dtype=bool)
        first[1:] = self.face_polygon[1:] != self.face_polygon[:-1]
        keep = np.ones(self.faces.shape, dtype=bool)
        keep[~first, :2] = False  # later fan triangles add only their last corner
        return self.faces[keep]

    def with_vertices(self, vertices) -> "Mesh":
        """The same topology with other vertex positions (N, 3), same units."""
        vertices = as_float_array(vertices, "vertices", shape=(self.n_vertices, 3),
                                  allow_nan=False)
        return Mesh(vertices, self.faces, self.face_polygon, self.polygon_sizes,
                    units=self.units)

    def same_topology(self, other: "Mesh") -> bool:
        """True when `other` has the same vertex count and the same triangles."""
        return (self.n_vertices == other.n_vertices and self.faces.shape == other.faces.shape
                and bool(np.array_equal(self.faces, other.faces)))


def _topology_problem(vertices: np.ndarray, faces: np.ndarray) -> str:
    """What is wrong with a vertex/face pair, or an empty string."""
    if len(vertices) == 0:
        return "empty mesh: no vertices"
    if len(faces) == 0:
        return "empty mesh: no faces"
    # whole-array tests first: the rows are looked for only when one fails
    if not np.isfinite(vertices).all():
        bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
        return (f"{len(bad)} vertices have NaN or infinite coordinates "
                f"(first: vertex {bad[0]})")
    if np.abs(vertices).max() > _MAX_COORDINATE:
        bad = np.flatnonzero((np.abs(vertices) > _MAX_COORDINATE).any(axis=1))
        return (f"{len(bad)} vertices have coordinates beyond ±{_MAX_COORDINATE:.0e} "
                f"(first: vertex {bad[0]}, {vertices[bad[0]].tolist()}), in any unit no face")
    if faces.min() < 0 or faces.max() >= len(vertices):
        out = np.flatnonzero(((faces < 0) | (faces >= len(vertices))).any(axis=1))
        return (f"face {out[0]} indexes vertex {faces[out[0]].tolist()}, out of range "
                f"for {len(vertices)} vertices ({len(out)} such faces)")
    return ""


def degenerate_faces(vertices, faces) -> np.ndarray:
    """Ids of zero-area triangles.

    A triangle is degenerate when twice its area is at most 1e-12 times the
    squared diagonal of the vertices' bounding box (repeated corners included).

    Parameters
    ----------
    vertices : array_like of shape (N, 3)
    faces : array_like of shape (F, 3), int

    Returns
    -------
    ndarray of int64, sorted face ids
    """
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    coordinates, cross = _face_cross_rows(vertices, np.asarray(faces, np.int64).reshape(-1, 3))
    doubled = np.sqrt(sum(c * c for c in cross))
    diag2 = float(sum(np.ptp(c) ** 2 for c in coordinates)) if len(vertices) else 0.0
    return np.flatnonzero(doubled <= _DEGENERATE_REL_AREA * diag2)


def _warn_degenerate(vertices, faces, where) -> None:
    bad = degenerate_faces(vertices, faces)
    if len(bad):
        warnings.warn(f"{where}: {len(bad)} degenerate (zero-area) triangles, first "
                      f"{bad[:5].tolist()}; kept, but marker binding never projects onto them",
                      stacklevel=3)


def _fan(corners: np.ndarray, sizes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fan-triangulate polygons: faces (F, 3) and the polygon of each face."""
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    face_polygon = np.repeat(np.arange(len(sizes)), sizes - 2)
    k = np.arange(len(face_polygon)) - np.repeat(np.cumsum(sizes - 2) - (sizes - 2), sizes - 2)
    base = starts[face_polygon]
    faces = np.stack([corners[base], corners[base + k + 1], corners[base + k + 2]], axis=1)
    return faces, face_polygon


def _read_obj(path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (N, 3), flat 0-based polygon corners, polygon sizes of an OBJ file.

    Only ``v`` and ``f`` lines are read; ``f v/vt/vn`` and negative (relative)
    indices are understood. Plain files (``v x y z``, ``f a b c ...`` with single
    spaces, positive indices) are parsed in one C call per block; anything else
    goes through a line-by-line parser that names the faulty line.
    """
    data = _obj_text(path)
    vertices = _fast_block(_block(data, b"v"), np.float64)
    faces = _fast_block(_block(data, b"f"), np.int64)
    if vertices is not None and faces is not None and np.all(vertices[1] == 3) \
            and np.all(faces[1] >= 3) and np.all(faces[0] >= 1):
        vertices = vertices[0].reshape(-1, 3)
        if np.all(faces[0] <= len(vertices)):
            return vertices, faces[0] - 1, faces[1]
    return _read_obj_lines(path, data.splitlines())


def _obj_text(path) -> bytes:
    """The bytes of an OBJ file, line ends as ``\\n``."""
    data = read_input_bytes(path, "mesh")
    # a search for "\r" (memchr) costs a tenth of a replace that finds nothing to replace
    return data.replace(b"\r\n", b"\n") if b"\r" in data else data


def _line_starts(data: bytes) -> np.ndarray:
    """Offsets of the lines of `data` (``\\n`` line ends) that hold a keyword and a byte."""
    chars = np.frombuffer(data, dtype=np.uint8)
    starts = np.concatenate([[0], np.flatnonzero(chars[:-1] == 10) + 1])
    return starts[starts < len(data) - 1]


def _key_rows(data: bytes, starts: np.ndarray, key: bytes) -> np.ndarray | None:
    """Indices into `starts` of the lines ``key`` + space; None when a line has ``key`` +
    tab (left to the careful parser)."""
    chars = np.frombuffer(data, dtype=np.uint8)
    ours = chars[starts] == key[0]
    if np.any(ours & (chars[starts + 1] == 9)):
        return None
    return np.flatnonzero(ours & (chars[starts + 1] == 32))


def _run_end(data: bytes, starts: np.ndarray, rows: np.ndarray) -> int:
    """Where the line after the last of `rows` starts (the end of `data` after the last)."""
    return int(starts[rows[-1] + 1]) if rows[-1] + 1 < len(starts) else len(data)


def _span(data: bytes, starts: np.ndarray, key: bytes) -> tuple[bytes | None, bool]:
    """The text of an OBJ from its first ``key`` line to the end of its last, as it is in the
    file (keywords, line ends and any lines between kept; b"" when there is none), and
    whether the ``key`` lines are all its lines; (None, False) when a line has ``key`` + tab."""
    rows = _key_rows(data, starts, key)
    if rows is None:
        return None, False
    if len(rows) == 0:
        return b"", True
    return (data[starts[rows[0]]:_run_end(data, starts, rows)],
            bool(rows[-1] - rows[0] + 1 == len(rows)))


def _block(data: bytes, key: bytes) -> bytes | None:
    """The ``key`` lines of an OBJ without their keyword, newline separated.

    None when a line starts with ``key`` and a tab (left to the careful parser).
    """
    starts = _line_starts(data)
    rows = _key_rows(data, starts, key)
    if rows is None:
        return None
    if len(rows) == 0:
        return b""
    if rows[-1] - rows[0] + 1 == len(rows):  # one contiguous run: slice it out
        run = data[starts[rows[0]] + 2:_run_end(data, starts, rows)]
        return run.rstrip(b"\n").replace(b"\n" + key + b" ", b"\n")
    lines = data.splitlines()
    return b"\n".join(lines[i][2:] for i in rows)


def _fast_block(text: bytes | None, dtype):
    """All numbers of single-space separated rows and the count per row, or None."""
    if text is None:
        return None
    if not text:
        return np.zeros(0, dtype), np.zeros(0, np.int64)
    if b"  " in text or b"\t" in text or b"/" in text or b" \n" in text \
            or text.endswith(b" "):
        return None
    chars = np.frombuffer(text, dtype=np.uint8)
    ends = np.concatenate([np.flatnonzero(chars == 10), [len(chars)]])
    counts = np.diff(np.searchsorted(np.flatnonzero(chars == 32), ends), prepend=0) + 1
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            values = np.fromstring(text.decode("ascii"), dtype=dtype, sep=" ")
    except (ValueError, UnicodeDecodeError):
        return None
    return (values, counts) if len(values) == counts.sum() else None


def _read_obj_lines(path, lines: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The careful OBJ parser: errors name their line."""
    kind = np.array([line[:2] for line in lines] or [b""])
    v_idx = np.flatnonzero((kind == b"v ") | (kind == b"v\t"))
    f_idx = np.flatnonzero((kind == b"f ") | (kind == b"f\t"))
    vertices = _slow_vertices(path, [lines[i][2:] for i in v_idx], v_idx)
    raw, sizes = _slow_faces(path, [lines[i][2:] for i in f_idx], f_idx)
    if np.any(sizes < 3):
        row = int(np.argmax(sizes < 3))
        raise FileFormatError(path, f"face has {sizes[row]} corners; a polygon needs 3 or more",
                              line=int(f_idx[row]) + 1)
    polygon = np.repeat(np.arange(len(f_idx)), sizes)
    defined_before = np.searchsorted(v_idx, f_idx)[polygon]  # for negative indices
    corners = np.where(raw < 0, defined_before + raw, raw - 1)
    bad = np.flatnonzero((raw == 0) | (corners < 0) | (corners >= len(vertices)))
    if len(bad):
        raise FileFormatError(path, f"face indexes vertex {raw[bad[0]]}, out of range for "
                                    f"{len(vertices)} vertices (OBJ indices are 1-based)",
                              line=int(f_idx[polygon[bad[0]]]) + 1)
    return vertices, corners, sizes


def _slow_vertices(path, v_lines, v_idx) -> np.ndarray:
    rows = [line.split() for line in v_lines]
    short = [n for n, r in enumerate(rows) if len(r) < 3]
    if short:
        raise FileFormatError(path, "vertex line needs 3 coordinates",
                              line=int(v_idx[short[0]]) + 1)
    try:
        return np.array([r[:3] for r in rows], dtype=np.float64).reshape(-1, 3)
    except ValueError:
        row = next(n for n, r in enumerate(rows) if not _all_numbers(r[:3], float))
        raise FileFormatError(path, "vertex coordinates are not numbers",
                              line=int(v_idx[row]) + 1) from None


def _slow_faces(path, f_lines, f_idx) -> tuple[np.ndarray, np.ndarray]:
    rows = [[tok.split(b"/", 1)[0] for tok in line.split()] for line in f_lines]
    sizes = np.array([len(r) for r in rows], dtype=np.int64)
    try:
        return np.array([t for r in rows for t in r], dtype=np.int64), sizes
    except (ValueError, OverflowError):
        row = next(n for n, r in enumerate(rows) if not _all_numbers(r, _int64))
        raise FileFormatError(path, "face indices are not integers of at most 64 bits",
                              line=int(f_idx[row]) + 1) from None


def _int64(token) -> int:
    value = int(token)
    if not -2 ** 63 <= value < 2 ** 63:
        raise ValueError(f"{value} does not fit in 64 bits")
    return value


def _all_numbers(tokens, kind) -> bool:
    try:
        [kind(t) for t in tokens]
    except ValueError:
        return False
    return True


def load_mesh(path, *, units: str | None = None) -> Mesh:
    """Read a face mesh, keeping its vertex order.

    Parameters
    ----------
    path : str or os.PathLike
        An OBJ (triangles, quads or larger polygons: fan-triangulated, see the
        module docstring), PLY, glTF or GLB file (read with trimesh,
        ``process=False``; their polygons count as triangles).
    units : str, optional
        Length unit of the file (``"cm"`` for the ICT face); None if unknown.

    Returns
    -------
    Mesh

    Raises
    ------
    FileFormatError
        Unknown extension, unreadable or malformed file, empty mesh, NaN or
        infinite coordinates, faces indexing vertices out of range.

    Warns
    -----
    UserWarning
        Degenerate (zero-area) triangles: legal, kept, but suspicious.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in MESH_FORMATS:
        raise FileFormatError(path, f"unknown mesh format {suffix!r}; expected one of "
                                    f"{', '.join(MESH_FORMATS)}")
    if units is not None:
        mm_per_unit(units, where="units")
    if suffix == ".obj":
        vertices, corners, sizes = _read_obj(path)
        faces, face_polygon = _fan(corners, sizes)
    else:
        vertices, faces = _read_trimesh(path)
        face_polygon, sizes = None, None
    message = _topology_problem(vertices, faces)
    if message:
        raise FileFormatError(path, message)
    _warn_degenerate(vertices, faces, path)
    return Mesh(vertices, faces, face_polygon, sizes, units=units, path=str(path))


def load_shape_vertices(paths, neutral: Mesh) -> np.ndarray:
    """The vertices of meshes of the neutral's topology (expression shapes), in order.

    An OBJ whose face lines are the very text of the neutral's OBJ has only its vertex lines
    parsed (its triangles are the neutral's): by one C call (:func:`numpy.loadtxt`), or,
    in a process that has loaded numba or for shapes that pay for loading it, by a
    compiled loop about ten times as fast (:mod:`mocap.mesh._obj_kernel`, the same values
    bit for bit). Any other file is read by :func:`load_mesh` and compared with the neutral.

    Parameters
    ----------
    paths : sequence of path
        Mesh files, one shape each.
    neutral : Mesh
        Their topology (vertex count and triangles).

    Returns
    -------
    ndarray of shape (len(paths), N, 3)
        In the files' units (as :func:`load_mesh` reads them).

    Raises
    ------
    FileFormatError
        A file that :func:`load_mesh` refuses, or whose vertex count or triangles are not
        the neutral's (the file is named).

    Warns
    -----
    UserWarning
        Degenerate triangles, as :func:`load_mesh`.
    """
    faces_text, parse = None, _loadtxt_vertices
    if neutral.path is not None and Path(neutral.path).suffix.lower() == ".obj":
        text = _obj_text(neutral.path)
        faces_text = _span(text, _line_starts(text), b"f")[0]
        kernel = compiled_if_worth(_compiled_vertex_rows, len(paths) * len(text),
                                   _OBJ_BYTES_WORTH_COMPILING)
        if kernel is not None:
            parse = functools.partial(_compiled_vertices, kernel,
                                      np.empty((3 * neutral.n_vertices, 3), np.int64))
    out = np.empty((len(paths), neutral.n_vertices, 3))
    for row, path in enumerate(paths):
        vertices = _vertices_beside(path, faces_text, neutral.n_vertices, parse)
        if vertices is None:                                  # read and compared whole
            mesh = load_mesh(path)
            if mesh.n_vertices != neutral.n_vertices:
                raise FileFormatError(path, f"has {mesh.n_vertices} vertices but the neutral "
                                            f"has {neutral.n_vertices}")
            if not neutral.same_topology(mesh):
                raise FileFormatError(path, "has the neutral's vertex count but other faces: "
                                            "a shape must keep the neutral's topology")
            vertices = mesh.vertices
        else:
            message = _topology_problem(vertices, neutral.faces)
            if message:
                raise FileFormatError(path, message)
            _warn_degenerate(vertices, neutral.faces, path)
        out[row] = vertices
    return out


def _vertices_beside(path, faces_text: bytes | None, n_vertices: int,
                     parse) -> np.ndarray | None:
    """The (n_vertices, 3) vertices of the OBJ `path` when its face lines are `faces_text`
    (the neutral's, from its first face line to the end of its last) and its vertex lines one
    run of ``v x y z ...`` lines, parsed by ``parse(text, n_vertices)``; None otherwise
    (the file is then read whole)."""
    path = Path(path)
    if faces_text is None or path.suffix.lower() != ".obj":
        return None
    data = _obj_text(path)
    starts = _line_starts(data)
    if _span(data, starts, b"f")[0] != faces_text:
        return None
    text, one_run = _span(data, starts, b"v")
    if not text or not one_run:
        return None
    return parse(text, n_vertices)


def _loadtxt_vertices(text: bytes, n_vertices: int) -> np.ndarray | None:
    """The (n_vertices, 3) numbers of the lines ``v x y z ...`` `text`, or None when they
    are not n_vertices such lines."""
    try:
        # the keyword is column 0; a row short of three numbers, or a field that is not
        # one (two spaces, a tab), raises; NumPy converts as float() does (correctly rounded)
        vertices = np.loadtxt(io.BytesIO(text), dtype=np.float64, delimiter=" ",
                              usecols=(1, 2, 3), comments=None, ndmin=2)
    except ValueError:
        return None
    return vertices if len(vertices) == n_vertices else None


def _compiled_vertices(kernel, slow: np.ndarray, text: bytes,
                       n_vertices: int) -> np.ndarray | None:
    """:func:`_loadtxt_vertices` by the compiled `kernel` (:func:`_compiled_vertex_rows`),
    with `slow` (3 n_vertices, 3) int64 for the numbers it leaves to ``float``; lines the
    kernel does not take are left to :func:`_loadtxt_vertices`."""
    vertices = np.empty((n_vertices, 3))
    rows, n_slow = kernel(np.frombuffer(text, np.uint8), vertices, slow)
    if rows != n_vertices:
        return _loadtxt_vertices(text, n_vertices)
    flat = vertices.reshape(-1)
    for index, first, end in slow[:n_slow].tolist():
        flat[index] = float(text[first:end])
    return vertices


@functools.cache
def _compiled_vertex_rows():
    """:func:`mocap.mesh._obj_kernel.vertex_rows`, or None (NumPy parses the vertex lines):
    :func:`mocap.util.optional.compiled`."""
    return compiled("mocap.mesh._obj_kernel", "vertex_rows", what="OBJ vertex parser",
                    fallback="NumPy parses the shapes' vertex lines, about ten times slower")


def _read_trimesh(path) -> tuple[np.ndarray, np.ndarray]:
    import trimesh
    from trimesh.resolvers import FilePathResolver

    with open_input(path, "mesh") as fh:
        try:
            loaded = trimesh.load(fh, file_type=Path(path).suffix.lower()[1:], process=False,
                                  maintain_order=True, force="mesh",
                                  resolver=FilePathResolver(path))  # a .gltf's buffers
        except Exception as exc:  # trimesh raises many types on corrupt files
            raise FileFormatError(path, f"cannot read mesh: {exc}") from None
    if not hasattr(loaded, "faces"):
        raise FileFormatError(path, "empty mesh: the file holds no triangle geometry")
    return np.asarray(loaded.vertices, dtype=np.float64), np.asarray(loaded.faces, np.int64)


def save_obj(mesh, path, *, faces=None, inputs=()) -> None:
    """Write a mesh to an OBJ file atomically.

    Parameters
    ----------
    mesh : Mesh or array_like of shape (N, 3)
        A Mesh (its file polygons are written back, e.g. quads) or vertices.
    path : str or os.PathLike
        Output file; written to a temporary file, then renamed.
    faces : array_like of shape (F, 3), optional
        Triangles (0-based) when `mesh` is a vertex array.
    inputs : iterable of path, optional
        Files this output must never replace.
    """
    if not isinstance(mesh, Mesh):
        if faces is None:
            raise InputError("save_obj needs faces when given a vertex array")
        mesh = Mesh(mesh, faces)
    elif faces is not None:
        raise InputError("save_obj takes faces only with a vertex array, not with a Mesh")
    corners = mesh.polygon_corners + 1
    sizes = mesh.polygon_sizes
    with atomic_path(path, inputs=inputs) as tmp:
        with open(tmp, "w", encoding="ascii") as fh:
            if mesh.units:
                fh.write(f"# units: {mesh.units}\n")
            np.savetxt(fh, mesh.vertices, fmt="v %.10g %.10g %.10g")
            if np.all(sizes == sizes[0]):
                k = int(sizes[0])
                np.savetxt(fh, corners.reshape(-1, k), fmt="f" + " %d" * k)
            else:
                for poly in np.split(corners, np.cumsum(sizes)[:-1]):
                    fh.write("f " + " ".join(map(str, poly)) + "\n")


def _face_cross_rows(vertices: np.ndarray, faces: np.ndarray) -> tuple:
    """:func:`_face_cross` of one mesh, vertices (N, 3) and faces (F, 3), by coordinate:
    the vertices' x, y and z rows (N,) each, and the cross products' (F,) each.

    Each coordinate a contiguous row: gathers and products along the faces, a few times
    faster than ``np.cross`` of gathered (F, 3) rows, the same values to the bit.
    """
    x, y, z = vertices.T.copy()
    first, second, third = faces.T.copy()
    ax, ay, az = x[first], y[first], z[first]
    ux, uy, uz = x[second] - ax, y[second] - ay, z[second] - az
    vx, vy, vz = x[third] - ax, y[third] - ay, z[third] - az
    return (x, y, z), (uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx)


def _face_cross(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unnormalized face normals (…, F, 3): twice the area times the unit normal."""
    a = vertices[..., faces[:, 0], :]
    return np.cross(vertices[..., faces[:, 1], :] - a, vertices[..., faces[:, 2], :] - a)


def face_normals(vertices, faces) -> np.ndarray:
    """Unit face normals, right-handed from the corner order.

    Parameters
    ----------
    vertices : array_like of shape (..., N, 3)
        One mesh or many frames of one topology.
    faces : array_like of shape (F, 3), int

    Returns
    -------
    ndarray of shape (..., F, 3)
        Zero for degenerate faces. NaN vertices give NaN normals.
    """
    vertices = as_float_array(vertices, "vertices")
    cross = _face_cross(vertices, np.asarray(faces, dtype=np.int64))
    norm = np.linalg.norm(cross, axis=-1, keepdims=True)
    return np.divide(cross, norm, out=np.zeros_like(cross), where=norm > 0)


def vertex_normals(vertices, faces) -> np.ndarray:
    """Area-weighted unit vertex normals, for one mesh or many frames at once.

    Parameters
    ----------
    vertices : array_like of shape (..., N, 3)
    faces : array_like of shape (F, 3), int

    Returns
    -------
    ndarray of shape (..., N, 3)
        Zero for vertices that no face uses. NaN vertices propagate NaN to the
        normals of their neighbours.
    """
    vertices = as_float_array(vertices, "vertices")
    if vertices.ndim < 2 or vertices.shape[-1] != 3:
        raise InputError(f"vertices must have shape (..., N, 3), got {vertices.shape}")
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    n = vertices.shape[-2]
    if len(faces) == 0:
        return np.zeros_like(vertices)
    if vertices.ndim == 2:
        # one mesh: each vertex's faces summed in face order, as the product below sums them
        # (each face's cross product repeated for its three corners)
        _, cross = _face_cross_rows(vertices, faces)
        summed = np.stack([np.bincount(faces.ravel(), np.repeat(c, 3), minlength=n)
                           for c in cross], axis=1)
    else:
        cross = _face_cross(vertices, faces)                   # (..., F, 3)
        incidence = sp.csr_matrix((np.ones(faces.size), (faces.ravel(),
                                                         np.repeat(np.arange(len(faces)), 3))),
                                  shape=(n, len(faces)))
        batch = cross.shape[:-2]
        flat = np.moveaxis(cross.reshape(-1, len(faces), 3), 1, 0).reshape(len(faces), -1)
        summed = np.asarray(incidence @ flat).reshape(n, -1, 3)
        summed = np.moveaxis(summed, 1, 0).reshape(batch + (n, 3))
    norm = np.linalg.norm(summed, axis=-1, keepdims=True)
    return np.divide(summed, norm, out=np.zeros_like(summed), where=norm > 0)


def mesh_edges(faces) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The undirected edges of triangles, each once.

    Parameters
    ----------
    faces : ndarray of int, shape (F, 3)

    Returns
    -------
    edges : ndarray of int64, shape (E, 2)
        Vertex ids, the lower first, rows in lexicographic order.
    side_edge : ndarray of int64, shape (3 F,)
        The edge of each face's sides 01, 12 and 20, face after face.
    counts : ndarray of int64, shape (E,)
        The sides on each edge: 1 on the boundary.
    """
    sides = np.asarray(faces, dtype=np.int64)[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    low, high = sides.min(axis=1), sides.max(axis=1)
    span = int(high.max(initial=0)) + 1
    # one integer per edge, in the rows' lexicographic order: a sort of integers, not of rows
    keys, side_edge, counts = np.unique(low * span + high, return_inverse=True,
                                        return_counts=True)
    return np.column_stack(np.divmod(keys, span)), side_edge, counts


def boundary_loops(mesh_or_faces) -> list[np.ndarray]:
    """The closed boundary loops of a mesh, longest first.

    Parameters
    ----------
    mesh_or_faces : Mesh or array_like of shape (F, 3), int

    Returns
    -------
    list of ndarray of int
        Vertex ids of each loop in the faces' orientation. The ICT face has 4:
        the outer rim, the two eye holes and the mouth opening.
    """
    faces = mesh_or_faces.faces if isinstance(mesh_or_faces, Mesh) else \
        np.asarray(mesh_or_faces, dtype=np.int64)
    _, side_edge, counts = mesh_edges(faces)
    edges = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)[counts[side_edge] == 1]
    following: dict[int, list[int]] = {}
    for a, b in edges.tolist():
        following.setdefault(a, []).append(b)
    loops = []
    while following:
        start = next(iter(following))
        loop, current = [start], start
        while True:
            nexts = following[current]
            nxt = nexts.pop()
            if not nexts:
                del following[current]
            if nxt == start or nxt not in following:
                break
            loop.append(nxt)
            current = nxt
        loops.append(np.array(loop, dtype=np.int64))
    return sorted(loops, key=len, reverse=True)
