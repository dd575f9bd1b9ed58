"""Numerics of :mod:`mocap.viz.render`: a z-buffer rasterizer and shading.

Conventions: image coordinates are continuous pixels, ``x`` to the right and
``y`` downwards; pixel ``(row, col)`` covers ``[col, col + 1) x [row, row + 1)``
and is sampled at its centre ``(col + 0.5, row + 0.5)``. Depth grows towards
the viewer (the nearest fragment has the largest depth).

Scan conversion: every triangle is cut into the pixel rows of its bounding box;
on each row the three barycentric coordinates are linear in ``x``, so the span
of pixel centres where all are >= 0 comes from where each one vanishes. Only
pixels inside triangles are ever generated. In NumPy, spans are expanded into
fragments (pixel, depth) in batches of about ``_BATCH`` pixels, and a
scatter-max (``np.maximum.at``) merges each batch into the z-buffer; the
covered pixels are then shaded as arrays. Where numba is loaded (the ``speed``
extra), :mod:`mocap.viz._raster_kernel` walks the same spans and shades the
same pixels one by one, with the same arithmetic (:func:`paint`).
"""

from __future__ import annotations

import functools
import importlib
from dataclasses import dataclass

import cv2
import numpy as np

from mocap.util.optional import compiled, compiled_if_worth

#: Fragments generated per vectorized batch (~60 bytes each while live).
_BATCH = 1 << 18
#: Slack of the span ends, pixels: a pixel centre on an edge shared by two
#: triangles belongs to both (the z-buffer keeps one), so meshes have no cracks.
_X_EPS = 1e-7
#: Slack of a barycentric coordinate constant along a row (horizontal edges).
_EDGE_EPS = 1e-9
#: Triangles whose doubled screen area is below this (pixels^2) are edge-on: skipped.
_MIN_AREA2 = 1e-12
#: Triangles (summed over the renders to come) from which the compiled kernels are worth
#: loading numba in a process that has not: its import and the kernels' load take about
#: 0.35 s, and they save about 0.6 µs a triangle (the ICT face at a report's cell size).
_TRIANGLES_WORTH_COMPILING = 600_000


@dataclass(frozen=True)
class Fragments:
    """The visible fragment of every covered pixel.

    Attributes
    ----------
    pixel : ndarray of shape (K,), int64
        Flat pixel index ``row * width + col``, increasing.
    face : ndarray of shape (K,), int64
        The triangle seen at the pixel.
    bary : ndarray of shape (3, K), float64
        Barycentric coordinates of the pixel centre in that triangle, one row
        per corner (arrays are kept per corner: numpy is slow on short axes).
    depth : ndarray of shape (H * W,), float64
        The full z-buffer, ``-inf`` where nothing is drawn.
    front : ndarray of shape (F,), bool
        Whether each triangle faces the viewer (counter-clockwise on screen
        when seen with ``y`` upwards).
    """

    pixel: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    depth: np.ndarray
    front: np.ndarray


def _rows(y: list, live: np.ndarray, height: int):
    """(triangle, row) pairs of the pixel rows whose centres cross each live triangle."""
    lo = np.ceil(np.minimum(np.minimum(y[0], y[1]), y[2])[live] - 0.5)
    hi = np.floor(np.maximum(np.maximum(y[0], y[1]), y[2])[live] - 0.5)
    # clamped to the image before they become integers: a vertex far off it would overflow
    lo = np.clip(lo, 0.0, float(height)).astype(np.int64)
    hi = np.clip(hi, -1.0, height - 1.0).astype(np.int64)
    n = np.maximum(hi - lo + 1, 0)
    tri = np.repeat(live, n)
    row = np.repeat(lo, n) + np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    return tri, row


def _spans(a, u, v, tri, row, width: int):
    """First column and length of the pixel span of each (triangle, row) pair."""
    left, right = np.full(len(tri), -1.0), np.full(len(tri), float(width))
    flat_ok = np.ones(len(tri), dtype=bool)
    cy = row + 0.5
    for a_i, u_i, v_i in zip(a, u, v):
        c = a_i[tri] + v_i[tri] * cy                  # b_i(x) = c + u x on this row
        ut = u_i[tri]
        x0 = np.divide(-c, ut, out=np.zeros_like(c), where=ut != 0)    # where b_i = 0
        np.maximum(left, np.where(ut > 0, x0 - _X_EPS, -1.0), out=left)
        np.minimum(right, np.where(ut < 0, x0 + _X_EPS, float(width)), out=right)
        flat_ok &= (ut != 0) | (c >= -_EDGE_EPS)
    # clamped to the image before they become integers: a span end far off the image (a
    # nearly horizontal edge) would overflow int64
    first = np.maximum(np.ceil(np.minimum(left, float(width)) - 0.5), 0.0).astype(np.int64)
    last = np.minimum(np.floor(np.maximum(right, -1.0) - 0.5), width - 1.0).astype(np.int64)
    return first, np.where(flat_ok, np.maximum(last - first + 1, 0), 0)


def _merge(zbuf, fbuf, pix, depth, face) -> None:
    """Keep the nearest of the fragments (pix, depth, face) and of the buffers, in place."""
    np.maximum.at(zbuf, pix, depth)
    win = depth == zbuf[pix]        # ties are one surface point seen through a shared edge
    fbuf[pix[win]] = face[win]


def _scan_triangles(live, y, a, u, v, za, zu, zv, width: int, height: int, zbuf,
                    fbuf) -> None:
    """Draw the triangles `live` into the z-buffer `zbuf` and `fbuf` (H W,), in place: their
    (triangle, row) spans expanded into fragments ``_BATCH`` pixels at a time, each batch
    merged by a scatter-max (:func:`_merge`)."""
    tri, row = _rows(y, live, height)
    first, count = _spans(a, u, v, tri, row, width)
    base = row * width + first                                  # pixel of each span start
    z0 = za[tri] + zu[tri] * (first + 0.5) + zv[tri] * (row + 0.5)
    dz = zu[tri]
    ends = np.cumsum(count)
    cuts = np.searchsorted(ends, np.arange(_BATCH, ends[-1] if len(ends) else 0, _BATCH))
    for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, len(count)]):
        n = count[lo:hi]
        offset = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        _merge(zbuf, fbuf, np.repeat(base[lo:hi], n) + offset,
               np.repeat(z0[lo:hi], n) + np.repeat(dz[lo:hi], n) * offset,
               np.repeat(tri[lo:hi], n))


@functools.cache
def _compiled_kernels():
    """(:func:`~mocap.viz._raster_kernel.scan_triangles`,
    :func:`~mocap.viz._raster_kernel.shade_pixels`), or None (NumPy rasterizes and shades):
    :func:`mocap.util.optional.compiled`."""
    scan = compiled("mocap.viz._raster_kernel", "scan_triangles", what="mesh rasterizer",
                    fallback="NumPy rasterizes and shades, several times slower")
    return None if scan is None else (scan, importlib.import_module(scan.__module__).shade_pixels)


def kernels_for(n_triangles: int):
    """The compiled kernels (:func:`_compiled_kernels`) where numba is loaded already or
    rendering `n_triangles` in all pays for loading it (it is then loaded); else None."""
    return compiled_if_worth(_compiled_kernels, n_triangles, _TRIANGLES_WORTH_COMPILING)


@dataclass(frozen=True)
class _Planes:
    """Each triangle's barycentric and depth planes in image coordinates.

    Barycentric coordinate i of triangle t at (x, y) is ``a[i, t] + u[i, t] x + v[i, t] y``
    and its depth ``za[t] + zu[t] x + zv[t] y``; `y` (3, F) holds the corners' rows;
    `live` the triangles that are not edge-on, in order; `front` as in :class:`Fragments`.
    """

    y: np.ndarray
    a: np.ndarray
    u: np.ndarray
    v: np.ndarray
    za: np.ndarray
    zu: np.ndarray
    zv: np.ndarray
    live: np.ndarray
    front: np.ndarray

    @classmethod
    def of(cls, xy: np.ndarray, depth: np.ndarray, faces: np.ndarray) -> "_Planes":
        """The planes of `faces` (F, 3) with vertices at `xy` (N, 2) pixels, `depth` (N,)."""
        x = [xy[faces[:, i], 0] for i in range(3)]                 # per corner, (F,) each
        y = [xy[faces[:, i], 1] for i in range(3)]
        z = [depth[faces[:, i]] for i in range(3)]
        cyc = [(1, 2), (2, 0), (0, 1)]
        # b_i(p) = (a_i + u_i p_x + v_i p_y) / area2, (i, j, k) cyclic
        a = [x[j] * y[k] - x[k] * y[j] for j, k in cyc]
        u = [y[j] - y[k] for j, k in cyc]
        v = [x[k] - x[j] for j, k in cyc]
        area2 = a[0] + a[1] + a[2]
        keep = np.abs(area2) > _MIN_AREA2
        inv = np.divide(1.0, area2, out=np.zeros_like(area2), where=keep)
        a, u, v = [np.stack([c * inv for c in coef]) for coef in (a, u, v)]
        # depth plane of each triangle: z(p) = sum_i b_i(p) z_i = za + zu p_x + zv p_y
        za, zu, zv = [c[0] * z[0] + c[1] * z[1] + c[2] * z[2] for c in (a, u, v)]
        # image y points down: counter-clockwise is negative
        return cls(np.stack(y), a, u, v, za, zu, zv, np.flatnonzero(keep), area2 < 0)

    def zbuffer(self, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
        """The depth (H W,) of the nearest fragment of each pixel (``-inf`` for none) and its
        triangle (-1 for none), by the compiled scan where it is worth loading, else NumPy's:
        the same bits."""
        zbuf = np.full(width * height, -np.inf)
        fbuf = np.full(width * height, -1, dtype=np.int64)
        kernels = kernels_for(len(self.live))
        if kernels is not None:
            scan = kernels[0]
            scan(self.live, self.y, self.a, self.u, self.v, self.za, self.zu, self.zv, width,
                 height, _X_EPS, _EDGE_EPS, zbuf, fbuf)
        else:
            _scan_triangles(self.live, self.y, self.a, self.u, self.v, self.za, self.zu,
                            self.zv, width, height, zbuf, fbuf)
        return zbuf, fbuf


def rasterize(xy: np.ndarray, depth: np.ndarray, faces: np.ndarray,
              width: int, height: int) -> Fragments:
    """Z-buffer rasterization of triangles in image coordinates.

    Parameters
    ----------
    xy : ndarray of shape (N, 2)
        Vertex image coordinates, pixels.
    depth : ndarray of shape (N,)
        Vertex depth, larger is nearer.
    faces : ndarray of shape (F, 3), int
    width, height : int
        Image size, pixels.
    """
    planes = _Planes.of(xy, depth, faces)
    zbuf, fbuf = planes.zbuffer(width, height)
    pixel = np.flatnonzero(fbuf >= 0)
    face = fbuf[pixel]
    px, py = pixel % width + 0.5, pixel // width + 0.5
    bary = np.empty((3, len(pixel)))
    for i in range(2):
        bary[i] = (np.take(planes.a[i], face) + np.take(planes.u[i], face) * px
                   + np.take(planes.v[i], face) * py)
    bary[2] = 1.0 - bary[0] - bary[1]
    return Fragments(pixel=pixel, face=face, bary=bary, depth=zbuf, front=planes.front)


def paint(image: np.ndarray, width: int, xy: np.ndarray, depth: np.ndarray, faces: np.ndarray,
          normals: np.ndarray, *, values, lut, vmin: float, vmax: float, base_rgb, nan_rgb,
          light: np.ndarray, ambient: float, diffuse: float, specular: float,
          shininess: float) -> np.ndarray:
    """Rasterize the triangles and write the shaded colour of every pixel they cover into
    `image`; returns the z-buffer.

    :func:`rasterize`, then :func:`interpolate` (and :func:`scalar_rgb`) and :func:`shade`,
    or the same pixel by pixel by the compiled kernels where they are worth loading (the
    same to the last bit of the specular power).

    Parameters
    ----------
    image : ndarray of shape (3, H * W), float32
        Planar RGB in [0, 1], written where a triangle is seen.
    width : int
        W, pixels.
    xy, depth, faces
        As for :func:`rasterize`.
    normals : ndarray of shape (N, 3)
        Unit vertex normals in camera coordinates.
    values : ndarray of shape (N, 3) or (N, 1), or None
        Vertex RGB in [0, 1]; or scalars, looked up in `lut` (L, 3) over [`vmin`, `vmax`]
        (NaN: `nan_rgb`); None: every triangle is `base_rgb`.
    light, ambient, diffuse, specular, shininess
        As for :func:`shade`.

    Returns
    -------
    ndarray of shape (H * W,)
        Depth of the nearest fragment of each pixel, ``-inf`` where nothing is drawn.
    """
    height = image.shape[1] // width
    kernels = kernels_for(len(faces))
    if kernels is None:
        frags = rasterize(xy, depth, faces, width, height)
        if values is None:
            base = np.broadcast_to(np.float32(base_rgb)[:, None], (3, len(frags.pixel)))
        else:
            base = interpolate(values, faces, frags)
        if lut is not None:
            base = scalar_rgb(base[0], lut, vmin, vmax, nan_rgb=nan_rgb)
        image[:, frags.pixel] = shade(normals, faces, frags, base, light=light,
                                      ambient=ambient, diffuse=diffuse, specular=specular,
                                      shininess=shininess)
        return frags.depth
    planes = _Planes.of(xy, depth, faces)
    zbuf, fbuf = planes.zbuffer(width, height)
    shade_pixels = kernels[1]
    shade_pixels(fbuf, width, planes.a, planes.u, planes.v, faces, planes.front,
                 np.ascontiguousarray(normals, dtype=np.float32),
                 None if values is None else np.ascontiguousarray(values, dtype=float),
                 None if lut is None else np.ascontiguousarray(lut, dtype=float),
                 float(vmin), float(vmax), np.asarray(nan_rgb, dtype=float),
                 np.float32(base_rgb), light, _half_vector(light), ambient, diffuse, specular,
                 shininess, image)
    return zbuf


def interpolate(values: np.ndarray, faces: np.ndarray, frags: Fragments) -> np.ndarray:
    """Per-vertex values (N, d) interpolated at the fragments, (d, K), in their dtype."""
    out = np.zeros((values.shape[1], len(frags.face)), dtype=values.dtype)
    bary = frags.bary.astype(values.dtype)
    columns = [np.ascontiguousarray(col) for col in values.T]
    for k in range(3):
        corner = np.take(faces[:, k], frags.face)
        for out_c, col in zip(out, columns):
            out_c += np.take(col, corner) * bary[k]
    return out


def shade(normals: np.ndarray, faces: np.ndarray, frags: Fragments, base: np.ndarray, *,
          light: np.ndarray, ambient: float, diffuse: float, specular: float,
          shininess: float) -> np.ndarray:
    """Lambert + ambient + Blinn-Phong shading with per-pixel interpolated normals.

    Parameters
    ----------
    normals : ndarray of shape (N, 3)
        Unit vertex normals in camera coordinates (z towards the viewer).
    base : ndarray of shape (3, K)
        Surface colour of each fragment, RGB in [0, 1].
    light : ndarray of shape (3,)
        Unit direction towards the light, camera coordinates.

    Returns
    -------
    ndarray of shape (3, K), float32
        RGB in [0, 1]. Triangles seen from behind are lit on their visible
        side (two-sided lighting: their normals are flipped). A pixel whose
        interpolated normal vanishes is lit as if it faced the viewer.
    """
    nx, ny, nz = interpolate(normals.astype(np.float32), faces, frags)
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    norm *= np.where(np.take(frags.front, frags.face), 1.0, -1.0).astype(np.float32)
    cosines = []
    for d in (light, _half_vector(light)):
        dot = nx * np.float32(d[0]) + ny * np.float32(d[1]) + nz * np.float32(d[2])
        cosines.append(np.divide(dot, norm, where=norm != 0,
                                 out=np.full(len(dot), d[2], dtype=np.float32)))
    lambert = np.clip(cosines[0], 0.0, None)
    spec = np.float32(specular) * np.clip(cosines[1], 0.0, None) ** np.float32(shininess)
    spec[lambert == 0] = 0.0
    rgb = base.astype(np.float32) * (np.float32(ambient) + np.float32(diffuse) * lambert)
    rgb += spec
    return np.clip(rgb, 0.0, 1.0, out=rgb)


def _half_vector(light: np.ndarray) -> np.ndarray:
    """Blinn-Phong's half-vector of the unit `light` direction and the view (+z), (3,)."""
    half = light + [0.0, 0.0, 1.0]
    return half / np.linalg.norm(half)


def scalar_rgb(values: np.ndarray, lut: np.ndarray, vmin: float, vmax: float, *,
               nan_rgb) -> np.ndarray:
    """(K,) scalars looked up in an (L, 3) table over [vmin, vmax]: (3, K); NaN: nan_rgb."""
    t = (values - vmin) / (vmax - vmin) if vmax > vmin else np.full_like(values, 0.5)
    idx = np.clip(np.nan_to_num(t) * (len(lut) - 1) + 0.5, 0, len(lut) - 1).astype(np.int64)
    return np.where(np.isnan(values), np.reshape(nan_rgb, (3, 1)), lut[idx].T)


def draw_points(image, zbuf, proj, colors, size, *, radius, rim, rim_rgb, hidden,
                tolerance) -> None:
    """Draw dots with a dark rim, in place, nearest on top.

    Parameters
    ----------
    image : ndarray of shape (3, H * W)
        Flat planar RGB image in [0, 1], modified in place.
    zbuf : ndarray of shape (H * W,)
        Depth of the mesh at each pixel, ``-inf`` on the background.
    proj : ndarray of shape (P, 3)
        Image x, y (pixels) and depth of the points; NaN rows are skipped.
    colors : ndarray of shape (P, 3)
    size : (int, int)
        ``(W, H)``.
    radius, rim : float
        Dot radius and rim width, pixels.
    hidden : {"hide", "dim", "show"}
        Points more than `tolerance` behind the z-buffer: skipped, faded, or drawn.
    """
    width, height = size
    xy = np.nan_to_num(proj[:, :2], nan=-1e9)            # NaN points fall off the image
    r = int(np.ceil(radius))
    off = np.arange(-r, r + 1)
    cx = np.floor(xy[:, 0, None, None]).astype(np.int64) + off[None, None, :]
    cy = np.floor(xy[:, 1, None, None]).astype(np.int64) + off[None, :, None]
    dist = np.hypot(cx + 0.5 - xy[:, 0, None, None], cy + 0.5 - xy[:, 1, None, None])
    ok = (dist <= radius) & (cx >= 0) & (cx < width) & (cy >= 0) & (cy < height)
    which, i, k = np.nonzero(ok)
    pixel, dist = cy[which, i, 0] * width + cx[which, 0, k], dist[which, i, k]
    col = np.clip(xy[:, 0], 0, width - 1).astype(np.int64)
    row = np.clip(xy[:, 1], 0, height - 1).astype(np.int64)
    behind = proj[:, 2] < zbuf[row * width + col] - tolerance
    rgb = np.where((dist > radius - rim)[:, None], rim_rgb, colors[which])
    if hidden == "hide":
        keep = ~behind[which]
        pixel, which, rgb = pixel[keep], which[keep], rgb[keep]
    elif hidden == "dim":
        rgb = np.where(behind[which][:, None], 0.35 * rgb + 0.65, rgb)
    win = nearest_per_pixel(pixel, proj[which, 2])
    image[:, pixel[win]] = rgb[win].T


def nearest_per_pixel(pixel: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Indices of the nearest (largest depth) entry of each distinct pixel."""
    order = np.lexsort((depth, pixel))
    last = np.ones(len(order), dtype=bool)
    last[:-1] = pixel[order[1:]] != pixel[order[:-1]]
    return order[last]


def downsample(image: np.ndarray, factor: int) -> np.ndarray:
    """Box-filter a (3, H*f, W*f) planar image to an (H, W, 3) one (OpenCV area resampling)."""
    size = (image.shape[2] // factor, image.shape[1] // factor)
    return np.stack([cv2.resize(plane, size, interpolation=cv2.INTER_AREA) for plane in image],
                    axis=-1)
