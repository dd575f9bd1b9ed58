"""Artist bases: the blendshapes an artist sculpted, as displacements of a neutral.

e_i = ê_i − v0 for each artist shape ê_i on the neutral's topology (the
quasi-eigen paper's E^H). Shapes come from a directory of OBJ files (one per
shape, named by file stem) or from the morph targets of a glTF/GLB file.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from mocap.errors import FileFormatError, InputError
from mocap.mesh.mesh import Mesh, load_mesh, load_shape_vertices
from mocap.units import mm_per_unit
from mocap.util.validation import as_float_array

__all__ = ["ArtistBasis", "load_artist_basis"]

#: glTF base positions may differ from the neutral's by this fraction of its
#: bounding-box diagonal (float32 storage); more means other units or vertex order.
_GLTF_BASE_RTOL = 1e-5
_GLTF_FLOAT, _GLTF_VEC3 = 5126, "VEC3"


@dataclass(frozen=True, eq=False)
class ArtistBasis:
    """An artist's blendshapes as displacements of a neutral mesh.

    Attributes
    ----------
    names : tuple of str
        Shape names, n of them (OBJ file stems, or glTF ``extras.targetNames``).
    neutral : Mesh
        The neutral v0 (N vertices, mesh units).
    displacements : ndarray of shape (n, N, 3), mesh units
        e_i = ê_i − v0 (read-only).
    """

    names: tuple
    neutral: Mesh
    displacements: np.ndarray

    def __post_init__(self):
        disp = as_float_array(self.displacements, "displacements",
                              shape=(len(self.names), self.neutral.n_vertices, 3),
                              allow_nan=False)
        disp.flags.writeable = False
        object.__setattr__(self, "displacements", disp)
        object.__setattr__(self, "names", tuple(self.names))

    @property
    def n_shapes(self) -> int:
        """Number of shapes n."""
        return len(self.names)

    def index(self, name: str) -> int:
        """Position of a shape in the basis."""
        try:
            return self.names.index(name)
        except ValueError:
            raise InputError(f"no artist shape {name!r}; shapes: {', '.join(self.names)}") \
                from None

    def evaluate(self, weights) -> np.ndarray:
        """Vertices v0 + Σ w_i e_i for one weight vector or many frames at once.

        Parameters
        ----------
        weights : array_like of shape (..., n)

        Returns
        -------
        ndarray of shape (..., N, 3), mesh units
            NaN weights give NaN vertices.
        """
        weights = as_float_array(weights, "weights")
        if weights.ndim < 1 or weights.shape[-1] != self.n_shapes:
            raise InputError(f"weights must have shape (..., {self.n_shapes}), "
                             f"got {weights.shape}")
        flat = self.displacements.reshape(self.n_shapes, -1)
        out = (weights.reshape(-1, self.n_shapes) @ flat).reshape(
            weights.shape[:-1] + (self.neutral.n_vertices, 3))
        return out + self.neutral.vertices


def load_artist_basis(neutral, shapes, *, names: Sequence[str] | None = None,
                      units: str | None = None) -> ArtistBasis:
    """Load an artist basis.

    Parameters
    ----------
    neutral : str, os.PathLike or Mesh
        The neutral mesh (file read with :func:`mocap.mesh.mesh.load_mesh`).
    shapes : str or os.PathLike
        A directory of OBJ files, one shape each, named by file stem (all
        ``*.obj`` in name order unless `names` is given); or a glTF/GLB file whose
        first mesh with morph targets holds the shapes, named by
        ``mesh.extras.targetNames`` (else ``target_0``, ...). glTF positions are
        metres (the glTF convention) and are converted to the neutral's units;
        when the neutral has no units they are taken as they are.
    names : sequence of str, optional
        The shapes to load, in this order.
    units : str, optional
        Units of the neutral file (ignored when `neutral` is a Mesh).

    Returns
    -------
    ArtistBasis

    Raises
    ------
    FileFormatError
        A shape with another vertex count or topology than the neutral (the
        file is named), a glTF without morph targets or with base positions
        other than the neutral's, an unreadable file.
    InputError
        `shapes` neither a directory nor a glTF/GLB file, a requested name
        absent, no shapes.
    """
    if not isinstance(neutral, Mesh):
        neutral = load_mesh(neutral, units=units)
    shapes = Path(shapes)
    if names is not None:
        names = [str(n) for n in names]
        if len(set(names)) != len(names):
            raise InputError("names lists a shape twice")
    if shapes.is_dir():
        names, vertices = _obj_shapes(neutral, shapes, names)
    elif shapes.suffix.lower() in (".gltf", ".glb") and shapes.is_file():
        names, vertices = _gltf_shapes(neutral, shapes, names)
    else:
        raise InputError(f"{shapes}: shapes must be a directory of OBJ files or a glTF/GLB file")
    if not names:
        raise InputError(f"{shapes}: no artist shapes found")
    return ArtistBasis(tuple(names), neutral, vertices - neutral.vertices)


def _obj_shapes(neutral: Mesh, folder: Path, names):
    files = {p.stem: p for p in sorted(folder.glob("*.obj"))}
    if names is None:
        names = list(files)
    absent = [n for n in names if n not in files]
    if absent:
        raise InputError(f"{folder}: no OBJ file for shapes {', '.join(absent)}")
    return names, load_shape_vertices([files[name] for name in names], neutral)


def _gltf_shapes(neutral: Mesh, path: Path, names):
    import pygltflib

    try:
        gltf = pygltflib.GLTF2().load(str(path))
    except Exception as exc:  # pygltflib raises many types on corrupt files
        raise FileFormatError(path, f"cannot read glTF: {exc}") from None
    mesh = next((m for m in gltf.meshes if any(p.targets for p in m.primitives)), None)
    if mesh is None:
        raise FileFormatError(path, "no mesh with morph targets")
    buffers = {}
    to_mesh_units = 1.0 if neutral.units is None else 1000.0 / mm_per_unit(neutral.units)
    base = to_mesh_units * np.concatenate([_accessor(gltf, path, p.attributes.POSITION, buffers)
                                           for p in mesh.primitives])
    n_targets = len(mesh.primitives[0].targets)
    if any(len(p.targets or ()) != n_targets for p in mesh.primitives):
        raise FileFormatError(path, "primitives of the morphed mesh have different target counts")
    if len(base) != neutral.n_vertices:
        raise FileFormatError(path, f"has {len(base)} vertices but the neutral has "
                                    f"{neutral.n_vertices}")
    diag = float(np.linalg.norm(np.ptp(neutral.vertices, axis=0)))
    if np.abs(base - neutral.vertices).max() > _GLTF_BASE_RTOL * diag:
        raise FileFormatError(path, "base positions differ from the neutral's (other units or "
                                    "vertex order?)")
    extras = mesh.extras if isinstance(mesh.extras, dict) else {}
    all_names = [str(n) for n in extras.get("targetNames", [])]
    if len(all_names) != n_targets:
        all_names = [f"target_{i}" for i in range(n_targets)]
    target, factor = list(range(n_targets)), [1.0] * n_targets
    folded = _folded_targets(extras.get("mocap2mesh"), n_targets)
    if folded is not None:      # written by basis.gltf: scaled and split targets
        all_names, target, factor = folded
    if names is None:
        names = all_names
    absent = [n for n in names if n not in all_names]
    if absent:
        raise InputError(f"{path}: no morph target named {', '.join(absent)}")
    vertices = np.empty((len(names), neutral.n_vertices, 3))
    for i, name in enumerate(names):
        t = all_names.index(name)
        delta = to_mesh_units * np.concatenate(
            [_accessor(gltf, path, p.targets[target[t]]["POSITION"], buffers)
             for p in mesh.primitives])
        vertices[i] = base + delta / factor[t]
    return names, vertices


def _folded_targets(record, n_targets: int):
    """Shape names, the target holding each shape and its factor, from the record that
    :func:`basis.gltf.write_gltf` leaves in ``mesh.extras.mocap2mesh``; None if absent or
    inconsistent (the targets are then read as shapes)."""
    if not isinstance(record, dict):
        return None
    shapes, owner, factor = (record.get(k) for k in ("shapes", "target_shape", "target_factor"))
    if not (isinstance(shapes, list) and isinstance(owner, list) and isinstance(factor, list)
            and len(owner) == len(factor) == n_targets):
        return None
    try:
        first = {int(i): k for k, i in reversed(list(enumerate(owner)))}
        scale = [float(factor[first[i]]) for i in range(len(shapes))]
    except (KeyError, TypeError, ValueError):
        return None
    if not all(np.isfinite(scale)) or min(scale, default=1.0) <= 0:
        return None
    return [str(n) for n in shapes], [first[i] for i in range(len(shapes))], scale


def _accessor(gltf, path: Path, index, buffers: dict) -> np.ndarray:
    """A float VEC3 accessor as a (count, 3) float64 array."""
    if index is None:
        raise FileFormatError(path, "a primitive or morph target has no POSITION")
    acc = gltf.accessors[index]
    if acc.componentType != _GLTF_FLOAT or acc.type != _GLTF_VEC3:
        raise FileFormatError(path, f"accessor {index} is not float VEC3")
    if acc.sparse is not None:
        raise FileFormatError(path, f"accessor {index} is sparse, which is not supported")
    if acc.bufferView is None:
        return np.zeros((acc.count, 3))
    view = gltf.bufferViews[acc.bufferView]
    if view.buffer not in buffers:
        buffers[view.buffer] = _buffer_bytes(gltf, path, view.buffer)
    data = buffers[view.buffer]
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    stride = view.byteStride or 12
    if start + stride * (acc.count - 1) + 12 > len(data):
        raise FileFormatError(path, f"accessor {index} runs past the end of its buffer",
                              offset=start)
    arr = np.ndarray((acc.count, 3), dtype="<f4", buffer=data, offset=start,
                     strides=(stride, 4))
    return arr.astype(np.float64)


def _buffer_bytes(gltf, path: Path, index: int) -> bytes:
    uri = gltf.buffers[index].uri
    if uri is None:
        blob = gltf.binary_blob()
        if blob is None:
            raise FileFormatError(path, f"buffer {index} has no data")
        return blob
    if uri.startswith("data:"):
        return gltf.decode_data_uri(uri)
    try:
        return (path.parent / uri).read_bytes()
    except OSError as exc:
        raise FileFormatError(path.parent / uri, f"cannot read glTF buffer: {exc.strerror}") \
            from None
