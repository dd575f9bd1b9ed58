"""Mesh renderer (mocap.viz.render, mocap.viz._raster)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import matplotlib
import numpy as np
import pytest
import trimesh
from helpers import kernel_or_numpy, numba_cannot_cache
from tolerances import (
    EXACT_FLOAT64,
    RENDER_EXACT_PX,
    RENDER_KERNEL_LEVELS,
    RENDER_KERNEL_PIXELS,
    RENDER_POINT_CENTRE_PX,
    RENDER_POINT_RGB_LEVELS,
    RENDER_RGB_LEVELS,
    RENDER_SILHOUETTE_REL,
)

from mocap.errors import InputError
from mocap.mesh.mesh import load_mesh, vertex_normals
from mocap.viz import _raster
from mocap.viz.render import (
    HIDDEN_POINTS,
    VIEWS,
    Camera,
    Lighting,
    colorbar,
    compiled_renders,
    image_grid,
    render_mesh,
    save_png,
)

WHITE = np.array([255, 255, 255])
#: Shading that returns the base colour: no light direction dependence.
FLAT = Lighting(ambient=1.0, diffuse=0.0, specular=0.0)


def _square(z=0.0, half=1.0):
    """Two triangles, counter-clockwise seen from +Z."""
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def _grid(n=12):
    """A flat n x n vertex grid in the XY plane, [-1, 1]^2, facing +Z."""
    x, y = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n))
    v = np.column_stack([x.ravel(), y.ravel(), np.zeros(n * n)])
    i = np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]
    f = np.concatenate([np.stack([i, i + 1, i + n + 1], -1).reshape(-1, 3),
                        np.stack([i, i + n + 1, i + n], -1).reshape(-1, 3)])
    return v, f


def _camera(size=(200, 200), scale=50.0, rotation=np.eye(3)):
    return Camera(rotation=rotation, centre=np.zeros(3), scale=scale, size=size)


def _not_background(image) -> np.ndarray:
    return np.any(image != 255, axis=2)


@pytest.fixture(params=["compiled", "numpy"])
def raster_by(request, monkeypatch):
    """The z-buffer and the shading by numba's loops over the triangles and the pixels (the
    `speed` extra, in .[test]) or by NumPy's batches of fragments."""
    return kernel_or_numpy(request.param, monkeypatch, _raster, "_compiled_kernels",
                           "_TRIANGLES_WORTH_COMPILING")


# ---------------------------------------------------------------- rasterizer

def _brute_force_faces(xy, depth, faces, width, height):
    """Oracle: every pixel centre against every triangle (a 2x2 solve each), nearest kept."""
    cols, rows = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    centres = np.column_stack([cols.ravel(), rows.ravel()])
    best = np.full(len(centres), -np.inf)
    out = np.full(len(centres), -1)
    for f, (i, j, k) in enumerate(faces):
        m = np.column_stack([xy[j] - xy[i], xy[k] - xy[i]])
        if abs(np.linalg.det(m)) < 1e-12:
            continue
        b1, b2 = np.linalg.solve(m, (centres - xy[i]).T)
        z = depth[i] + b1 * (depth[j] - depth[i]) + b2 * (depth[k] - depth[i])
        hit = (np.minimum(np.minimum(b1, b2), 1 - b1 - b2) >= -1e-9) & (z > best)
        best[hit], out[hit] = z[hit], f
    return out.reshape(height, width)


@pytest.mark.parametrize("seed", range(6))
def test_rasterizer_matches_brute_force(seed, raster_by):
    rng = np.random.default_rng(seed)
    width, height = 90, 70
    # small and large triangles (tiled), some reaching past the image border
    centres = rng.uniform([-10, -10], [width + 10, height + 10], (12, 2))
    sizes = np.repeat([4.0, 15.0, 60.0], 4)[:, None, None]
    xy = (centres[:, None, :] + sizes * rng.uniform(-1, 1, (12, 3, 2))).reshape(-1, 2)
    depth = rng.uniform(-5, 5, len(xy))
    faces = np.arange(len(xy)).reshape(-1, 3)
    frags = _raster.rasterize(xy, depth, faces, width, height)
    got = np.full(width * height, -1)
    got[frags.pixel] = frags.face
    expected = _brute_force_faces(xy, depth, faces, width, height)
    np.testing.assert_array_equal(got.reshape(height, width), expected)
    # barycentric coordinates reproduce the pixel centres
    centre = np.column_stack([frags.pixel % width, frags.pixel // width]) + 0.5
    np.testing.assert_allclose(np.einsum("ck,kcd->kd", frags.bary, xy[faces[frags.face]]),
                               centre, atol=RENDER_EXACT_PX)


def test_of_triangles_at_the_same_depth_the_last_drawn_is_seen(raster_by):
    """A tie in the z-buffer (here the same triangle drawn three times) goes to the triangle
    drawn last, whichever way the buffer is made."""
    xy = np.array([[5.0, 5.0], [60.0, 8.0], [30.0, 50.0]])
    depth = np.array([1.0, 2.0, 3.0])
    frags = _raster.rasterize(xy, depth, np.array([[0, 1, 2]] * 3), 64, 64)
    assert len(frags.pixel) > 500
    np.testing.assert_array_equal(frags.face, 2)


def test_triangles_far_off_the_image_draw_nothing_or_all_of_it(raster_by):
    """Vertices 1e20 px away (beyond int64 once rounded to rows and columns): triangles
    wholly above, below, left or right of the image draw nothing, and one around it covers
    every pixel."""
    far, width, height = 1e20, 40, 30
    outside = [[(-far, -far), (far, -far), (0.0, -far / 2)],           # above
               [(-far, 2 * far), (far, 2 * far), (0.0, far)],          # below
               [(-far, -far), (-far / 2, 0.0), (-far, far)],           # left
               [(2 * far, -far), (far, 0.0), (2 * far, far)]]          # right
    xy = np.array(outside, dtype=float).reshape(-1, 2)
    faces = np.arange(len(xy)).reshape(-1, 3)
    assert len(_raster.rasterize(xy, np.zeros(len(xy)), faces, width, height).pixel) == 0
    around = np.array([(-far, -far), (far, -far), (0.0, far)])
    frags = _raster.rasterize(around, np.zeros(3), np.array([[0, 1, 2]]), width, height)
    np.testing.assert_array_equal(frags.pixel, np.arange(width * height))


# ---------------------------------------------------------------- geometry oracles

@pytest.mark.parametrize("supersample", [1, 2, 3])
@pytest.mark.parametrize("view", VIEWS)
def test_sphere_silhouette_is_pi_r_squared(view, supersample, raster_by):
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=2.0)
    cam = Camera.fit(sphere.vertices, view=view, size=(300, 260), margin=0.1)
    image = render_mesh(sphere.vertices, sphere.faces, camera=cam, supersample=supersample,
                        lighting=Lighting(specular=0.0))
    radius_px = 2.0 * cam.scale
    area = _not_background(image).sum()
    # a rim pixel counts whole once any of its k x k samples is covered: on average
    # (1 - 1/k) / 2 pixel of extra width along the perimeter
    rim = (1 - 1 / supersample) / 2 * 2 * np.pi * radius_px
    assert area == pytest.approx(np.pi * radius_px ** 2 + rim, rel=RENDER_SILHOUETTE_REL)


def test_near_triangle_hides_far_one_in_any_order(raster_by):
    near, faces = _square(z=1.0)
    far, _ = _square(z=-1.0, half=1.5)
    vertices = np.concatenate([near, far])
    colors = np.repeat([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], 4, axis=0)
    both = np.concatenate([faces, faces + 4])
    cam = _camera()
    first = render_mesh(vertices, both, camera=cam, colors=colors, lighting=FLAT)
    second = render_mesh(vertices, both[::-1], camera=cam, colors=colors, lighting=FLAT)
    np.testing.assert_array_equal(first, second)
    np.testing.assert_array_equal(first[100, 100], [255, 0, 0])
    np.testing.assert_array_equal(first[100, 30], [0, 0, 255])   # only the far square
    behind = _camera(rotation=np.diag([-1.0, 1.0, -1.0]))            # seen from -Z
    np.testing.assert_array_equal(
        render_mesh(vertices, both, camera=behind, colors=colors, lighting=FLAT)[100, 100],
        [0, 0, 255])


@pytest.mark.parametrize("kind", ["rgb", "uint8", "scalar"])
def test_constant_colour_field_renders_that_colour_where_lit(kind, raster_by):
    vertices, faces = _grid()
    light = Lighting(direction=(0, 0, 1), ambient=0.3, diffuse=0.6, specular=0.0)
    rgb = np.array([0.2, 0.7, 0.4])
    if kind == "scalar":
        colors = np.full(len(vertices), 0.3)
        rgb = np.array(matplotlib.colormaps["plasma"](0.3)[:3])
    elif kind == "uint8":
        colors, rgb = np.tile(np.round(rgb * 255).astype(np.uint8), (len(vertices), 1)), \
            np.round(rgb * 255) / 255
    else:
        colors = np.tile(rgb, (len(vertices), 1))
    image = render_mesh(vertices, faces, camera=_camera(), colors=colors, cmap="plasma",
                        vmin=0.0, vmax=1.0, lighting=light)
    inner = image[60:140, 60:140].reshape(-1, 3).astype(float)
    expected = 255 * rgb * (0.3 + 0.6)
    assert np.abs(inner - expected).max() <= RENDER_RGB_LEVELS


def test_plane_facing_the_light_is_brighter_than_one_at_60_degrees(raster_by):
    light = Lighting(direction=(0, 0, 1), ambient=0.2, diffuse=0.8, specular=0.0)
    vertices, faces = _square()
    c, s = np.cos(np.radians(60)), np.sin(np.radians(60))
    tilted = vertices @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]]).T
    white = np.ones((4, 3))
    facing = render_mesh(vertices, faces, camera=_camera(), colors=white, lighting=light)
    at_60 = render_mesh(tilted, faces, camera=_camera(), colors=white, lighting=light)
    assert facing[100, 100, 0] > at_60[100, 100, 0]
    np.testing.assert_allclose(facing[100, 100], 255 * (0.2 + 0.8), atol=RENDER_RGB_LEVELS)
    np.testing.assert_allclose(at_60[100, 100], 255 * (0.2 + 0.8 * 0.5), atol=RENDER_RGB_LEVELS)


# ---------------------------------------------------------------- camera and framing

def test_given_normals_are_the_ones_shaded(ict_mesh):
    """The vertex normals given (made once for a mesh seen from several views) render the
    image they would make themselves; other normals shade it otherwise."""
    normals = vertex_normals(ict_mesh.vertices, ict_mesh.faces)
    for view in ("front", "side"):
        own = render_mesh(ict_mesh.vertices, ict_mesh.faces, view=view, size=(160, 200))
        given = render_mesh(ict_mesh.vertices, ict_mesh.faces, view=view, size=(160, 200),
                            normals=normals)
        np.testing.assert_array_equal(given, own)
    flipped = render_mesh(ict_mesh.vertices, ict_mesh.faces, size=(160, 200),
                          normals=np.roll(normals, 1, axis=1))
    assert np.any(flipped != own)


def test_shared_framing_puts_unchanged_vertices_at_the_same_pixels():
    base, faces = _grid()
    moved = base.copy()
    moved[-1] += [1.5, 0.8, 0.0]             # one corner pulled out: a different bounding box
    colors = base[:, 0] + 2 * base[:, 1]     # pixels carry the vertex positions
    kwargs = dict(colors=colors, vmin=-3, vmax=3, lighting=FLAT)
    cam = Camera.fit([base, moved], size=(240, 200))
    a = render_mesh(base, faces, camera=cam, **kwargs)
    b = render_mesh(moved, faces, camera=cam, **kwargs)
    xy = cam.project(base[:50])[:, :2]       # rows far from the moved corner
    rows, cols = xy[:, 1].astype(int).clip(0, 199), xy[:, 0].astype(int).clip(0, 239)
    np.testing.assert_array_equal(a[rows, cols], b[rows, cols])
    alone = render_mesh(base, faces, size=(240, 200), **kwargs)    # framed on its own
    assert np.any(alone[rows, cols] != a[rows, cols])
    pa, pb = cam.project(base), cam.project(moved)
    np.testing.assert_array_equal(pa[:-1], pb[:-1])


def test_camera_projection_formula():
    rng = np.random.default_rng(3)
    rot = trimesh.transformations.random_rotation_matrix(rand=rng.random(3))[:3, :3]
    cam = Camera(rotation=rot, centre=[1.0, 2.0, 3.0], scale=7.5, size=(320, 240))
    p = rng.normal(size=(20, 3))
    q = (p - [1.0, 2.0, 3.0]) @ rot.T
    expected = np.column_stack([160 + 7.5 * q[:, 0], 120 - 7.5 * q[:, 1], q[:, 2]])
    np.testing.assert_allclose(cam.project(p), expected, atol=EXACT_FLOAT64)


@pytest.mark.parametrize("view", VIEWS)
def test_fit_frames_the_bounding_box_inside_the_margin(view):
    vertices = np.random.default_rng(4).normal(size=(200, 3)) * [3, 5, 2]
    cam = Camera.fit(vertices, view=view, size=(300, 200), margin=0.1)
    xy = cam.project(vertices)[:, :2]
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    assert np.all(lo >= [30 - RENDER_EXACT_PX,
                         20 - RENDER_EXACT_PX]) and np.all(hi <= [270 + RENDER_EXACT_PX,
                                                                  180 + RENDER_EXACT_PX])
    assert np.isclose(hi[0] - lo[0], 240) or np.isclose(hi[1] - lo[1], 160)
    np.testing.assert_allclose((lo + hi) / 2, [150, 100])


def test_front_view_keeps_plus_x_on_the_viewer_right():
    cam = Camera.fit(np.array([[-1.0, 0, 0], [1.0, 0, 0], [0, 1, 0]]), size=(100, 100))
    x, y = cam.project([[1.0, 0, 0], [0, 1, 0]])[:, :2].T
    assert x[0] > 50 and y[1] < 50


@pytest.mark.parametrize("supersample", [1, 2])
def test_points_are_drawn_where_the_camera_projects_them(supersample):
    vertices, faces = _square(z=-5.0, half=0.1)
    cam = _camera(size=(160, 120), scale=10.0)
    points = np.array([[-3.3, 2.1, 0.0], [2.45, -1.7, 0.0], [np.nan, np.nan, np.nan]])
    image = render_mesh(vertices, faces, camera=cam, points=points, point_colors=[0.0, 1.0, 0.0],
                        point_radius=3.0, supersample=supersample)
    green = (image[:, :, 1] > 200) & (image[:, :, 0] < 60)
    for x, y, _ in cam.project(points[:2]):
        blob = green[int(y) - 5:int(y) + 6, int(x) - 5:int(x) + 6]
        rows, cols = np.nonzero(blob)
        assert green[int(y), int(x)]
        assert abs(rows.mean() + int(y) - 5 + 0.5 - y) < RENDER_POINT_CENTRE_PX
        assert abs(cols.mean() + int(x) - 5 + 0.5 - x) < RENDER_POINT_CENTRE_PX


@pytest.mark.parametrize("hidden", HIDDEN_POINTS)
def test_points_behind_the_mesh(hidden, raster_by):
    vertices, faces = _square(z=0.0)
    points = np.array([[0.0, 0.0, -1.0]])                    # behind the square
    cam = _camera()
    xy = cam.project(points)[:, :2].astype(int)
    plain = render_mesh(vertices, faces, camera=cam, lighting=FLAT)[xy[0, 1], xy[0, 0]]
    image = render_mesh(vertices, faces, camera=cam, points=points, lighting=FLAT,
                        point_colors=[0, 0, 1.0], point_radius=3.0, hidden_points=hidden)
    back = image[xy[0, 1], xy[0, 0]]
    expected = {"hide": plain, "dim": 255 * (0.65 + 0.35 * np.array([0, 0, 1.0])),
                "show": [0, 0, 255]}[hidden]
    np.testing.assert_allclose(back, expected, atol=RENDER_POINT_RGB_LEVELS)


def test_point_in_front_hides_point_behind():
    vertices, faces = _square(z=-9.0, half=0.1)
    points = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]])
    image = render_mesh(vertices, faces, camera=_camera(), points=points,
                        point_colors=[[0, 0, 1.0], [1.0, 0, 0]])
    np.testing.assert_array_equal(image[100, 100], [255, 0, 0])


# ---------------------------------------------------------------- outputs

@pytest.mark.parametrize("size", [(64, 48), (33, 77)])
@pytest.mark.parametrize("supersample", [1, 2, 4])
def test_shape_and_dtype(size, supersample):
    vertices, faces = _square()
    before = vertices.copy()
    image = render_mesh(vertices, faces, size=size, supersample=supersample)
    assert image.shape == (size[1], size[0], 3) and image.dtype == np.uint8
    np.testing.assert_array_equal(vertices, before)
    assert (image[0, 0] == WHITE).all()


def test_nan_scalars_render_grey_and_empty_faces_render_white(raster_by):
    vertices, faces = _grid()
    colors = np.full(len(vertices), np.nan)
    image = render_mesh(vertices, faces, camera=_camera(), colors=colors, lighting=FLAT)
    assert np.ptp(image[100, 100]) == 0 and image[100, 100, 0] < 200
    blank = render_mesh(vertices, np.zeros((0, 3), int), camera=_camera())
    assert (blank == 255).all()


def test_save_png_round_trip(tmp_path):
    image = np.random.default_rng(5).integers(0, 256, (20, 30, 3), dtype=np.uint8)
    path = tmp_path / "a.png"
    save_png(image, path)
    np.testing.assert_array_equal(cv2.imread(str(path))[:, :, ::-1], image)
    assert [p.name for p in tmp_path.iterdir()] == ["a.png"]


def test_image_grid_places_images_and_captions():
    a = np.zeros((20, 30, 3), np.uint8)
    b = np.full((10, 10, 3), 100, np.uint8)
    grid = image_grid([a, b, a], ["a", "b", ""], ncols=2, pad=4)
    caption = cv2.getTextSize("Ag", cv2.FONT_HERSHEY_SIMPLEX, 0.6, 1)
    cap = caption[0][1] + caption[1] + 6
    assert grid.shape == (4 + 2 * (20 + cap + 4), 4 + 2 * (30 + 4), 3)
    np.testing.assert_array_equal(grid[4:24, 4:34], a)
    np.testing.assert_array_equal(grid[4 + 5:4 + 15, 38 + 10:38 + 20], b)
    assert (grid[24:24 + cap, 4:34] < 128).any()          # caption "a" is drawn


def test_colorbar_runs_from_vmin_at_the_bottom_to_vmax_at_the_top():
    bar = colorbar(vmin=0.0, vmax=2.0, cmap="viridis", height=200, width=90)
    viridis = matplotlib.colormaps["viridis"]
    np.testing.assert_allclose(bar[-9, 10], np.array(viridis(0.0)[:3]) * 255,
                               atol=RENDER_RGB_LEVELS)
    np.testing.assert_allclose(bar[8, 10], np.array(viridis(1.0)[:3]) * 255,
                               atol=RENDER_RGB_LEVELS)


# ---------------------------------------------------------------- errors

GOOD_V, GOOD_F = _square()


@pytest.mark.parametrize("kwargs, match", [
    (dict(vertices=np.where(np.eye(4, 3) > 0, np.nan, GOOD_V)), "vertices contains NaN"),
    (dict(vertices=np.zeros((0, 3))), "vertices is empty"),
    (dict(faces=[[0, 1, 4]]), r"faces must hold vertex ids in \[0, 4\)"),
    (dict(faces=[[0.0, 1.0, 2.0]]), "faces must be an integer array"),
    (dict(faces=[[0, 1, 2, 3]]), r"faces must be an integer array of shape \(F, 3\)"),
    (dict(view="top"), "view must be one of"),
    (dict(view=np.diag([1.0, 1.0, -1.0])), "view must be one of .* rotation matrix"),
    (dict(size=(0, 10)), r"size\[0\] \(width\) must be at least 1"),
    (dict(size=100), r"size must be \(width, height\)"),
    (dict(camera=_camera(), size=(10, 10)), "disagrees with camera.size"),
    (dict(camera="front"), "camera must be a mocap.viz.render.Camera"),
    (dict(colors=np.zeros(3)), r"colors must have shape \(4,\) .* or \(4, 3\)"),
    (dict(colors=np.full((4, 3), 2.0)), r"colors must be RGB in \[0, 1\]"),
    (dict(cmap="no-such-map"), "is not a matplotlib colour map"),
    (dict(supersample=0), "supersample must be at least 1"),
    (dict(hidden_points="maybe"), "hidden_points must be one of"),
    (dict(points=np.zeros((2, 2))), r"points must have shape \(any, 3\)"),
    (dict(points=np.zeros((2, 3)), point_colors=np.zeros((3, 3))),
     r"point_colors must have shape \(3,\) or \(2, 3\)"),
    (dict(lighting=(0, 0, 1)), "lighting must be a mocap.viz.render.Lighting"),
    (dict(normals=np.zeros((3, 3))), r"normals must have shape \(4, 3\)"),
    (dict(normals=np.full((4, 3), np.nan)), "normals contains NaN"),
])
def test_render_errors(kwargs, match):
    args = dict(vertices=GOOD_V, faces=GOOD_F) | kwargs
    with pytest.raises(InputError, match=match):
        render_mesh(args.pop("vertices"), args.pop("faces"), **args)


@pytest.mark.parametrize("build, match", [
    (lambda: Camera.fit(GOOD_V, margin=0.5), r"margin must be in \[0, 0.5\)"),
    (lambda: Camera.fit([GOOD_V, np.full((2, 3), np.nan)]), r"vertices\[1\] contains NaN"),
    (lambda: Camera(np.eye(3), np.zeros(3), -1.0, (10, 10)), "scale must be positive"),
    (lambda: Lighting(direction=(0, 0, 0)), "direction must be a non-zero vector"),
    (lambda: Lighting(ambient=-0.1), "ambient must be a non-negative number"),
    (lambda: Lighting(shininess=0), "shininess must be positive"),
    (lambda: save_png(np.zeros((4, 4, 3)), "x.png"), "image must be a uint8 RGB image"),
    (lambda: image_grid([]), "images is empty"),
    (lambda: image_grid([np.zeros((2, 2, 3), np.uint8)], ["a", "b"]), "labels has 2 entries"),
    (lambda: colorbar(vmin=0, vmax=np.inf), "vmin and vmax must be finite"),
])
def test_other_errors(build, match):
    with pytest.raises(InputError, match=match):
        build()


def test_save_png_refuses_a_missing_directory(tmp_path):
    with pytest.raises(InputError, match="cannot write: directory"):
        save_png(np.zeros((4, 4, 3), np.uint8), tmp_path / "nope" / "a.png")


# ---------------------------------------------------------------- real face

@pytest.fixture(scope="module")
def ict_smile(ict_expressions_dir):
    """The ICT mouthSmile_L expression as a Mesh (cm)."""
    return load_mesh(ict_expressions_dir / "mouthSmile_L.obj", units="cm")


def test_ict_face_front_view_has_no_holes_and_faces_the_viewer(ict_mesh, raster_by):
    neutral = ict_mesh
    cam = Camera.fit(neutral.vertices, size=(300, 300)).zoomed(1)
    proj = cam.project(neutral.vertices)
    frags = _raster.rasterize(proj[:, :2], proj[:, 2], neutral.faces, 300, 300)
    covered = np.zeros(300 * 300, bool)
    covered[frags.pixel] = True
    covered = covered.reshape(300, 300)
    # no speckle: no background pixel with all four neighbours covered
    inner = covered[1:-1, 1:-1]
    nbrs = covered[:-2, 1:-1] & covered[2:, 1:-1] & covered[1:-1, :-2] & covered[1:-1, 2:]
    assert not np.any(~inner & nbrs)
    # the skin seen from the front faces the viewer (normals not inverted)
    assert frags.front[frags.face].mean() > 0.97


def test_ict_left_smile_is_on_the_viewer_right(ict_mesh, ict_smile, raster_by):
    neutral, smile = ict_mesh, ict_smile
    error = np.linalg.norm(smile.vertices - neutral.vertices, axis=1)
    image = render_mesh(smile.vertices, smile.faces, size=(200, 200), colors=error,
                        cmap="gray", vmin=0.0, vmax=error.max(), lighting=FLAT)
    hot = (image[:, :, 0] > 128) & np.any(image != 255, axis=2)    # bright, not background
    cols = np.nonzero(hot)[1]
    assert len(cols) > 20 and cols.mean() > 110


@pytest.mark.parametrize("colours", ["clay", "rgb", "scalars"])
@pytest.mark.parametrize("view", VIEWS)
def test_the_compiled_render_is_numpys(ict_mesh, ict_smile, monkeypatch, colours, view):
    """The compiled scan and shading against NumPy's batches of fragments (the oracle), on
    the ICT face smiling: the same depth and triangle at every pixel, bit for bit, and the
    same picture but where the specular power's last bit moves a pixel's 8-bit level."""
    vertices, faces = ict_smile.vertices, ict_smile.faces
    moved = np.linalg.norm(vertices - ict_mesh.vertices, axis=1)
    moved[::53] = np.nan                                    # grey vertices among the scalars
    colors = {"clay": None, "scalars": moved,
              "rgb": np.random.default_rng(2).uniform(0, 1, vertices.shape)}[colours]
    cam = Camera.fit(vertices, view=view, size=(216, 248))
    proj = cam.zoomed(2).project(vertices)
    planes = _raster._Planes.of(proj[:, :2], proj[:, 2], faces)

    def both(function):
        got = {}
        for way in ("compiled", "numpy"):
            with monkeypatch.context() as patch:
                kernel_or_numpy(way, patch, _raster, "_compiled_kernels",
                                "_TRIANGLES_WORTH_COMPILING")
                got[way] = function()
        return got["compiled"], got["numpy"]
    (zbuf, fbuf), (zbuf_np, fbuf_np) = both(lambda: planes.zbuffer(*cam.zoomed(2).size))
    np.testing.assert_array_equal(zbuf, zbuf_np)
    np.testing.assert_array_equal(fbuf, fbuf_np)
    assert (fbuf >= 0).mean() > 0.2
    image, image_np = both(lambda: render_mesh(
        vertices, faces, camera=cam, colors=colors, vmin=0.0, vmax=float(np.nanmax(moved)),
        points=vertices[::300], hidden_points="dim"))
    levels = np.abs(image.astype(int) - image_np.astype(int))
    assert levels.max() <= RENDER_KERNEL_LEVELS
    assert (levels > 0).any(axis=2).mean() <= RENDER_KERNEL_PIXELS


def test_numba_without_a_cache_folder_renders_with_numpy_and_a_warning(monkeypatch):
    """numba raises RuntimeError when it can write its compiled code nowhere (a read-only
    install and home): NumPy renders, with a warning saying so, the same picture."""
    vertices, faces = _grid()
    expected = render_mesh(vertices, faces, camera=_camera())
    monkeypatch.setattr(_raster, "_TRIANGLES_WORTH_COMPILING", 0)
    numba_cannot_cache(monkeypatch, "mocap.viz._raster_kernel")
    _raster._compiled_kernels.cache_clear()
    try:
        with pytest.warns(UserWarning, match="compiled mesh rasterizer is off .*no locator"):
            got = render_mesh(vertices, faces, camera=_camera())
        assert _raster._compiled_kernels() is None
    finally:
        monkeypatch.undo()
        _raster._compiled_kernels.cache_clear()
    np.testing.assert_array_equal(got, expected)


def test_compiled_renders_loads_numba_only_for_work_that_pays_for_it():
    """In a process that has not loaded numba, a few small renders leave it unloaded (NumPy
    draws them); a video's worth of renders loads it, and render_mesh then uses it."""
    script = (
        "import sys\n"
        "from mocap.viz import _raster\n"
        "from mocap.viz.render import compiled_renders\n"
        "small = compiled_renders(3, 1000)\n"
        "loaded_small = 'numba' in sys.modules\n"
        "large = compiled_renders(300, 18460)\n"
        "print(small, loaded_small, large, 'numba' in sys.modules,"
        " _raster.kernels_for(1) is not None)\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         check=True, cwd=Path(__file__).resolve().parents[1])
    assert out.stdout.split() == ["False", "False", "True", "True", "True"]
    with pytest.raises(InputError, match="n_renders"):
        compiled_renders(-1, 10)
