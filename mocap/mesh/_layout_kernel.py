"""The marker layout's placement as one compiled loop (numba, the ``speed`` extra).

:meth:`mocap.mesh.layout.MarkerLayout._place` in NumPy takes about 25 calls a pass (sparse
edge products, cross products, corner sums, two normalizations, interpolation), each a
pass over arrays of a few hundred KB; this does the same arithmetic, in the same order,
frame by frame in one loop without the GIL: the same positions, bit for bit, for two
frames or more (for one, NumPy's products take other paths and may round differently in
the last bit). The marker-centre fit evaluates it several times a frame.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["place_markers"]


@numba.njit(cache=True, nogil=True)
def place_markers(near, faces, face_start, face_corners, n_corners, slot, local, bary,
                  offsets, offset, out):  # pragma: no cover - compiled; tested against NumPy
    """Marker positions into `out` (B, M, 3) from the needed vertices `near` (3, K, B).

    `faces` (Fs, 3) are the faces around the marker corners in local vertex ids;
    `face_start` and `face_corners` list the marker corners of each face (CSR, rows of
    the `n_corners` corner normals); `slot`, `local` and `bary` (M, 3) give each
    marker's corners (rows of the corner normals), their local vertex ids and its
    barycentric weights; `offsets` (M,) its distance along the normal, added where
    nonzero when `offset`. Each face's normal is added to its corners' as it is made
    (no array of all the face normals): a corner sums its faces in their order, as the
    NumPy path's sparse product does.
    """
    n_frames = near.shape[2]
    n_markers = len(offsets)
    if offset:
        normals = np.zeros((3, n_corners, n_frames))
        cross = np.empty((3, n_frames))
        for f in range(len(faces)):
            a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
            for t in range(n_frames):
                ux = near[0, b, t] - near[0, a, t]
                uy = near[1, b, t] - near[1, a, t]
                uz = near[2, b, t] - near[2, a, t]
                vx = near[0, c, t] - near[0, a, t]
                vy = near[1, c, t] - near[1, a, t]
                vz = near[2, c, t] - near[2, a, t]
                cross[0, t] = uy * vz - uz * vy
                cross[1, t] = uz * vx - ux * vz
                cross[2, t] = ux * vy - uy * vx
            for k in range(face_start[f], face_start[f + 1]):
                corner = face_corners[k]
                for t in range(n_frames):
                    normals[0, corner, t] += cross[0, t]
                    normals[1, corner, t] += cross[1, t]
                    normals[2, corner, t] += cross[2, t]
        for corner in range(n_corners):
            for t in range(n_frames):
                x, y, z = normals[0, corner, t], normals[1, corner, t], normals[2, corner, t]
                length = np.sqrt(x * x + y * y + z * z)
                if length > 0:
                    normals[0, corner, t] = x / length
                    normals[1, corner, t] = y / length
                    normals[2, corner, t] = z / length
    for m in range(n_markers):
        for t in range(n_frames):
            px, py, pz = _interpolated(near, local, bary, m, t)
            if offset and offsets[m] != 0:
                ax, ay, az = _interpolated(normals, slot, bary, m, t)
                length = np.sqrt(ax * ax + ay * ay + az * az)
                if not length > 0:
                    length = 1.0
                px += offsets[m] * (ax / length)
                py += offsets[m] * (ay / length)
                pz += offsets[m] * (az / length)
            out[t, m, 0] = px
            out[t, m, 1] = py
            out[t, m, 2] = pz


@numba.njit(cache=True, nogil=True, inline="always")
def _interpolated(values, rows, bary, m, t):  # pragma: no cover - compiled
    """``Σ_k bary[m, k] values[:, rows[m, k], t]``, k in order, as (x, y, z)."""
    x = y = z = 0.0
    for k in range(3):
        row, weight = rows[m, k], bary[m, k]
        x += values[0, row, t] * weight
        y += values[1, row, t] * weight
        z += values[2, row, t] * weight
    return x, y, z
