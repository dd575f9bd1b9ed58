"""Retargeted takes on disk: the ``.npz`` archive of ``mocap2mesh retarget`` and OBJ sequences.

Writers stream a :class:`~mocap.retarget.retargeting.Retargeting` chunk by
chunk (the mesh sequence is never whole in memory); :class:`ArchiveFrames`
reads archives back chunk by chunk, for a PCA of their frames.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from mocap.errors import FileFormatError, InputError
from mocap.mesh.mesh import save_obj
from mocap.retarget.retargeting import Retargeting
from mocap.util.atomic import atomic_path, refuse_overwrite
from mocap.util.validation import as_choice

__all__ = ["CONTENTS", "save_npz", "save_obj_sequence", "is_retargeted_archive",
           "ArchiveFrames"]

#: What a ``.npz`` archive holds per frame: vertex displacements from the neutral, or positions.
CONTENTS = ("vertices", "displacements")


def save_npz(result: Retargeting, path, *, content: str = "vertices", inputs=()) -> None:
    """Stream a retargeted take to an uncompressed ``.npz``, chunk by chunk, atomically.

    Arrays: ``vertices`` or ``displacements`` (T, N, 3) float32 mesh units
    (by `content`), ``neutral`` (N, 3) float32, ``faces`` (F, 3) int64,
    ``rate`` (Hz), ``first_frame``, ``labels`` (M,) and ``marker_displacements``
    (T, M, 3) float32. Only one chunk of frames is in memory at a time: the
    big array is written straight into the archive member.
    """
    content = as_choice(content, "content", CONTENTS)
    neutral = result.mesh.vertices.astype(np.float32)
    shape = (result.n_frames, result.mesh.n_vertices, 3)
    header = {"descr": np.lib.format.dtype_to_descr(np.dtype("<f4")),
              "fortran_order": False, "shape": shape}
    small = {"neutral": neutral, "faces": result.mesh.faces.astype(np.int64),
             "rate": np.array(result.rate), "first_frame": np.array(result.first_frame),
             "labels": np.array(result.labels, dtype=str),
             "marker_displacements": result.displacements.astype(np.float32)}
    with atomic_path(path, inputs=inputs) as tmp:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED) as archive:
            with archive.open(f"{content}.npy", "w", force_zip64=True) as member:
                np.lib.format.write_array_header_2_0(member, header)
                for _, block in result.iter_chunks(dtype=np.float32):
                    if content == "vertices":
                        block += neutral
                    member.write(np.ascontiguousarray(block, dtype="<f4").data)
            for name, arr in small.items():
                with archive.open(f"{name}.npy", "w") as member:
                    np.lib.format.write_array(member, arr, allow_pickle=False)


def save_obj_sequence(result: Retargeting, directory, *, stem: str = "frame",
                      inputs=()) -> list[Path]:
    """Write one OBJ per frame into `directory` (created if needed), atomically per file.

    Files are ``{stem}_{frame number:0Nd}.obj`` with the take's frame numbers,
    zero-padded to the widest; faces as in the neutral mesh's file (quads kept).
    Returns the paths written, in frame order.
    """
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise InputError(f"{directory}: exists and is not a directory (an OBJ sequence "
                         "is written into a directory)")
    refuse_overwrite(directory, inputs)
    directory.mkdir(parents=True, exist_ok=True)
    last = result.first_frame + result.n_frames - 1
    width = max(4, len(str(last)))
    neutral = result.mesh.vertices
    paths = []
    for frames, block in result.iter_chunks(dtype=np.float64):
        for offset, disp in enumerate(block):         # one file per frame: I/O bound
            path = directory / f"{stem}_{result.first_frame + frames.start + offset:0{width}d}.obj"
            save_obj(result.mesh.with_vertices(neutral + disp), path, inputs=inputs)
            paths.append(path)
    return paths


def is_retargeted_archive(path) -> bool:
    """Whether `path` is a ``.npz`` archive written by :func:`save_npz`."""
    path = Path(path)
    if path.suffix.lower() != ".npz" or not zipfile.is_zipfile(path):
        return False
    with zipfile.ZipFile(path) as archive:
        members = set(archive.namelist())
    return "marker_displacements.npy" in members and \
        any(f"{key}.npy" in members for key in CONTENTS)


def _npy_header(member):
    """(shape, fortran_order, dtype) of an open ``.npy`` stream, left at the data."""
    version = np.lib.format.read_magic(member)
    read = np.lib.format.read_array_header_1_0 if version == (1, 0) \
        else np.lib.format.read_array_header_2_0
    return read(member)


class ArchiveFrames:
    """Vertex displacements (t, N, 3) float64 of retargeted archives, chunk by chunk.

    Re-iterable (each pass reopens the files), as :func:`basis.pca.pca_streaming`
    asks; only one chunk of one archive is in memory at a time.

    Parameters
    ----------
    paths : sequence of path
        Archives of :func:`save_npz` (``vertices`` or ``displacements``), read
        in this order, their frames pooled.
    n_vertices : int
        N of the neutral mesh; an archive of another mesh is rejected.
    chunk_frames : int, default 512
        Frames per chunk.

    Attributes
    ----------
    n_frames : int
        Frames of all archives.
    n_markers : int
        Most markers an archive was retargeted from.

    Raises
    ------
    FileFormatError
        An archive of another vertex count, or whose frames are not a C-order
        (T, N, 3) array.
    """

    def __init__(self, paths, n_vertices: int, chunk_frames: int = 512):
        self.paths, self.chunk_frames = list(paths), chunk_frames
        self.n_frames, self.n_markers = 0, 0
        for path in self.paths:
            key, shape, _ = self._header(path)
            if shape[1:] != (n_vertices, 3):
                raise FileFormatError(path, f"{key} has shape {shape}: the neutral mesh has "
                                            f"{n_vertices} vertices (retargeted onto another "
                                            "mesh?)")
            with np.load(path) as archive:
                self.n_markers = max(self.n_markers, archive["labels"].shape[0])
            self.n_frames += shape[0]

    @staticmethod
    def _header(path: Path):
        with zipfile.ZipFile(path) as archive:
            key = next(k for k in CONTENTS if f"{k}.npy" in archive.namelist())
            with archive.open(f"{key}.npy") as member:
                shape, fortran, dtype = _npy_header(member)
        if fortran or len(shape) != 3:
            raise FileFormatError(path, f"{key}.npy must be a C-order (T, N, 3) array")
        return key, shape, dtype

    def __iter__(self):
        for path in self.paths:
            key, shape, dtype = self._header(path)
            with np.load(path) as archive:
                neutral = archive["neutral"].astype(np.float64) if key == "vertices" else 0.0
            frame_bytes = dtype.itemsize * shape[1] * 3
            with zipfile.ZipFile(path) as archive, archive.open(f"{key}.npy") as member:
                _npy_header(member)
                for start in range(0, shape[0], self.chunk_frames):
                    count = min(self.chunk_frames, shape[0] - start)
                    raw = member.read(count * frame_bytes)
                    block = np.frombuffer(raw, dtype=dtype).reshape(count, shape[1], 3)
                    yield block.astype(np.float64) - neutral
