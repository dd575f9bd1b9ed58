"""The z-buffer's scan conversion as one compiled loop (numba, the ``speed`` extra).

:func:`mocap.viz._raster.rasterize` in NumPy expands every (triangle, row) pair into its
span of fragments (index arrays of every fragment's pixel, depth and triangle, made
by ``np.repeat``) and merges them by a scatter-max, about ten passes over arrays of all
the fragments. This walks the same triangles, rows and pixels in the same order, with the
same arithmetic, and keeps each pixel's nearest fragment as it goes: the same z-buffer
and the same triangle at every pixel, bit for bit.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["scan_triangles"]


@numba.njit(cache=True, nogil=True)
def scan_triangles(live, y, a, u, v, za, zu, zv, width, height, x_eps, edge_eps, zbuf,
                   fbuf):  # pragma: no cover - compiled; tested against NumPy
    """Draw the triangles `live` (in order) into the z-buffer, in place.

    Parameters
    ----------
    live : ndarray of int, shape (L,)
        The triangles to draw, in the order their fragments are merged.
    y : ndarray of shape (3, F)
        Image rows of each triangle's corners, pixels.
    a, u, v : ndarray of shape (3, F)
        Barycentric coordinate i of a triangle at (x, y) is ``a[i] + u[i] x + v[i] y``.
    za, zu, zv : ndarray of shape (F,)
        Its depth is ``za + zu x + zv y``.
    width, height : int
        Image size, pixels.
    x_eps, edge_eps : float
        Slack of the span ends and of a coordinate constant along a row
        (:data:`mocap.viz._raster._X_EPS`, :data:`~mocap.viz._raster._EDGE_EPS`).
    zbuf : ndarray of shape (H * W,)
        Depth of the nearest fragment of each pixel (``-inf`` for none), updated.
    fbuf : ndarray of int, shape (H * W,)
        Its triangle (-1 for none), updated: of fragments at the same depth, the last.
    """
    for t in live:
        # rows clamped to the image before they become integers (as NumPy's): a vertex far
        # off it would overflow int64
        top = min(min(y[0, t], y[1, t]), y[2, t])
        bottom = max(max(y[0, t], y[1, t]), y[2, t])
        first_row = np.int64(min(max(np.ceil(top - 0.5), 0.0), float(height)))
        last_row = np.int64(max(min(np.floor(bottom - 0.5), height - 1.0), -1.0))
        for row in range(first_row, last_row + 1):
            cy = row + 0.5
            left, right = -1.0, float(width)
            flat_ok = True
            for i in range(3):
                c = a[i, t] + v[i, t] * cy          # coordinate i along the row: c + u x
                ut = u[i, t]
                x0 = -c / ut if ut != 0 else 0.0
                left = max(left, x0 - x_eps if ut > 0 else -1.0)
                right = min(right, x0 + x_eps if ut < 0 else float(width))
                flat_ok &= (ut != 0) | (c >= -edge_eps)
            if not flat_ok:
                continue
            first = np.int64(max(np.ceil(min(left, float(width)) - 0.5), 0.0))
            last = np.int64(min(np.floor(max(right, -1.0) - 0.5), width - 1.0))
            z0 = za[t] + zu[t] * (first + 0.5) + zv[t] * cy
            dz = zu[t]
            base = row * width + first
            for offset in range(last - first + 1):
                depth = z0 + dz * offset
                pixel = base + offset
                if depth >= zbuf[pixel]:
                    zbuf[pixel] = depth
                    fbuf[pixel] = t


@numba.njit(cache=True, nogil=True)
def shade_pixels(fbuf, width, a, u, v, faces, front, normals, values, lut, vmin, vmax,
                 nan_rgb, base_rgb, light, half, ambient, diffuse, specular, shininess,
                 image):  # pragma: no cover - compiled; tested against NumPy
    """The shaded colour of every covered pixel into `image` (3, H * W), float32, in place.

    What :func:`mocap.viz._raster.interpolate`, :func:`~mocap.viz._raster.scalar_rgb` and
    :func:`~mocap.viz._raster.shade` compute, pixel by pixel with the same arithmetic in
    the same precisions (the pixel's barycentric coordinates and colours in float64, its
    normal and shading in float32), but for the specular power (float32 ``**`` here,
    NumPy's own there: they may differ in the last bit).

    Parameters
    ----------
    fbuf : ndarray of int, shape (H * W,)
        Triangle seen at each pixel, -1 for none (:func:`scan_triangles`).
    width : int
    a, u, v : ndarray of shape (3, F)
        The triangles' barycentric planes (as in :func:`scan_triangles`).
    faces : ndarray of int, shape (F, 3)
    front : ndarray of bool, shape (F,)
        Triangles that face the viewer (the others are lit on their back).
    normals : ndarray of float32, shape (N, 3)
        Vertex normals, camera coordinates.
    values : ndarray of shape (N, 3) or (N, 1), or None
        Vertex RGB (`lut` None), or scalars looked up in `lut` (L, 3) over [`vmin`, `vmax`]
        (NaN: `nan_rgb`); None: every pixel is `base_rgb` (each case compiled apart).
    light, half : ndarray of shape (3,)
        Unit directions towards the light and of the half-vector.
    ambient, diffuse, specular, shininess : float
    """
    height = fbuf.size // width
    for row in range(height):
        py = row + 0.5
        for col in range(width):
            pixel = row * width + col
            t = fbuf[pixel]
            if t < 0:
                continue
            px = col + 0.5
            b0 = a[0, t] + u[0, t] * px + v[0, t] * py
            b1 = a[1, t] + u[1, t] * px + v[1, t] * py
            bary = (b0, b1, 1.0 - b0 - b1)
            corners = (faces[t, 0], faces[t, 1], faces[t, 2])
            light_factor, spec = _lit(normals, corners, bary, front[t], light, half, ambient,
                                      diffuse, specular, shininess)
            rgb = _colour(values, corners, bary, lut, vmin, vmax, nan_rgb, base_rgb)
            for c in range(3):
                value = rgb[c] * light_factor + spec
                image[c, pixel] = min(max(value, np.float32(0.0)), np.float32(1.0))


@numba.njit(cache=True, nogil=True, inline="always")
def _lit(normals, corners, bary, front, light, half, ambient, diffuse, specular,
         shininess):  # pragma: no cover - compiled
    """A pixel's light factor (ambient + diffuse) and specular term, float32, from its
    normal interpolated in float32 (two-sided: a back face's normal is turned)."""
    nx = ny = nz = np.float32(0.0)
    for k in range(3):
        weight = np.float32(bary[k])
        nx += normals[corners[k], 0] * weight
        ny += normals[corners[k], 1] * weight
        nz += normals[corners[k], 2] * weight
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    if not front:
        norm = -norm
    dot = nx * np.float32(light[0]) + ny * np.float32(light[1]) + nz * np.float32(light[2])
    lambert = max(dot / norm if norm != 0 else np.float32(light[2]), np.float32(0.0))
    dot = nx * np.float32(half[0]) + ny * np.float32(half[1]) + nz * np.float32(half[2])
    cosine = max(dot / norm if norm != 0 else np.float32(half[2]), np.float32(0.0))
    spec = np.float32(specular) * cosine ** np.float32(shininess) if lambert != 0 \
        else np.float32(0.0)
    return np.float32(ambient) + np.float32(diffuse) * lambert, spec


@numba.njit(cache=True, nogil=True, inline="always")
def _colour(values, corners, bary, lut, vmin, vmax, nan_rgb,
            base_rgb):  # pragma: no cover - compiled
    """A pixel's colour, three float32: `base_rgb` (no `values`), its vertex RGB (no `lut`)
    or its scalar looked up in `lut`, interpolated in float64 by `bary`."""
    if values is None:
        return base_rgb[0], base_rgb[1], base_rgb[2]
    if lut is None:
        return (np.float32(_interpolated(values, corners, bary, 0)),
                np.float32(_interpolated(values, corners, bary, 1)),
                np.float32(_interpolated(values, corners, bary, 2)))
    value = _interpolated(values, corners, bary, 0)
    if np.isnan(value):
        return np.float32(nan_rgb[0]), np.float32(nan_rgb[1]), np.float32(nan_rgb[2])
    share = (value - vmin) / (vmax - vmin) if vmax > vmin else 0.5
    if np.isnan(share):             # inf / inf: NumPy's nan_to_num makes it 0
        share = 0.0
    index = np.int64(min(max(share * (lut.shape[0] - 1) + 0.5, 0.0), lut.shape[0] - 1.0))
    return np.float32(lut[index, 0]), np.float32(lut[index, 1]), np.float32(lut[index, 2])


@numba.njit(cache=True, nogil=True, inline="always")
def _interpolated(values, corners, bary, column):  # pragma: no cover - compiled
    """``Σ_k values[corners[k], column] bary[k]`` in float64, k in order."""
    value = 0.0
    for k in range(3):
        value += values[corners[k], column] * bary[k]
    return value
