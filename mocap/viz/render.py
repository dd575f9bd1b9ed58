"""Shaded pictures of face meshes: a small, fast software renderer (NumPy or numba, no GPU).

:func:`render_mesh` draws a triangle mesh with an orthographic :class:`Camera`,
a z-buffer, per-pixel interpolated vertex normals, Lambert + ambient +
Blinn-Phong :class:`Lighting`, optional per-vertex scalars through a colour map
(error maps, painted weights) or per-vertex RGB, optional point markers, on a
white background, anti-aliased by supersampling. :func:`colorbar`,
:func:`image_grid` and :func:`save_png` assemble and write figures.

Views look at a Y-up mesh whose face points along +Z (the ICT face): ``"front"``
looks along -Z, so the subject's left (+X) is on the viewer's right;
``"side"`` looks along -X at the subject's left profile; ``"three_quarter"`` is
between the two (35 degrees). Several meshes rendered with one
``Camera.fit([v1, v2])`` share scale and position.

Examples
--------
>>> import numpy as np
>>> from mocap.viz.render import Camera, render_mesh
>>> v = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]])
>>> image = render_mesh(v, [[0, 1, 2]], size=(64, 48))
>>> image.shape, image.dtype.name
((48, 64, 3), 'uint8')
>>> cam = Camera.fit(v, size=(64, 48))
>>> bool((cam.project(v)[:, :2] >= 0).all())
True
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import matplotlib
import numpy as np

from mocap.errors import InputError
from mocap.mesh.mesh import vertex_normals
from mocap.util.atomic import atomic_path
from mocap.util.validation import as_choice, as_float_array, as_int, as_positive_float
from mocap.viz import _raster

__all__ = ["VIEWS", "HIDDEN_POINTS", "Camera", "Lighting", "render_mesh", "compiled_renders",
           "colorbar", "image_grid", "save_png"]

#: Named views of :meth:`Camera.fit` (any 3x3 rotation is accepted too).
VIEWS = ("front", "side", "three_quarter")
#: What :func:`render_mesh` does with points hidden behind the mesh.
HIDDEN_POINTS = ("hide", "dim", "show")

_THREE_QUARTER_DEG = 35.0
#: Colour of NaN scalars, RGB in [0, 1].
_NAN_RGB = (0.55, 0.55, 0.55)
_DEFAULT_RGB = (0.82, 0.80, 0.78)
_POINT_RGB = (0.85, 0.1, 0.1)
_RIM_RGB = (0.1, 0.1, 0.1)
#: A point is hidden when it is behind the z-buffer by more than this fraction of
#: the mesh's bounding-box diagonal (points on the skin stay visible).
_POINT_DEPTH_REL = 0.01
#: Lookup-table size of colour maps.
_LUT = 1024


def _yaw(deg: float) -> np.ndarray:
    """World-to-camera rotation of a camera turned `deg` from +Z towards +X about Y."""
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


_ROTATIONS = {"front": _yaw(0.0), "side": _yaw(90.0), "three_quarter": _yaw(_THREE_QUARTER_DEG)}


def _as_size(size) -> tuple[int, int]:
    if not (isinstance(size, (tuple, list)) and len(size) == 2):
        raise InputError(f"size must be (width, height) in pixels, got {size!r}")
    return as_int(size[0], "size[0] (width)", minimum=1), as_int(size[1], "size[1] (height)",
                                                                   minimum=1)


def _as_rotation(view) -> np.ndarray:
    if isinstance(view, str):
        return _ROTATIONS[as_choice(view, "view", VIEWS)].copy()
    rot = as_float_array(view, "view", shape=(3, 3), allow_nan=False)
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6) or np.linalg.det(rot) < 0:
        raise InputError("view must be one of " f"{list(VIEWS)} or a 3x3 rotation matrix "
                         "(orthonormal, determinant +1)")
    return rot


@dataclass(frozen=True)
class Camera:
    """An orthographic camera.

    A world point ``p`` goes to camera coordinates ``q = rotation @ (p - centre)``
    (x right, y up, z towards the viewer), then to image coordinates
    ``(width / 2 + scale * q_x, height / 2 - scale * q_y)`` in pixels, pixel
    ``(row, col)`` covering ``[col, col + 1) x [row, row + 1)``; its depth is
    ``q_z`` (larger is nearer).

    Attributes
    ----------
    rotation : ndarray of shape (3, 3)
        World-to-camera rotation.
    centre : ndarray of shape (3,)
        World point at the image centre, mesh units.
    scale : float
        Pixels per mesh unit.
    size : tuple of int
        ``(width, height)`` in pixels.
    """

    rotation: np.ndarray
    centre: np.ndarray
    scale: float
    size: tuple

    def __post_init__(self):
        object.__setattr__(self, "rotation", _as_rotation(self.rotation))
        object.__setattr__(self, "centre",
                           as_float_array(self.centre, "centre", shape=(3,), allow_nan=False))
        object.__setattr__(self, "scale", as_positive_float(self.scale, "scale"))
        object.__setattr__(self, "size", _as_size(self.size))
        for arr in (self.rotation, self.centre):
            arr.flags.writeable = False

    @classmethod
    def fit(cls, vertices, *, view="front", size=(800, 800), margin: float = 0.05) -> "Camera":
        """Frame the bounding box of `vertices` (seen from `view`) in the image.

        Parameters
        ----------
        vertices : array_like of shape (N, 3), or a list of such arrays
            Points to frame, mesh units; a list frames several meshes together
            (same scale and position for all). NaN is rejected.
        view : str in VIEWS or array_like of shape (3, 3)
            Named view or world-to-camera rotation.
        size : (int, int)
            ``(width, height)`` in pixels.
        margin : float
            Free border on each side, as a fraction of the image size, in [0, 0.5).
        """
        if isinstance(vertices, (list, tuple)) and vertices and np.ndim(vertices[0]) == 2:
            vertices = np.concatenate([_as_vertices(v, f"vertices[{i}]")
                                       for i, v in enumerate(vertices)])
        vertices = _as_vertices(vertices, "vertices")
        rot, size = _as_rotation(view), _as_size(size)
        if not 0 <= margin < 0.5:
            raise InputError(f"margin must be in [0, 0.5), got {margin!r}")
        q = vertices @ rot.T
        lo, hi = q.min(axis=0), q.max(axis=0)
        extent = np.maximum(hi - lo, 1e-12 * max(1.0, np.abs(q).max()))
        usable = np.asarray(size) * (1 - 2 * margin)
        scale = float(np.min(usable / extent[:2]))
        return cls(rotation=rot, centre=rot.T @ ((lo + hi) / 2), scale=scale, size=size)

    def project(self, points) -> np.ndarray:
        """Image coordinates and depth of world points.

        Parameters
        ----------
        points : array_like of shape (P, 3), mesh units; NaN propagates.

        Returns
        -------
        ndarray of shape (P, 3)
            ``x`` (column, pixels), ``y`` (row, pixels, downwards), depth (mesh
            units, larger is nearer). The pixel is ``(floor(y), floor(x))``.
        """
        points = as_float_array(points, "points", shape=(None, 3))
        q = (points - self.centre) @ self.rotation.T
        w, h = self.size
        return np.stack([w / 2 + self.scale * q[:, 0], h / 2 - self.scale * q[:, 1],
                         q[:, 2]], axis=1)

    def zoomed(self, factor: int) -> "Camera":
        """The same view on an image `factor` times larger (supersampling)."""
        return Camera(self.rotation, self.centre, self.scale * factor,
                      (self.size[0] * factor, self.size[1] * factor))


@dataclass(frozen=True)
class Lighting:
    """One directional light, fixed to the camera, plus ambient light.

    Colour = base * (ambient + diffuse * max(n.l, 0)) + specular * max(n.h, 0)^shininess,
    with ``h`` the half-vector of the light and the view direction.

    Attributes
    ----------
    direction : tuple of float
        Direction towards the light in camera coordinates (x right, y up, z
        towards the viewer); normalized. The default lights from above left.
    ambient, diffuse, specular : float
        Non-negative weights.
    shininess : float
        Blinn-Phong exponent, positive.
    """

    direction: tuple = (-0.35, 0.45, 1.0)
    ambient: float = 0.22
    diffuse: float = 0.78
    specular: float = 0.12
    shininess: float = 40.0

    def __post_init__(self):
        d = as_float_array(self.direction, "direction", shape=(3,), allow_nan=False)
        if np.linalg.norm(d) == 0:
            raise InputError("direction must be a non-zero vector")
        object.__setattr__(self, "direction", tuple(d / np.linalg.norm(d)))
        for name in ("ambient", "diffuse", "specular"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value >= 0):
                raise InputError(f"{name} must be a non-negative number, got {value!r}")
        as_positive_float(self.shininess, "shininess")


def _as_vertices(vertices, name: str) -> np.ndarray:
    vertices = as_float_array(vertices, name, shape=(None, 3), allow_nan=False)
    if len(vertices) == 0:
        raise InputError(f"{name} is empty: need at least one vertex")
    return vertices


def _as_faces(faces, n_vertices: int) -> np.ndarray:
    arr = np.asarray(faces)
    if arr.size == 0:
        arr = arr.reshape(0, 3)
    if not (np.issubdtype(arr.dtype, np.integer) and arr.ndim == 2 and arr.shape[1] == 3):
        raise InputError(f"faces must be an integer array of shape (F, 3), got "
                         f"{arr.dtype} {arr.shape}")
    if arr.size and (arr.min() < 0 or arr.max() >= n_vertices):
        raise InputError(f"faces must hold vertex ids in [0, {n_vertices}), got ids from "
                         f"{arr.min()} to {arr.max()}")
    return arr.astype(np.int64)


def _colormap(cmap):
    try:
        return matplotlib.colormaps[cmap] if isinstance(cmap, str) else cmap
    except KeyError:
        raise InputError(f"cmap {cmap!r} is not a matplotlib colour map") from None


def _lut(cmap) -> np.ndarray:
    return _colormap(cmap)(np.linspace(0.0, 1.0, _LUT))[:, :3]


def _vertex_colors(colors, n: int, cmap, vmin, vmax):
    """Validated `colors` of render_mesh: (values (N, d) or None, lut or None, lo, hi)."""
    if colors is None:
        return None, None, 0.0, 1.0
    colors = np.asarray(colors)
    if colors.shape == (n, 3):
        return _as_rgb(colors, "colors"), None, 0.0, 1.0
    if colors.shape != (n,):
        raise InputError(f"colors must have shape ({n},) (scalars) or ({n}, 3) (RGB), "
                         f"got {colors.shape}")
    values = as_float_array(colors, "colors")
    finite = values[np.isfinite(values)]
    lo = vmin if vmin is not None else float(finite.min()) if finite.size else 0.0
    hi = vmax if vmax is not None else float(finite.max()) if finite.size else 1.0
    return values[:, None], _lut(cmap), float(lo), float(hi)


def _as_points(points, point_colors):
    """Validated points (P, 3) and their colours (P, 3)."""
    points = as_float_array(points, "points", shape=(None, 3))
    colors = _as_rgb(_POINT_RGB if point_colors is None else point_colors, "point_colors")
    colors = np.broadcast_to(colors, points.shape) if colors.shape == (3,) else colors
    if colors.shape != points.shape:
        raise InputError(f"point_colors must have shape (3,) or {points.shape}, "
                         f"got {colors.shape}")
    return points, colors


def _as_rgb(rgb, name: str) -> np.ndarray:
    """RGB in [0, 1] from floats in [0, 1] or uint8."""
    arr = np.asarray(rgb)
    if arr.dtype == np.uint8:
        return arr.astype(np.float64) / 255.0
    arr = as_float_array(arr, name, allow_nan=False)
    if arr.size and (arr.min() < 0 or arr.max() > 1):
        raise InputError(f"{name} must be RGB in [0, 1] (or uint8), got values in "
                         f"[{arr.min():g}, {arr.max():g}]")
    return arr


def render_mesh(vertices, faces, *, view="front", size=None, camera: Camera | None = None,
                colors=None, cmap="viridis", vmin: float | None = None,
                vmax: float | None = None, lighting: Lighting = Lighting(),
                supersample: int = 2, points=None, point_colors=None,
                point_radius: float = 4.0, hidden_points: str = "hide",
                normals=None) -> np.ndarray:
    """Render a shaded triangle mesh (and optional points) on a white background.

    Parameters
    ----------
    vertices : array_like of shape (N, 3)
        Vertex positions, mesh units. NaN is rejected.
    faces : array_like of shape (F, 3), int
        Triangles as 0-based vertex ids (``Mesh.faces``).
    view : str in VIEWS or array_like of shape (3, 3)
        Used with `size` to frame the mesh when `camera` is None.
    size : (int, int), optional
        ``(width, height)`` of the image, pixels; default ``camera.size`` or (800, 800).
    camera : Camera, optional
        Shared framing (``Camera.fit([v1, v2], ...)``); overrides `view`.
    colors : array_like of shape (N,) or (N, 3), optional
        Per-vertex scalars mapped through `cmap` between `vmin` and `vmax`
        (default: their finite min and max; NaN drawn grey), or per-vertex
        RGB in [0, 1] (or uint8). Default: a light clay colour.
    cmap : str or matplotlib colormap
    vmin, vmax : float, optional
        Scalar range of the colour map; pass them to :func:`colorbar` too.
    lighting : Lighting
    supersample : int
        Anti-aliasing factor: render at `supersample` times the size, then average.
    points : array_like of shape (P, 3), optional
        Markers to overlay as dots, mesh units; rows with NaN are skipped.
    point_colors : array_like of shape (3,) or (P, 3), optional
        RGB in [0, 1] (or uint8); default red.
    point_radius : float
        Dot radius in output pixels (a dark rim of one pixel included).
    hidden_points : str in HIDDEN_POINTS
        Points behind the mesh (by more than 1 % of its bounding-box
        diagonal): not drawn, drawn faded, or drawn like the others.
    normals : array_like of shape (N, 3), optional
        The unit vertex normals of `vertices` (default: their
        :func:`mocap.mesh.mesh.vertex_normals`), for renders of one mesh from
        several views to make them once.

    Returns
    -------
    ndarray of shape (height, width, 3), uint8
        RGB image.

    Raises
    ------
    InputError
        NaN or infinite vertices, faces not (F, 3) integers in range, unknown
        view, colour map or hidden-point mode, colours of the wrong shape, a
        size that disagrees with `camera`.

    Notes
    -----
    Scan conversion (see :mod:`mocap.viz._raster`: vectorized, or compiled
    where numba is loaded) at `supersample` times the size; nearest fragment
    per pixel by a z-buffer; normals, colours and scalars interpolated per
    pixel with barycentric coordinates (scalars are mapped after
    interpolation, so colour bands are exact); two-sided lighting; box-filter
    downsampling.
    """
    vertices = _as_vertices(vertices, "vertices")
    faces = _as_faces(faces, len(vertices))
    factor = as_int(supersample, "supersample", minimum=1)
    as_choice(hidden_points, "hidden_points", HIDDEN_POINTS)
    if camera is None:
        camera = Camera.fit(vertices, view=view, size=(800, 800) if size is None else size)
    elif not isinstance(camera, Camera):
        raise InputError(f"camera must be a mocap.viz.render.Camera, got {type(camera).__name__}")
    elif size is not None and _as_size(size) != camera.size:
        raise InputError(f"size {tuple(size)} disagrees with camera.size {camera.size}")
    if not isinstance(lighting, Lighting):
        raise InputError(f"lighting must be a mocap.viz.render.Lighting, got "
                         f"{type(lighting).__name__}")
    _colormap(cmap)
    values, lut, lo, hi = _vertex_colors(colors, len(vertices), cmap, vmin, vmax)
    if points is not None:
        points, point_colors = _as_points(points, point_colors)
    normals = vertex_normals(vertices, faces) if normals is None else as_float_array(
        normals, "normals", shape=vertices.shape, allow_nan=False, copy=False)

    cam = camera.zoomed(factor)
    width, height = cam.size
    proj = cam.project(vertices)
    image = np.ones((3, width * height), dtype=np.float32)      # one plane per channel
    zbuf = _raster.paint(image, width, proj[:, :2], proj[:, 2], faces,
                         normals @ cam.rotation.T, values=values,
                         lut=lut, vmin=lo, vmax=hi, base_rgb=_DEFAULT_RGB, nan_rgb=_NAN_RGB,
                         light=np.asarray(lighting.direction), ambient=lighting.ambient,
                         diffuse=lighting.diffuse, specular=lighting.specular,
                         shininess=lighting.shininess)
    if points is not None:
        diag = np.linalg.norm(np.ptp(vertices, axis=0))
        _raster.draw_points(image, zbuf, cam.project(points), point_colors, cam.size,
                            radius=point_radius * factor, rim=factor, rim_rgb=_RIM_RGB,
                            hidden=hidden_points, tolerance=_POINT_DEPTH_REL * diag)
    image = _raster.downsample(image.reshape(3, height, width), factor)
    return np.round(image * 255).astype(np.uint8)


def compiled_renders(n_renders: int, n_faces: int) -> bool:
    """Whether the next `n_renders` renders of a mesh of `n_faces` triangles are drawn by the
    compiled z-buffer and shading (numba: the ``speed`` extra), loading numba for them when
    they pay for it (a video's frames; about 0.35 s to load, 0.6 µs saved a triangle).

    Without this, :func:`render_mesh` loads it only for a mesh large enough on its own, and
    uses it in any process that has loaded it (e.g. for a fit). The pictures are the same
    either way (to the last bit of the specular power: see :mod:`mocap.viz._raster`).
    """
    n = as_int(n_renders, "n_renders", minimum=0) * as_int(n_faces, "n_faces", minimum=0)
    return _raster.kernels_for(n) is not None


def colorbar(*, vmin: float, vmax: float, cmap="viridis", height: int = 300, width: int = 90,
             label: str | None = None, n_ticks: int = 5) -> np.ndarray:
    """A vertical colour bar with tick labels, to place beside a colour-mapped render.

    Parameters
    ----------
    vmin, vmax : float
        The range given to :func:`render_mesh`.
    cmap : str or matplotlib colormap
    height, width : int
        Image size, pixels (the bar takes the left third).
    label : str, optional
        Units or quantity, written above the bar.
    n_ticks : int
        Number of labelled ticks, at least 2.

    Returns
    -------
    ndarray of shape (height, width, 3), uint8
    """
    height, width = _as_size((height, width))
    as_int(n_ticks, "n_ticks", minimum=2)
    if not (np.isfinite(vmin) and np.isfinite(vmax)):
        raise InputError(f"vmin and vmax must be finite, got {vmin!r}, {vmax!r}")
    top, bottom = (22 if label else 8), 8
    image = np.full((height, width, 3), 255, dtype=np.uint8)
    bar_w = max(4, width // 3)
    t = np.linspace(1.0, 0.0, max(height - top - bottom, 1))
    image[top:height - bottom, 4:4 + bar_w] = np.round(
        _lut(cmap)[np.round(t * (_LUT - 1)).astype(int)] * 255)[:, None, :]
    for k in range(n_ticks):
        frac = k / (n_ticks - 1)
        y = int(round(height - bottom - 1 - frac * (height - top - bottom - 1)))
        cv2.line(image, (4 + bar_w, y), (8 + bar_w, y), (0, 0, 0), 1)
        cv2.putText(image, f"{vmin + frac * (vmax - vmin):.3g}", (11 + bar_w, y + 4),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.38, (0, 0, 0), 1, cv2.LINE_AA)
    if label:
        cv2.putText(image, label, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1,
                    cv2.LINE_AA)
    return image


def image_grid(images, labels=None, *, ncols: int | None = None, pad: int = 8,
               font_scale: float = 0.6) -> np.ndarray:
    """Tile images in a grid on white, each with a caption underneath.

    Parameters
    ----------
    images : sequence of ndarray of shape (h_i, w_i, 3), uint8
        Images of any sizes; each is centred in a cell of the largest size.
    labels : sequence of str, optional
        One caption per image.
    ncols : int, optional
        Columns; default all images on one row.
    pad : int
        White space between cells, pixels.
    font_scale : float
        OpenCV Hershey font scale of the captions.

    Returns
    -------
    ndarray of shape (H, W, 3), uint8
    """
    images = [_as_image(im, f"images[{i}]") for i, im in enumerate(images)]
    if not images:
        raise InputError("images is empty: need at least one image")
    labels = [""] * len(images) if labels is None else [str(s) for s in labels]
    if len(labels) != len(images):
        raise InputError(f"labels has {len(labels)} entries for {len(images)} images")
    ncols = len(images) if ncols is None else as_int(ncols, "ncols", minimum=1)
    pad = as_int(pad, "pad", minimum=0)
    font_scale = as_positive_float(font_scale, "font_scale")
    font = cv2.FONT_HERSHEY_SIMPLEX
    (_, text_h), base = cv2.getTextSize("Ag", font, font_scale, 1)
    cap = (text_h + base + 6) if any(labels) else 0
    cell_h = max(im.shape[0] for im in images)
    cell_w = max(im.shape[1] for im in images)
    nrows = -(-len(images) // ncols)
    out = np.full((pad + nrows * (cell_h + cap + pad), pad + ncols * (cell_w + pad), 3), 255,
                  dtype=np.uint8)
    for i, (im, text) in enumerate(zip(images, labels)):
        y0 = pad + (i // ncols) * (cell_h + cap + pad)
        x0 = pad + (i % ncols) * (cell_w + pad)
        dy, dx = (cell_h - im.shape[0]) // 2, (cell_w - im.shape[1]) // 2
        out[y0 + dy:y0 + dy + im.shape[0], x0 + dx:x0 + dx + im.shape[1]] = im
        if text:
            text_w = cv2.getTextSize(text, font, font_scale, 1)[0][0]
            cv2.putText(out, text, (x0 + max(0, (cell_w - text_w) // 2), y0 + cell_h + text_h + 3),
                        font, font_scale, (0, 0, 0), 1, cv2.LINE_AA)
    return out


def _as_image(image, name: str) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3 or 0 in image.shape:
        raise InputError(f"{name} must be a uint8 RGB image of shape (h, w, 3), got "
                         f"{image.dtype} {image.shape}")
    return image


def save_png(image, path, *, inputs=()) -> None:
    """Write an RGB image to a PNG file, atomically.

    Parameters
    ----------
    image : ndarray of shape (h, w, 3), uint8
    path : str or os.PathLike
    inputs : iterable of path, optional
        Files this output must never replace.

    Raises
    ------
    InputError
        Not a uint8 RGB image, or the file cannot be written.
    """
    image = _as_image(image, "image")
    ok, data = cv2.imencode(".png", image[:, :, ::-1])
    if not ok:
        raise InputError(f"{path}: cannot encode the image as PNG")
    with atomic_path(path, inputs=inputs) as tmp:
        tmp.write_bytes(data.tobytes())
