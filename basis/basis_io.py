"""Saving and loading a named expression basis.

Every basis of the project (an artist's shapes, a PCA model's components, a
quasi-eigen basis) is a set of named displacement fields (n, N, 3) on a
neutral mesh; :class:`basis.artist.ArtistBasis` is that common type. Build
one from another basis with ``ArtistBasis(qe.names, neutral, qe.displacements)``.

Two forms on disk, chosen by the path:

- ``*.npz``: one archive (see :func:`save_basis` for its keys);
- any other path: a directory with ``neutral.obj``, one OBJ per shape
  (neutral + displacement, the neutral's polygons kept, e.g. quads) and
  ``basis.json`` (format version, units, shape names in order and their file
  names). It reads back through :func:`basis.artist.load_artist_basis`, and
  so does any directory of OBJ files beside a ``neutral.obj``.
"""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

import numpy as np

from basis.artist import ArtistBasis, load_artist_basis
from mocap.errors import FileFormatError, InputError
from mocap.mesh.mesh import Mesh, save_obj
from mocap.util.atomic import atomic_path
from mocap.util.npz import read_npz, write_npz
from mocap.util.validation import as_choice

__all__ = ["BASIS_DTYPES", "save_basis", "load_basis", "load_any_basis", "shape_file_stems"]

#: Floating types :func:`save_basis` stores displacements in (npz form).
BASIS_DTYPES = ("float64", "float32")

_VERSION = 1
_MANIFEST = "basis.json"
_NEUTRAL = "neutral"
_NPZ_KEYS = ("format_version", "names", "units", "neutral_vertices", "faces",
             "face_polygon", "polygon_sizes", "displacements")
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]+")


def as_shape_names(names, n: int, *, against: str = "displacements",
                   reserved=()) -> tuple:
    """Validate shape names: n unique non-empty strings, none of `reserved`.

    Raises
    ------
    InputError
        One string instead of a sequence, no shapes, a count other than n
        (saying what `against` holds), an empty, duplicate or reserved name.
    """
    if isinstance(names, str):
        raise InputError("names must be a sequence of strings, not one string")
    names = tuple(names)
    if n == 0:
        raise InputError(f"{against} has no shapes")
    if len(names) != n:
        raise InputError(f"names has {len(names)} entries but {against} has {n} shapes")
    if not all(isinstance(x, str) and x for x in names):
        raise InputError("names must be non-empty strings")
    if len(set(names)) != n:
        dup = next(x for x in names if names.count(x) > 1)
        raise InputError(f"names must be unique: {dup!r} appears twice")
    bad = [x for x in names if x in reserved]
    if bad:
        raise InputError(f"shape name {bad[0]!r} is reserved (a column of the table)")
    return names


def shape_file_stems(names) -> tuple:
    """File stems for shape names: safe on every file system, unique, not ``neutral``.

    Characters other than letters, digits, ``_``, ``.`` and ``-`` become ``_``;
    leading dots are dropped; names equal without regard to case (or equal to
    ``neutral``) get a ``_2``, ``_3``, ... suffix in order of appearance.

    Parameters
    ----------
    names : sequence of str

    Returns
    -------
    tuple of str, one per name
    """
    stems, taken = [], {_NEUTRAL}
    for name in names:
        base = _UNSAFE.sub("_", str(name)).lstrip(".") or "shape"
        stem, k = base, 1
        while stem.lower() in taken:
            k += 1
            stem = f"{base}_{k}"
        taken.add(stem.lower())
        stems.append(stem)
    return tuple(stems)


def save_basis(basis: ArtistBasis, path, *, dtype: str = "float64", inputs=()) -> None:
    """Write a named basis as an ``.npz`` archive or as a directory of OBJ files.

    Parameters
    ----------
    basis : ArtistBasis
        Names, neutral Mesh (its units are recorded) and displacements (n, N, 3)
        in mesh units.
    path : str or os.PathLike
        ``*.npz`` for the archive, else a directory (created; an existing one
        is replaced only if :func:`save_basis` wrote it, i.e. it holds
        ``basis.json``).
    dtype : {"float64", "float32"}
        Storage of the npz displacements (float32 halves the file; ~1e-7
        relative). The neutral is always float64. The OBJ form prints 10
        significant digits of every vertex whatever `dtype`.
    inputs : iterable of path, optional
        Files never to replace (the neutral's own file is always protected).

    Notes
    -----
    npz keys: ``format_version`` (1), ``names`` (n, unicode), ``units`` ('' when
    unknown), ``neutral_vertices`` (N, 3) float64, ``faces`` (F, 3) int64,
    ``face_polygon`` (F,) and ``polygon_sizes`` (P,) int64 (the polygon map of
    :class:`mocap.mesh.mesh.Mesh`), ``displacements`` (n, N, 3) `dtype`. Written to
    a temporary file (directory) beside `path`, then renamed.

    Raises
    ------
    InputError
        Not an ArtistBasis, unknown `dtype`, `path` is an input or an existing
        file/directory that is not a saved basis, the directory cannot be written.
    """
    if not isinstance(basis, ArtistBasis):
        raise InputError(f"basis must be an ArtistBasis, got {type(basis).__name__}")
    dtype = as_choice(dtype, "dtype", BASIS_DTYPES)
    path = Path(path)
    inputs = [*inputs, basis.neutral.path]
    if path.suffix.lower() == ".npz":
        _save_npz(basis, path, dtype, inputs)
    else:
        _save_dir(basis, path, inputs)


def _save_npz(basis: ArtistBasis, path: Path, dtype: str, inputs) -> None:
    mesh = basis.neutral
    arrays = dict(format_version=np.int64(_VERSION), names=np.array(basis.names, dtype=str),
                  units=np.array(mesh.units or ""), neutral_vertices=mesh.vertices,
                  faces=mesh.faces, face_polygon=mesh.face_polygon,
                  polygon_sizes=mesh.polygon_sizes,
                  displacements=basis.displacements)
    with atomic_path(path, inputs=inputs) as tmp, open(tmp, "wb") as fh:
        write_npz(fh, arrays, store_as={"displacements": dtype})


def _save_dir(basis: ArtistBasis, path: Path, inputs) -> None:
    if path.exists():
        if not path.is_dir() or not (path / _MANIFEST).is_file():
            raise InputError(f"{path}: exists and is not a basis directory written by "
                             f"save_basis (no {_MANIFEST}); refusing to replace it")
        inside = [p for p in inputs if p is not None and Path(p).exists()
                  and Path(p).resolve().is_relative_to(path.resolve())]
        if inside:
            raise InputError(f"{path}: refusing to replace a directory holding the input "
                             f"{inside[0]}")
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    old = path.with_name(f".{path.name}.{os.getpid()}.old")
    stems = shape_file_stems(basis.names)
    mesh = basis.neutral
    try:
        tmp.mkdir()
        save_obj(mesh, tmp / f"{_NEUTRAL}.obj")
        for stem, disp in zip(stems, basis.displacements):
            save_obj(mesh.with_vertices(mesh.vertices + disp), tmp / f"{stem}.obj")
        manifest = {"format_version": _VERSION, "units": mesh.units,
                    "shapes": [{"name": n, "file": f"{s}.obj"}
                               for n, s in zip(basis.names, stems)]}
        (tmp / _MANIFEST).write_text(json.dumps(manifest, indent=1) + "\n", encoding="utf-8")
        if path.exists():
            os.replace(path, old)
        try:
            os.replace(tmp, path)
        except OSError:
            if old.exists():
                os.replace(old, path)  # put the previous basis back
            raise
    except OSError as exc:
        raise InputError(f"{path}: cannot write: {exc.strerror or exc}") from None
    finally:
        for leftover in (tmp, old):
            if leftover.exists():
                shutil.rmtree(leftover)


def load_basis(path, *, units: str | None = None) -> ArtistBasis:
    """Read a basis written by :func:`save_basis`.

    Parameters
    ----------
    path : str or os.PathLike
        An ``.npz`` archive, or a directory with ``neutral.obj`` and one OBJ per
        shape. Without ``basis.json`` every other ``*.obj`` is a shape, named by
        its file stem, in name order.
    units : str, optional
        Units of the mesh when the file does not record them (a recorded unit wins).

    Returns
    -------
    ArtistBasis
        Displacements as float64 (read-only), the neutral with its polygon map.

    Raises
    ------
    FileFormatError
        Missing or malformed keys, shapes inconsistent with the neutral, an
        unreadable manifest or OBJ (the file is named).
    InputError
        `path` neither an ``.npz`` file nor a directory.
    """
    path = Path(path)
    if path.suffix.lower() == ".npz" and path.is_file():
        return _load_npz(path, units)
    if path.is_dir():
        return _load_dir(path, units)
    raise InputError(f"{path}: a basis is an .npz file or a directory of OBJ files")


def _load_npz(path: Path, units) -> ArtistBasis:
    arrays = read_npz(path, "basis archive", required=_NPZ_KEYS,
                      version=("format_version", _VERSION))
    try:
        neutral = Mesh(arrays["neutral_vertices"], arrays["faces"], arrays["face_polygon"],
                       arrays["polygon_sizes"], units=str(arrays["units"]) or units,
                       path=str(path))
        return ArtistBasis(tuple(str(n) for n in arrays["names"]), neutral,
                           arrays["displacements"])
    except InputError as exc:
        raise FileFormatError(path, f"inconsistent basis: {exc}") from None


def _load_dir(path: Path, units) -> ArtistBasis:
    manifest_path = path / _MANIFEST
    if manifest_path.is_file():
        try:
            manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
            shapes = manifest["shapes"]
            names = [str(s["name"]) for s in shapes]
            stems = [str(Path(s["file"]).stem) for s in shapes]
            units = manifest.get("units") or units
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise FileFormatError(manifest_path, f"not a basis manifest: {exc!r}") from None
    else:
        stems = sorted(p.stem for p in path.glob("*.obj") if p.stem != _NEUTRAL)
        names = stems
    neutral_file = path / f"{_NEUTRAL}.obj"
    if not neutral_file.is_file():
        raise FileFormatError(neutral_file, "a basis directory needs its neutral mesh")
    loaded = load_artist_basis(neutral_file, path, names=stems, units=units)
    return ArtistBasis(tuple(names), loaded.neutral, loaded.displacements)


def load_any_basis(path, mesh: Mesh) -> ArtistBasis:
    """A basis on `mesh`'s topology from any form it comes in.

    Parameters
    ----------
    path : path
        A :func:`save_basis` archive (``.npz``) or directory (with
        ``basis.json``), a folder of OBJ shapes, or a glTF/GLB with morph
        targets (:func:`basis.artist.load_artist_basis`).
    mesh : Mesh
        The neutral mesh the basis must share a topology with; an archive's
        displacements are converted to its units.

    Returns
    -------
    ArtistBasis

    Raises
    ------
    InputError
        The basis has another vertex count than `mesh`.
    FileFormatError
        An unreadable basis.
    """
    path = Path(path)
    if path.suffix.lower() == ".npz" or (path / "basis.json").is_file():
        basis = load_basis(path, units=mesh.units)
    else:
        basis = load_artist_basis(mesh, path)
    if basis.neutral.n_vertices != mesh.n_vertices:
        raise InputError(f"{path}: the basis has {basis.neutral.n_vertices} vertices, the "
                         f"mesh {mesh.n_vertices}: they must share a topology")
    return basis
