"""Heat-method fields kept for the next geodesics on the same mesh.

A field depends on the mesh, the heat method's options and its source vertex only. The
takes of a session are bound to one mesh by one marker set, so their markers' faces,
whose corners are the sources of the retargeting's geodesic fields, are mostly the same
from take to take: the fields one take solved serve the next one in the same process
(a session run one take after another, a Dask worker's takes, a script's loop over
takes), the same bits without a solve.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict

import numpy as np

__all__ = ["FieldCache", "mesh_key", "FIELD_CACHE_BYTES"]

#: Bytes of fields a process keeps, at most: the 180 fields of 60 markers' faces on a mesh
#: of up to about 40,000 vertices. The fields of the meshes used least recently go first.
FIELD_CACHE_BYTES = 64 << 20


def mesh_key(vertices: np.ndarray, faces: np.ndarray, options: tuple) -> bytes:
    """What a mesh's fields depend on: a digest of its vertices, faces and the heat
    method's options."""
    digest = hashlib.blake2b(digest_size=20)
    for array in (vertices, faces):
        digest.update(repr((array.dtype.str, array.shape)).encode())
        digest.update(np.ascontiguousarray(array).data)
    digest.update(repr(options).encode())
    return digest.digest()


class FieldCache:
    """Fields by mesh (:func:`mesh_key`) and source vertex, up to `max_bytes` (0: none
    kept); safe to share between threads.

    Parameters
    ----------
    max_bytes : int
    """

    def __init__(self, max_bytes: int):
        self.max_bytes = int(max_bytes)
        self._meshes: OrderedDict = OrderedDict()      # key: {vertex: field}, oldest first
        self._bytes = 0
        self._lock = threading.Lock()

    def take(self, key: bytes, sources) -> dict:
        """The kept fields of those of the vertices `sources` that have one, by vertex:
        read-only arrays (N,)."""
        with self._lock:
            fields = self._meshes.get(key)
            if fields is None:
                return {}
            self._meshes.move_to_end(key)
            return {vertex: fields[vertex] for vertex in map(int, sources) if vertex in fields}

    def keep(self, key: bytes, sources, rows: np.ndarray) -> None:
        """Keep the fields `rows` (S, N) of the vertices `sources` (S,), as far as the
        bound allows once the fields of the meshes used least recently are dropped."""
        if not len(rows) or rows[0].nbytes > self.max_bytes:
            return
        with self._lock:
            fields = self._meshes.setdefault(key, {})
            self._meshes.move_to_end(key)
            for vertex, row in zip(map(int, sources), rows):
                if vertex not in fields:
                    fields[vertex] = row = row.copy()   # apart from the caller's array
                    row.flags.writeable = False
                    self._bytes += row.nbytes
            while self._bytes > self.max_bytes:
                oldest = next(iter(self._meshes.values()))
                self._bytes -= oldest.pop(next(iter(oldest))).nbytes
                if not oldest:
                    self._meshes.popitem(last=False)

    @property
    def nbytes(self) -> int:
        """Bytes of the fields kept."""
        return self._bytes

    def clear(self) -> None:
        """Drop every field."""
        with self._lock:
            self._meshes.clear()
            self._bytes = 0
