"""Exports of a solved take: per-frame weights (CSV, DataFrame) and mesh sequences (npz).

Weights table: one row per frame, columns ``frame`` (the take's frame
numbers, from its first frame), ``time`` (s from the first frame,
``(frame − first_frame) / rate``, as :attr:`mocap.take.Take.times`) and one
column per shape. Mesh sequence: an ``.npz`` archive, float32, either compact
(neutral + basis + weights, evaluated on demand) or materialized
(vertices of every frame); see :func:`write_mesh_sequence`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from basis.basis_io import as_shape_names
from fit.solve.weights import WeightSolution
from mocap.errors import FileFormatError, InputError
from mocap.mesh.mesh import Mesh
from mocap.util.atomic import atomic_path
from mocap.util.float_text import write_csv_lines
from mocap.util.npz import NotFiniteError, read_npz, write_npz
from mocap.util.validation import as_float_array, as_int, as_positive_float, surely_finite

__all__ = ["weights_frame", "write_weights_csv", "read_weights_csv", "MeshSequence",
           "write_mesh_sequence", "read_mesh_sequence"]

#: Frames evaluated per matrix product when materializing a sequence.
_CHUNK_FRAMES = 256
_SEQ_VERSION = 1
#: The leading columns of a weights table.
_COLUMNS = ("frame", "time")


def _weights(weights, n_names: int | None = None, *, copy: bool = True,
             check_finite: bool = True) -> np.ndarray:
    """Weights (T, n) float64 from an array or a WeightSolution (a float64 array is not
    copied with ``copy=False``); NaN and infinite values rejected (unless not
    `check_finite`, for a caller that checks them as it writes them)."""
    if isinstance(weights, WeightSolution):
        weights = weights.weights
    weights = as_float_array(weights, "weights", shape=(None, n_names), copy=copy,
                             check_finite=False)
    if check_finite and not surely_finite(weights):     # one pass when all are finite
        as_float_array(weights, "weights", copy=False)  # refuses infinite values
        bad = np.argwhere(np.isnan(weights))
        if len(bad):
            raise InputError(f"weights contain NaN ({len(np.unique(bad[:, 0]))} frames, first "
                             f"at frame index {bad[0, 0]}, shape {bad[0, 1]}): an export "
                             "needs every frame solved")
    return weights


def weights_frame(weights, names, *, rate: float, first_frame: int = 1) -> pd.DataFrame:
    """Per-frame weights as a DataFrame.

    Parameters
    ----------
    weights : array_like of shape (T, n) or WeightSolution
        Dimensionless weights. No NaN.
    names : sequence of str, length n
        Shape names (column names).
    rate : float
        Frame rate, Hz.
    first_frame : int, default 1
        Frame number of the first row (the take's ``first_frame``).

    Returns
    -------
    DataFrame
        Index ``frame`` (int64), columns ``time`` (s) then the shape names (float64).
    """
    frames, cells, names = _weights_table(weights, names, rate=rate, first_frame=first_frame)
    return pd.DataFrame(cells, columns=["time", *names], index=pd.Index(frames, name="frame"),
                        copy=False)


def _weights_table(weights, names, *, rate: float, first_frame: int) -> tuple:
    """:func:`weights_frame`'s frame numbers (T,) int64, its cells (T, 1 + n) float64
    (the times, then the weights: one new array) and the shape names, checked."""
    weights = _weights(weights, copy=False)             # only read, into the new cells
    names = list(as_shape_names(names, weights.shape[1], against="weights",
                                reserved=_COLUMNS))
    rate = as_positive_float(rate, "rate")
    first_frame = as_int(first_frame, "first_frame")
    cells = np.empty((len(weights), 1 + weights.shape[1]))
    cells[:, 0] = np.arange(len(weights)) / rate
    cells[:, 1:] = weights
    return first_frame + np.arange(len(weights), dtype=np.int64), cells, names


def write_weights_csv(path, weights, names, *, rate: float, first_frame: int = 1,
                      inputs=()) -> None:
    """Write per-frame weights as CSV: ``frame,time,<name>,...``, one row per frame.

    Parameters are those of :func:`weights_frame`, plus the output `path`
    (written atomically; never over one of `inputs`). Floats are written with
    the shortest repr that reads back exactly (:mod:`mocap.util.float_text`).

    Raises
    ------
    InputError
        Shapes, names or NaN as in :func:`weights_frame`; the file cannot be written.
    """
    frames, cells, names = _weights_table(weights, names, rate=rate, first_frame=first_frame)
    header = pd.DataFrame(columns=[*_COLUMNS, *names]).to_csv(  # quoted as needed
        index=False, lineterminator="\n")
    with atomic_path(path, inputs=inputs) as tmp, open(tmp, "wb") as fh:
        fh.write(header.encode("utf-8"))
        write_csv_lines(fh, frames, cells)


def read_weights_csv(path) -> pd.DataFrame:
    """Read a weights CSV written by :func:`write_weights_csv`.

    Returns
    -------
    DataFrame
        As :func:`weights_frame`: index ``frame``, columns ``time`` and shapes.

    Raises
    ------
    FileFormatError
        Unreadable file, no ``frame``/``time`` columns, non-numeric or empty
        cells (the line is named), frames not consecutive.
    """
    path = Path(path)
    try:  # cells as text, parsed by numpy: correctly rounded whatever the pandas version
        table = pd.read_csv(path, index_col=None, dtype=str, keep_default_na=False)
    except (OSError, ValueError, pd.errors.ParserError) as exc:
        raise FileFormatError(path, f"cannot read weights CSV: {exc}") from None
    if tuple(table.columns[:2]) != _COLUMNS:
        raise FileFormatError(path, "expected the columns frame, time, then one per shape; "
                                    f"got {', '.join(map(str, table.columns[:3]))}", line=1)
    cells = table.to_numpy(dtype=str)
    try:
        numbers = cells.astype(np.float64)
    except ValueError:
        numbers = table.apply(pd.to_numeric, errors="coerce").to_numpy(dtype=np.float64)
    bad = np.argwhere(~np.isfinite(numbers))
    if len(bad):
        row, col = bad[0]
        raise FileFormatError(path, f"column {table.columns[col]!r}: {str(cells[row, col])!r} is "
                                    "empty or not a finite number", line=int(row) + 2)
    values = pd.DataFrame(numbers, columns=table.columns)
    frames = values["frame"].to_numpy()
    if np.any(frames != np.round(frames)) or np.any(np.diff(frames) <= 0):
        raise FileFormatError(path, "frame numbers must be increasing integers")
    values.index = pd.Index(frames.astype(np.int64), name="frame")
    return values.drop(columns="frame").astype(np.float64)


@dataclass(frozen=True, eq=False)
class MeshSequence:
    """A mesh sequence read from an ``.npz`` written by :func:`write_mesh_sequence`.

    Attributes
    ----------
    faces : ndarray of shape (F, 3), int64
        Triangles of every frame.
    neutral : ndarray of shape (N, 3), float32, or None
        v0 (compact form), mesh units.
    displacements : ndarray of shape (n, N, 3), float32, or None
        Basis e_i (compact form), mesh units.
    weights : ndarray of shape (T, n), float32, or None
        w_t (compact form).
    materialized : ndarray of shape (T, N, 3), float32, or None
        Every frame's vertices (materialized form), mesh units.
    names : tuple of str
        Shape names, empty when none were given.
    units : str or None
    rate : float or None
        Frame rate, Hz, when recorded.
    first_frame : int
        The capture's frame number of the first frame.
    rotation : ndarray of shape (T, 3, 3), or None
        Head motion of the mesh, when recorded: vertex v of frame t is placed at
        ``rotation[t] @ v + translation[t]`` (what the glTF node does).
    translation : ndarray of shape (T, 3), mesh units, or None
    """

    faces: np.ndarray
    neutral: np.ndarray | None
    displacements: np.ndarray | None
    weights: np.ndarray | None
    materialized: np.ndarray | None
    names: tuple
    units: str | None
    rate: float | None
    first_frame: int
    rotation: np.ndarray | None = None
    translation: np.ndarray | None = None

    def __post_init__(self):
        for arr in (self.faces, self.neutral, self.displacements, self.weights,
                    self.materialized, self.rotation, self.translation):
            if arr is not None:
                arr.flags.writeable = False

    @property
    def n_frames(self) -> int:
        """Number of frames T."""
        return len(self.materialized if self.materialized is not None else self.weights)

    def vertices(self, t=None) -> np.ndarray:
        """Vertices of frame(s) `t`: v(t) = v0 + Σ_i w_ti e_i, in float64.

        Parameters
        ----------
        t : int, slice or array_like of int, optional
            0-based frame indices (not frame numbers); all frames if None.

        Returns
        -------
        ndarray of shape (N, 3) for an int, (T', N, 3) otherwise; mesh units.
        """
        index = slice(None) if t is None else t
        if self.materialized is not None:
            return self.materialized[index].astype(np.float64)
        w = self.weights[index].astype(np.float64)
        basis = self.displacements.reshape(len(self.displacements), -1).astype(np.float64)
        out = (np.atleast_2d(w) @ basis).reshape(-1, *self.neutral.shape) + self.neutral
        return out[0] if w.ndim == 1 else out

    def placed_vertices(self, t=None) -> np.ndarray:
        """:meth:`vertices` moved by the recorded head motion, mesh units (unmoved without one)."""
        out = self.vertices(t)
        if self.rotation is None:
            return out
        index = slice(None) if t is None else t
        rotation, translation = (np.asarray(a, dtype=np.float64)[index]
                                 for a in (self.rotation, self.translation))
        return np.einsum("...ij,...vj->...vi", rotation, out) + translation[..., None, :]


def write_mesh_sequence(path, neutral: Mesh, displacements, weights, *,
                        materialize: bool = False, names=None, rate: float | None = None,
                        first_frame: int = 1, rotation=None, translation=None,
                        inputs=()) -> None:
    """Write the reconstructed mesh sequence v(t) = v0 + Σ_i w_ti e_i as float32 ``.npz``.

    Parameters
    ----------
    path : str or os.PathLike
        Output ``.npz``, written atomically, never over one of `inputs` or the
        neutral's file.
    neutral : Mesh
        v0 (N vertices, mesh units) and the faces.
    displacements : array_like of shape (n, N, 3), mesh units
        The basis e_i. No NaN.
    weights : array_like of shape (T, n) or WeightSolution
        No NaN.
    materialize : bool, default False
        False: store ``neutral`` (N, 3), ``displacements`` (n, N, 3) and
        ``weights`` (T, n), ~T/(3N) of the size. True: store ``vertices``
        (T, N, 3), evaluated in float64 by chunks of frames, then rounded.
    names : sequence of str, optional
        Shape names, stored with either form.
    rate : float, optional
        Frame rate, Hz, stored when given.
    first_frame : int, default 1
        The capture's frame number of the first row of `weights`.
    rotation : array_like of shape (T, 3, 3), optional
        Head motion (with `translation`): frame t is placed at
        ``rotation[t] @ v + translation[t]``, stored in float64.
    translation : array_like of shape (T, 3), mesh units, optional

    Notes
    -----
    Keys: ``format_version``, ``faces`` (F, 3) int64, ``units`` ('' if
    unknown), ``rate`` (NaN if unknown), ``first_frame``, ``names``, and the
    arrays of the chosen form, and ``rotation``/``translation`` with a head
    motion. Read back with :func:`read_mesh_sequence`, or
    with numpy: ``v = z["neutral"] + np.tensordot(z["weights"][t],
    z["displacements"], 1)``.

    Raises
    ------
    InputError
        Inconsistent shapes, NaN, names count, values (or materialized
        vertices) beyond the range of float32, the file cannot be written.
    """
    if not isinstance(neutral, Mesh):
        raise InputError(f"neutral must be a Mesh, got {type(neutral).__name__}")
    # not copied; the compact form's values are checked as they are written (as float32)
    displacements = as_float_array(displacements, "displacements", copy=False,
                                   shape=(None, neutral.n_vertices, 3), allow_nan=False,
                                   check_finite=materialize)
    weights = _weights(weights, len(displacements), copy=False, check_finite=materialize)
    names = () if names is None else as_shape_names(names, len(displacements))
    rate = np.nan if rate is None else as_positive_float(rate, "rate")
    arrays = dict(format_version=np.int64(_SEQ_VERSION), faces=neutral.faces,
                  units=np.array(neutral.units or ""), rate=np.float64(rate),
                  first_frame=np.int64(as_int(first_frame, "first_frame")),
                  names=np.array(names, dtype=str))
    store_as = {}       # members stored rounded to float32, as they are written
    if (rotation is None) != (translation is None):
        raise InputError("rotation and translation go together (the head motion)")
    if rotation is not None:
        arrays.update(      # only read: not copied
            rotation=as_float_array(rotation, "rotation", shape=(len(weights), 3, 3),
                                    allow_nan=False, copy=False),
            translation=as_float_array(translation, "translation", shape=(len(weights), 3),
                                       allow_nan=False, copy=False))
    if materialize:
        flat = displacements.reshape(len(displacements), -1)
        out = np.empty((len(weights), neutral.n_vertices, 3), dtype=np.float32)
        # rounded once, on store; beyond float32's range they become inf, which the
        # writer's finite check refuses
        with np.errstate(over="ignore"):
            for start in range(0, len(weights), _CHUNK_FRAMES):  # chunks, not frames
                chunk = weights[start:start + _CHUNK_FRAMES] @ flat
                np.add(chunk.reshape(-1, neutral.n_vertices, 3), neutral.vertices,
                       out=out[start:start + _CHUNK_FRAMES])
        arrays["vertices"] = out
    else:
        arrays.update(neutral=neutral.vertices, displacements=displacements, weights=weights)
        store_as.update(neutral=np.float32, displacements=np.float32, weights=np.float32)
    try:
        with atomic_path(path, inputs=[*inputs, neutral.path]) as tmp, open(tmp, "wb") as fh:
            write_npz(fh, arrays, store_as=store_as,
                      finite=("displacements", "weights", "vertices"))
    except NotFiniteError as exc:     # the exact checks name the first bad value
        as_float_array(displacements, "displacements", copy=False, allow_nan=False)
        _weights(weights, copy=False)
        raise InputError(f"{exc.member} hold values beyond the range of float32 (±3.4e38), "
                         "in which the sequence stores them") from None


def read_mesh_sequence(path) -> MeshSequence:
    """Read a mesh sequence written by :func:`write_mesh_sequence`.

    Raises
    ------
    FileFormatError
        Unreadable archive, missing keys, inconsistent shapes.
    """
    path = Path(path)
    z = read_npz(path, "mesh sequence")
    compact = ("neutral", "displacements", "weights")
    need = ["faces", "units", "rate", "first_frame", "names"]
    need += ["vertices"] if "vertices" in z else list(compact)
    absent = [k for k in need if k not in z]
    if absent:
        raise FileFormatError(path, f"not a mesh sequence: members {', '.join(absent)} missing")
    if "vertices" in z:
        n_vertices, consistent = z["vertices"].shape[1:2], z["vertices"].ndim == 3
    else:
        neutral, disp, w = (z[k] for k in compact)
        n_vertices = neutral.shape[:1]
        consistent = (neutral.ndim == 2 and disp.shape[1:] == neutral.shape
                      and w.ndim == 2 and w.shape[1] == len(disp))
    faces = z["faces"]
    if not consistent or faces.ndim != 2 or (faces.size and faces.max() >= n_vertices[0]):
        raise FileFormatError(path, "inconsistent shapes of vertices, basis, weights or faces")
    rate = float(z["rate"])
    n_frames = len(z["vertices"] if "vertices" in z else z["weights"])
    motion = [z.get(k) for k in ("rotation", "translation")]
    if (motion[0] is None) != (motion[1] is None) or (
            motion[0] is not None and (motion[0].shape != (n_frames, 3, 3)
                                       or motion[1].shape != (n_frames, 3))):
        raise FileFormatError(path, f"the head motion must be rotation ({n_frames}, 3, 3) and "
                                    f"translation ({n_frames}, 3)")
    return MeshSequence(faces=faces, neutral=z.get("neutral"),
                        displacements=z.get("displacements"), weights=z.get("weights"),
                        materialized=z.get("vertices"),
                        names=tuple(str(n) for n in z["names"]),
                        units=str(z["units"]) or None,
                        rate=None if np.isnan(rate) else rate,
                        first_frame=int(z["first_frame"]), rotation=motion[0],
                        translation=motion[1])
