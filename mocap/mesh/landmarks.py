"""Mesh landmarks: anatomical points of a face mesh, by vertex id.

A mesh-landmark file is a small TOML file::

    mesh = "ICT-FaceKit generic_neutral_mesh.obj"   # optional, free text
    n_vertices = 9409                              # optional, checked when given
    [landmarks]                # anatomical point (mocap.anatomy) = 0-based vertex id
    mouth_corner_left = 6213
    nose_tip = 4857
    [open_questions]           # optional; a file with a question in it is refused

Left and right are the subject's own. A mesh landmark meets the marker-set
landmark of the same name when markers are bound to the mesh
(:func:`mocap.bind.bind_markers`).
"""

from __future__ import annotations

import numbers
from pathlib import Path
from typing import Mapping

from mocap.anatomy import ANATOMICAL_POINTS
from mocap.errors import FileFormatError, InputError
from mocap.mesh.mesh import Mesh
from mocap.util.toml import check_open_questions, read_toml

__all__ = ["load_mesh_landmarks", "check_mesh_landmarks"]

_KEYS = {"mesh", "n_vertices", "landmarks", "description", "open_questions"}


def check_mesh_landmarks(landmarks: Mapping, n_vertices: int | None = None, *,
                         where: str = "mesh landmarks") -> dict[str, int]:
    """Validate a mapping of anatomical point to vertex id.

    Parameters
    ----------
    landmarks : mapping of str to int
        Anatomical point name (:data:`mocap.anatomy.ANATOMICAL_POINTS`) to a
        0-based vertex id.
    n_vertices : int, optional
        Vertex count of the mesh the ids index, to check their range.
    where : str
        What the landmarks came from, for error messages.

    Returns
    -------
    dict of str to int
        A new dict, in the order given.

    Raises
    ------
    InputError
        Unknown anatomical point, non-integer or out-of-range vertex id.
    """
    if not isinstance(landmarks, Mapping):
        raise InputError(f"{where}: landmarks must be a mapping of anatomical point to "
                         f"vertex id, got {type(landmarks).__name__}")
    out = {}
    for point, vertex in landmarks.items():
        if point not in ANATOMICAL_POINTS:
            raise InputError(f"{where}: unknown anatomical point {point!r}; known: "
                             f"{', '.join(ANATOMICAL_POINTS)}")
        if isinstance(vertex, bool) or not isinstance(vertex, numbers.Integral):
            raise InputError(f"{where}: landmark {point!r} must be a vertex id (integer), "
                             f"got {vertex!r}")
        if vertex < 0 or (n_vertices is not None and vertex >= n_vertices):
            limit = f"0..{n_vertices - 1}" if n_vertices is not None else ">= 0"
            raise InputError(f"{where}: landmark {point!r} is vertex {vertex}, out of range "
                             f"({limit})")
        out[point] = int(vertex)
    return out


def load_mesh_landmarks(path, mesh: Mesh | int | None = None) -> dict[str, int]:
    """Read a mesh-landmark TOML file.

    Parameters
    ----------
    path : str or os.PathLike
    mesh : Mesh or int, optional
        The mesh (or its vertex count) the landmarks index; vertex ids and the
        file's ``n_vertices`` are checked against it.

    Returns
    -------
    dict of str to int
        Anatomical point name to 0-based vertex id, in file order.

    Raises
    ------
    FileFormatError
        Unreadable TOML, unknown keys, an unknown anatomical point, a vertex id
        that is not an integer or out of range, ``n_vertices`` different from
        the mesh's, an open question (``[open_questions]``, written by
        ``mocap2mesh init``) not answered.
    """
    path = Path(path)
    doc = read_toml(path, "mesh landmarks")
    unknown = set(doc) - _KEYS
    if unknown:
        raise FileFormatError(path, f"unknown keys {sorted(unknown)}; expected {sorted(_KEYS)}")
    check_open_questions(doc, path, "mesh-landmark file")
    n_vertices = mesh.n_vertices if isinstance(mesh, Mesh) else mesh
    stated = doc.get("n_vertices")
    if stated is not None:
        if isinstance(stated, bool) or not isinstance(stated, int) or stated < 1:
            raise FileFormatError(path, f"n_vertices must be a positive integer, got {stated!r}")
        if n_vertices is not None and stated != n_vertices:
            raise FileFormatError(path, f"written for a mesh of {stated} vertices, but the mesh "
                                        f"has {n_vertices}")
        n_vertices = stated
    landmarks = doc.get("landmarks")
    if not isinstance(landmarks, dict) or not landmarks:
        raise FileFormatError(path, "needs a non-empty [landmarks] table of "
                                    "anatomical point = vertex id")
    try:
        return check_mesh_landmarks(landmarks, n_vertices, where="[landmarks]")
    except InputError as exc:
        raise FileFormatError(path, str(exc)) from None
