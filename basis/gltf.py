"""glTF 2.0 export of a basis as morph targets, with an optional weight animation.

One scene, one node, one mesh with one triangle primitive: the neutral's
POSITION and NORMAL, uint32 indices, and one morph target per shape (POSITION
displacements). The shape names go to ``mesh.extras.targetNames``, which
Blender, three.js and :func:`basis.artist.load_artist_basis` read. Weights of
a take become an animation of the node's ``weights``; a rigid motion of the
face (e.g. head motion) an animation of its ``rotation`` and ``translation``.

Weights that play back exactly: importers keep a morph weight inside a
slider range (Blender clamps each shape key to ``[slider_min, slider_max]``,
``[0, 1]`` unless the file's default weights or the first key of its weight
animation say otherwise; both are the glTF importer's only hooks). So every
animated weight is written inside ``[0, 1]``: a shape whose weights leave it
becomes one target scaled by its largest weight (``e · max w``, weight
``w / max w``) and, when its weights turn negative, a second target
``<name>.neg`` (``−e · max(−w)``, weight ``max(−w, 0) / max(−w)``). Linear
interpolation commutes with this split, so the played mesh is the one
computed at every time, between keys too. ``mesh.extras.mocap2mesh`` records
each target's shape and factor (:func:`basis.artist.load_artist_basis` folds
them back into the shapes).

Frame numbers: key ``k`` of an animation is at ``(first_frame + k) / rate``
seconds, so that an importer at the take's rate puts it on the capture's own
frame number (Blender: scene fps = rate).

Units and axes: glTF is in metres, +Y up, the front of an asset facing +Z.
Positions are scaled from the mesh's ``units`` to metres (cm × 0.01,
mm × 0.001); axes are written as they are, so the mesh must already be Y-up
and facing +Z, as the ICT face is (nose tip at the largest z). A mesh without
units is written unscaled, with a warning.
"""

from __future__ import annotations

import base64
import functools
import json
import math
import struct
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from basis.basis_io import as_shape_names
from mocap.errors import InputError
from mocap.mesh.mesh import Mesh, vertex_normals
from mocap.units import mm_per_unit
from mocap.util.atomic import atomic_path, preallocate
from mocap.util.blas import map_on_blas_threads, worker_threads
from mocap.util.extremes import column_extremes
from mocap.util.parallel_writes import positional_writer, write_parts
from mocap.util.validation import as_float_array, as_int, as_positive_float

__all__ = ["GLTF_FORMATS", "NEGATIVE_SUFFIX", "MorphTargets", "morph_targets", "write_gltf"]

#: File extensions :func:`write_gltf` writes: binary GLB, or JSON with the buffer embedded.
GLTF_FORMATS = (".glb", ".gltf")
#: Name suffix of the target that carries a shape's negative weights.
NEGATIVE_SUFFIX = ".neg"
#: The weight range every importer gives a morph target (Blender's default slider range).
PLAYBACK_RANGE = (0.0, 1.0)

# glTF 2.0's codes (the specification's, as pygltflib names them): buffer view targets,
# accessor component types and types, the triangle primitive mode, linear interpolation,
# and the GLB header's magic, version and chunk types
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_FLOAT, _UNSIGNED_INT = 5126, 5125
_SCALAR, _VEC3, _VEC4 = "SCALAR", "VEC3", "VEC4"
_TRIANGLES, _LINEAR = 4, "LINEAR"
_GLB_MAGIC, _GLB_VERSION, _CHUNK_JSON, _CHUNK_BIN = b"glTF", 2, b"JSON", b"BIN\0"
#: Bytes of the GLB header (magic, version, length) and of a chunk header (length, type).
_GLB_HEADER, _CHUNK_HEADER = 12, 8


class _Buffer:
    """One glTF buffer assembled from float32/uint32 arrays, one view and accessor each.

    Views and accessors are the glTF JSON objects as dicts, with pygltflib's key
    order (so that the document is the one ``pygltflib.GLTF2.gltf_to_json`` writes).
    """

    def __init__(self):
        self.chunks, self.views, self.accessors, self.length = [], [], [], 0

    def add(self, arr, kind: str, *, target: int | None = None, extremes=None) -> int:
        """Append `arr` (count, k) or (count,), or a :class:`_Rows`, as one view and
        accessor; return its index. `extremes`: the (2, k) min and max of its stored
        values, when known without reading them (a :class:`_Rows` needs them)."""
        if isinstance(arr, _Rows):
            data, component = arr, _FLOAT
        else:
            component = _UNSIGNED_INT if arr.dtype == np.uint32 else _FLOAT
            data = np.ascontiguousarray(arr, dtype="<u4" if component == _UNSIGNED_INT
                                        else "<f4")
        if extremes is None:
            extremes = column_extremes(data.reshape(data.shape[0], -1))
        index = self.describe(data.shape, kind, extremes, component=component, target=target)
        self.chunks.append(data)
        return index

    def describe(self, shape: tuple, kind: str, extremes, *, component=_FLOAT,
                 target: int | None = None) -> int:
        """A view of the buffer's next ``4 · prod(shape)`` bytes and its accessor (count
        ``shape[0]``, min and max the (2, k) `extremes`); return its index. The bytes are
        the caller's to append to :attr:`chunks` (:meth:`add` does), one chunk for one
        view or for several views described one after another."""
        width = math.prod(shape[1:])
        view = {"buffer": 0, "byteOffset": self.length, "byteLength": 4 * math.prod(shape)}
        if target == _ARRAY_BUFFER:     # every element is 4 bytes: views stay 4-byte aligned
            view["byteStride"] = 4 * width
        if target is not None:
            view["target"] = target
        self.views.append(view)
        low, high = np.asarray(extremes).reshape(2, -1).tolist()
        self.accessors.append({
            "bufferView": len(self.views) - 1, "byteOffset": 0, "componentType": component,
            "normalized": False, "count": shape[0], "type": kind, "max": high, "min": low})
        self.length += view["byteLength"]
        return len(self.accessors) - 1

    def write(self, fh) -> None:
        """Write the buffer's bytes to the binary file `fh` from its position, which is
        left after them: each array from its own memory, the values of each
        :class:`_Rows` made a part at a time, the parts shared among the worker threads."""
        start = fh.tell()
        write_parts(positional_writer(fh, start), self._parts(), workers=worker_threads(),
                    part_bytes=_PART_BYTES)
        fh.seek(start + self.length)

    def blob(self) -> bytearray:
        """The buffer's bytes in memory (for a ``.gltf``'s data URI)."""
        out = bytearray(self.length)

        def write_at(offset: int, data) -> None:
            out[offset:offset + memoryview(data).nbytes] = data
        write_parts(write_at, self._parts(), workers=1, part_bytes=_PART_BYTES)
        return out

    def _parts(self) -> list:
        """The buffer's bytes as parts of :func:`mocap.util.parallel_writes.write_parts`,
        (size, part) each: each array's memory, and the :class:`_Rows` values of about
        :data:`_PART_BYTES` at a time (of one or of several consecutive accessors), made
        when called."""
        parts, pieces, size = [], [], 0
        for chunk in self.chunks:
            if not isinstance(chunk, _Rows):
                if pieces:
                    parts.append((size, functools.partial(_made_part, pieces, size)))
                    pieces, size = [], 0
                parts.append((chunk.nbytes, memoryview(chunk).cast("B")))
                continue
            rows_per_piece = max(1, _PART_BYTES // chunk.row_bytes)
            for first in range(0, chunk.n_rows, rows_per_piece):
                rows = slice(first, min(first + rows_per_piece, chunk.n_rows))
                piece_bytes = (rows.stop - rows.start) * chunk.row_bytes
                if pieces and size + piece_bytes > _PART_BYTES:
                    parts.append((size, functools.partial(_made_part, pieces, size)))
                    pieces, size = [], 0
                pieces.append((chunk, rows))
                size += piece_bytes
        if pieces:
            parts.append((size, functools.partial(_made_part, pieces, size)))
        return parts


#: Bytes of :class:`_Rows` values made at a time, by one worker thread (cache-sized).
_PART_BYTES = 1 << 19


def _made_part(pieces, size: int, out: np.ndarray) -> memoryview:
    """The bytes (`size`) of `pieces`, (:class:`_Rows`, slice of its rows) each, in order,
    made in `out` (uint8, at least `size`)."""
    part = out[:size].view("<f4")
    start = 0
    for rows_of, rows in pieces:
        n = rows.stop - rows.start
        rows_of.fill(rows, part[start:start + n * rows_of.row_values].reshape(
            n, rows_of.row_values))
        start += n * rows_of.row_values
    return memoryview(out[:size])


@dataclass(frozen=True, eq=False)
class _Rows:
    """An accessor's float32 values (`shape`) made from the caller's arrays as they are
    written: ``fill(rows, out)`` writes those of a slice of the `n_rows` source rows
    (`row_values` floats each) into `out` (rows, row_values) float32 (no copy of the whole).
    """

    shape: tuple
    fill: Callable[[slice, np.ndarray], None]
    n_rows: int
    row_values: int

    @property
    def nbytes(self) -> int:
        return 4 * math.prod(self.shape)

    @property
    def row_bytes(self) -> int:
        return 4 * self.row_values


@dataclass(frozen=True, eq=False)
class MorphTargets:
    """How shapes and their weights become morph targets whose weights stay in [0, 1].

    Target k is ``factor[k] · e_{shape[k]}``; its weight at frame t is
    ``max(w_t,shape[k] / factor[k], 0)``, and ``w_ti = Σ_{k: shape[k] = i}
    factor[k] · u_tk``.

    Attributes
    ----------
    names : tuple of str
        Target names: the shape's name, ``<name>.neg`` for a negative part.
    shape : ndarray of int, shape (K,)
        The shape each target comes from.
    factor : ndarray, shape (K,)
        Scale of each target (negative for a ``.neg`` target); 1 for a shape
        whose weights already stay in [0, 1].
    """

    names: tuple
    shape: np.ndarray
    factor: np.ndarray

    def weights(self, weights, dtype=np.float64, *, out=None) -> np.ndarray:
        """Target weights (T, K) in [0, 1] of shape weights (T, n), as `dtype` or into
        `out` (T, K) (rounded once, from the float64 quotients)."""
        weights = np.asarray(weights, dtype=float)
        if out is None:
            out = np.empty((len(weights), len(self.shape)), dtype=dtype)
        # the shapes are valid columns: "clip" skips take's bounds check (twice as fast)
        quotients = np.take(weights, self.shape, axis=1, mode="clip")
        np.divide(quotients, self.factor, out=quotients)
        np.copyto(out, np.maximum(quotients, 0.0, out=quotients), casting="same_kind")
        return out

    def shape_weights(self, target_weights) -> np.ndarray:
        """Shape weights (T, n) back from target weights (T, K)."""
        target_weights = np.asarray(target_weights, dtype=float)
        out = np.zeros((len(target_weights), int(self.shape.max()) + 1))
        np.add.at(out.T, self.shape, (target_weights * self.factor).T)
        return out


def morph_targets(names, weights=None) -> MorphTargets:
    """The morph targets that play `weights` back inside [0, 1] (see the module notes).

    Parameters
    ----------
    names : sequence of str, length n
    weights : array_like of shape (T, n), optional
        Without weights (a basis without animation), one target per shape, factor 1.

    Returns
    -------
    MorphTargets

    Raises
    ------
    InputError
        A ``<name>.neg`` target would take the name of another shape.

    Examples
    --------
    >>> t = morph_targets(["a", "b"], [[0.5, -3.0], [0.25, 2.0]])
    >>> t.names, t.factor.tolist()
    (('a', 'b', 'b.neg'), [1.0, 2.0, -3.0])
    >>> t.weights([[0.5, -3.0]]).tolist()
    [[0.5, 0.0, 1.0]]
    """
    names = tuple(names)
    if weights is None:
        return MorphTargets(names, np.arange(len(names)), np.ones(len(names)))
    weights = np.asarray(weights, dtype=float)
    if not len(weights):
        return _targets_of_range(names, np.zeros(len(names)), np.zeros(len(names)))
    return _targets_of_range(names, *column_extremes(weights))


def _targets_of_range(names: tuple, lowest, highest) -> MorphTargets:
    """:func:`morph_targets` of weights whose columns span `lowest` to `highest`, (n,) each."""
    low, high = PLAYBACK_RANGE
    top = np.maximum(highest, high)
    bottom = np.minimum(lowest, 0.0)
    shape, factor, out = [], [], []
    for i, name in enumerate(names):
        shape.append(i)
        factor.append(top[i])
        out.append(name)
        if bottom[i] < low:
            negative = name + NEGATIVE_SUFFIX
            if negative in names:
                raise InputError(f"shape {name!r} has negative weights, and its negative "
                                 f"target's name {negative!r} is another shape's")
            shape.append(i)
            factor.append(min(bottom[i], -high))
            out.append(negative)
    return MorphTargets(tuple(out), np.array(shape, dtype=np.intp), np.array(factor))


def write_gltf(path, neutral: Mesh, displacements, names, *, weights=None, rotation=None,
               translation=None, rate: float | None = None, first_frame: int = 0,
               name: str = "face", inputs=()) -> None:
    """Write a neutral mesh and its basis as glTF morph targets.

    Parameters
    ----------
    path : str or os.PathLike
        ``*.glb`` (binary) or ``*.gltf`` (JSON, buffer embedded as a data URI).
        Written to a temporary file beside it, then renamed.
    neutral : Mesh
        The neutral, Y-up and facing +Z; its ``units`` set the scale to metres.
    displacements : array_like of shape (n, N, 3), mesh units
        One displacement field per shape. No NaN.
    names : sequence of str, length n
        Shape names (``mesh.extras.targetNames``), unique.
    weights : array_like of shape (T, n), optional
        Weights of each frame: an animation with one LINEAR sampler (input:
        times ``(first_frame + t) / rate`` s, output: the weights of the
        morph targets of :func:`morph_targets`, in [0, 1], frame after frame)
        targeting the node's ``weights``. No NaN.
    rotation : array_like of shape (T, 3, 3), or scipy.spatial.transform.Rotation, optional
        Rigid motion of the face in each frame, about the mesh's origin:
        vertex v of frame t is at ``rotation[t] @ v + translation[t]``. Written
        as LINEAR samplers of the node's ``rotation`` (unit quaternions x, y, z,
        w, signs made continuous so that the slerp takes the short way) and
        ``translation`` (metres). Goes with `translation`. Matrices are checked
        (orthonormal, det +1) and converted at each call; a ``Rotation`` of T
        rotations is taken as it is (several files of one motion convert it once).
    translation : array_like of shape (T, 3), mesh units, optional
    rate : float, optional
        Frame rate, Hz; required with `weights` or a motion, only with them.
    first_frame : int
        Frame number of the first row of `weights` and of the motion (the
        capture's; key times are frame numbers over `rate`).
    name : str
        Name of the node, mesh and animation.
    inputs : iterable of path, optional
        Files never to replace (the neutral's own file is always protected).

    Raises
    ------
    InputError
        Unknown extension, shapes or names inconsistent with the neutral, NaN
        or infinite values, `rate` missing or given without an animation,
        `rotation` without `translation` (or the reverse), not rotations,
        frame counts that differ, the file cannot be written (named).

    Warns
    -----
    UserWarning
        The neutral has no units: positions are written unscaled.

    Notes
    -----
    Accessors are float32 (positions, normals, times, weights) or uint32
    (indices), each in its own 4-byte-aligned view with ``min``/``max`` of the
    stored values; vertex-attribute views carry ``byteStride`` 12. NORMAL is
    the area-weighted vertex normal of the neutral (``+Z`` where no face
    defines one); morph targets carry no NORMAL displacement. Default morph
    weights are 0. ``mesh.extras.mocap2mesh`` holds ``shapes`` (the names),
    ``target_shape`` and ``target_factor`` (:class:`MorphTargets`); the
    animation's extras hold ``rate`` and ``first_frame``.
    """
    path = Path(path)
    if path.suffix.lower() not in GLTF_FORMATS:
        raise InputError(f"{path}: unknown glTF extension {path.suffix!r}; expected one of "
                         f"{', '.join(GLTF_FORMATS)}")
    if not isinstance(neutral, Mesh):
        raise InputError(f"neutral must be a Mesh, got {type(neutral).__name__}")
    n_vertices = neutral.n_vertices
    # values checked by their extremes below (no pass of their own)
    displacements = as_float_array(displacements, "displacements", shape=(None, n_vertices, 3),
                                   copy=False, check_finite=False)
    names = as_shape_names(names, len(displacements))
    times, weights, motion = _animation(weights, rotation, translation, rate, len(names),
                                        first_frame)
    # the stored values are the inputs rounded monotonically, so every large accessor's
    # min and max are those of its input's extremes, rounded the same way
    shape_range, weight_range, normals = _surveyed(neutral, displacements, weights)
    # extremes are NaN or infinite exactly where a value is: the exact checks name it
    for values, what, extremes in ((displacements, "displacements", shape_range),
                                   (weights, "weights", weight_range)):
        if extremes is not None and not np.isfinite(extremes).all():
            as_float_array(values, what, allow_nan=False, copy=False)
    targets = morph_targets(names) if weights is None else _targets_of_range(names,
                                                                             *weight_range)
    scale = _to_metres(neutral)

    buf = _Buffer()
    indices = buf.add(neutral.faces.reshape(-1).astype(np.uint32), _SCALAR,
                      target=_ELEMENT_ARRAY_BUFFER)
    position = buf.add(_scaled(neutral.vertices, scale), _VEC3, target=_ARRAY_BUFFER)
    normal = buf.add(normals, _VEC3, target=_ARRAY_BUFFER)
    # each target's stored extremes: its shape's extremes scaled and rounded as its values
    target_range = _scaled(shape_range[targets.shape], targets.factor[:, None, None] * scale)
    target_range = np.stack([target_range.min(axis=1), target_range.max(axis=1)], axis=1)
    morphs = [{"POSITION": buf.describe((n_vertices, 3), _VEC3, extremes,
                                        target=_ARRAY_BUFFER)} for extremes in target_range]
    buf.chunks.append(_target_displacement_rows(displacements, targets, scale))
    record = {"shapes": list(names), "target_shape": targets.shape.tolist(),
              "target_factor": targets.factor.tolist()}
    # the glTF JSON objects, keys in pygltflib's order, empty ones left out as it does
    primitive = {"attributes": {"POSITION": position, "NORMAL": normal}, "indices": indices,
                 "mode": _TRIANGLES, "targets": morphs}
    mesh = {"extras": {"targetNames": list(targets.names), "mocap2mesh": record},
            "primitives": [primitive], "weights": [0.0] * len(targets.names), "name": name}
    gltf = {"accessors": buf.accessors}
    if times is not None:
        time = buf.add(times, _SCALAR)
        outputs = [] if weights is None else [
            ("weights", buf.add(_target_weight_rows(targets, weights), _SCALAR,
                                extremes=_min_max(targets.weights(np.stack(weight_range),
                                                                 np.float32).reshape(-1, 1))))]
        if motion is not None:
            outputs += [("rotation", buf.add(motion[0], _VEC4)),
                        ("translation", buf.add(_scaled(motion[1], scale), _VEC3))]
        gltf["animations"] = [{
            "extras": {"rate": float(rate), "first_frame": int(first_frame)}, "name": name,
            "channels": [{"sampler": i, "target": {"node": 0, "path": path}}
                         for i, (path, _) in enumerate(outputs)],
            "samplers": [{"input": time, "interpolation": _LINEAR, "output": out}
                         for _, out in outputs]}]
    gltf.update({
        "asset": {"generator": "mocap2mesh", "version": "2.0"}, "bufferViews": buf.views,
        "buffers": [{"byteLength": buf.length}], "meshes": [mesh],
        "nodes": [{"mesh": 0, "name": name}], "scene": 0, "scenes": [{"nodes": [0]}]})
    _save(gltf, buf, path, [*inputs, neutral.path])


def _surveyed(neutral: Mesh, displacements: np.ndarray, weights):
    """The extremes of each shape's displacements (n, 2, 3) and of each column of
    `weights` (two (n,); None without weights), and the neutral's unit vertex normals
    (N, 3), +Z where no face defines one: in pieces, on the worker threads."""
    def normals():
        unit = vertex_normals(neutral.vertices, neutral.faces)
        unit[np.linalg.norm(unit, axis=1) == 0] = (0.0, 0.0, 1.0)
        return unit

    def shape_extremes(shapes):
        return np.stack(column_extremes(shapes), axis=1)

    shape_parts = np.array_split(displacements, 2)
    frame_parts = [] if weights is None else [p for p in np.array_split(weights, 2) if len(p)]
    done = map_on_blas_threads(lambda task: task(), [
        normals, *(functools.partial(shape_extremes, p) for p in shape_parts),
        *(functools.partial(column_extremes, p) for p in frame_parts)])
    shape_range = np.concatenate(done[1:1 + len(shape_parts)])
    frame_ends = list(zip(*done[1 + len(shape_parts):]))
    weight_range = None if weights is None else (np.minimum.reduce(frame_ends[0]),
                                                np.maximum.reduce(frame_ends[1]))
    return shape_range, weight_range, done[0]


def _animation(weights, rotation, translation, rate, n: int, first_frame):
    """Times (T,) s, weights (T, n), (quaternions (T, 4), translation (T, 3)); None if absent."""
    if (rotation is None) != (translation is None):
        raise InputError("rotation and translation go together (the face's rigid motion)")
    if weights is None and rotation is None:
        if rate is not None:
            raise InputError("rate is only used with an animation (weights or a motion)")
        return None, None, None
    if rate is None:
        raise InputError("an animation needs the take's rate (Hz) to time it")
    rate = as_positive_float(rate, "rate")
    counts = []
    if weights is not None:
        weights = as_float_array(weights, "weights", shape=(None, n), copy=False,
                                 check_finite=False)     # checked by the caller
        counts.append(len(weights))
    motion = None
    if rotation is not None:
        quat = _quaternions(rotation)                       # x, y, z, w: glTF's order
        translation = as_float_array(translation, "translation", shape=(len(quat), 3),
                                     allow_nan=False)
        turn = np.einsum("ij,ij->i", quat[1:], quat[:-1]) < 0
        quat[1:] *= np.where(np.cumsum(turn) % 2 == 1, -1.0, 1.0)[:, None]
        motion = (quat, translation)
        counts.append(len(quat))
    if counts[0] == 0:
        raise InputError("the animation has no frames")
    if len(set(counts)) > 1:
        raise InputError(f"weights have {counts[0]} frames but the motion {counts[1]}")
    first_frame = as_int(first_frame, "first_frame", minimum=0)
    return (first_frame + np.arange(counts[0])) / rate, weights, motion


def _quaternions(rotation) -> np.ndarray:
    """Unit quaternions (T, 4), x, y, z, w, of rotation matrices (T, 3, 3), checked, or of a
    :class:`~scipy.spatial.transform.Rotation` of T rotations."""
    if isinstance(rotation, Rotation):
        if rotation.single:
            raise InputError("rotation must hold one rotation a frame, got a single Rotation")
        return rotation.as_quat()
    rotation = as_float_array(rotation, "rotation", shape=(None, 3, 3), allow_nan=False)
    orthogonal = np.einsum("tij,tkj->tik", rotation, rotation)
    if not (np.allclose(orthogonal, np.eye(3), atol=1e-6)
            and np.all(np.linalg.det(rotation) > 0)):
        raise InputError("rotation must hold rotation matrices (orthonormal, det +1)")
    return Rotation.from_matrix(rotation).as_quat()


def _to_metres(neutral: Mesh) -> float:
    if neutral.units is None:
        warnings.warn("the neutral mesh has no units: positions are written unscaled, "
                      "as if in metres", stacklevel=3)
        return 1.0
    return mm_per_unit(neutral.units) / 1000.0


def _scaled(values: np.ndarray, factor: float) -> np.ndarray:
    """``values * factor`` as float32, rounded once from the float64 product."""
    out = np.empty(values.shape, dtype="<f4")
    return np.multiply(values, factor, out=out, casting="same_kind")


def _target_displacement_rows(displacements: np.ndarray, targets: MorphTargets,
                              scale: float) -> _Rows:
    """The displacements of every target, ``displacements[shape[k]] · factor[k] · scale``
    (:func:`_scaled`), one after another as (K N, 3) rows, formed as they are written."""
    factor = targets.factor * scale
    n_vertices = displacements.shape[1]

    def fill(rows, out):
        for k in range(rows.start // n_vertices, (rows.stop - 1) // n_vertices + 1):
            first, last = max(rows.start, k * n_vertices), min(rows.stop, (k + 1) * n_vertices)
            np.multiply(displacements[targets.shape[k], first - k * n_vertices:
                                      last - k * n_vertices], factor[k],
                        out=out[first - rows.start:last - rows.start], casting="same_kind")
    n_rows = len(targets.shape) * n_vertices
    return _Rows((n_rows, 3), fill, n_rows, 3)


def _target_weight_rows(targets: MorphTargets, weights: np.ndarray) -> _Rows:
    """The target weights (T, K) of `weights` (T, n) as one (T K,) accessor, formed as it
    is written, a few frames at a time."""
    return _Rows((len(weights) * len(targets.shape),),
                 lambda rows, out: targets.weights(weights[rows], out=out), len(weights),
                 len(targets.shape))


def _min_max(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Min and max over the rows of `values` (rows, k), e.g. of an input's extremes rounded
    as its stored values are."""
    return values.min(axis=0), values.max(axis=0)


def _json(gltf: dict, **layout) -> str:
    """The glTF JSON text, as ``pygltflib.GLTF2.gltf_to_json`` writes it."""
    return json.dumps(gltf, allow_nan=False, **layout)


def _save(gltf: dict, buf: _Buffer, path: Path, inputs) -> None:
    with atomic_path(path, inputs=inputs) as tmp:
        if path.suffix.lower() == ".gltf":
            gltf["buffers"][0] = {"uri": "data:application/octet-stream;base64,"
                                         + base64.b64encode(buf.blob()).decode("ascii"),
                                  "byteLength": buf.length}
            tmp.write_text(_json(gltf, indent="  "), encoding="ascii")
        else:
            _save_glb(gltf, buf, tmp)


def _save_glb(gltf: dict, buf: _Buffer, path: Path) -> None:
    """Write the binary glTF: the bytes of ``pygltflib.GLTF2.save_binary`` (header, JSON
    chunk padded with spaces to 4 bytes, BIN chunk), each array written from its own
    memory instead of being copied into one blob and re-sliced per view."""
    text = _json(gltf, separators=(",", ":")).encode("ascii")
    text += b" " * (-(_GLB_HEADER + len(text)) % 4)
    size = _GLB_HEADER + 2 * _CHUNK_HEADER + len(text) + buf.length
    header = struct.pack("<4sIII4s", _GLB_MAGIC, _GLB_VERSION, size, len(text), _CHUNK_JSON)
    with open(path, "wb") as fh:
        preallocate(fh, size)
        fh.write(header)
        fh.write(text)
        fh.write(struct.pack("<I4s", buf.length, _CHUNK_BIN))
        buf.write(fh)
