"""The Maskle: asset round trip, placement, geometry kernels vs oracles, transfer invariance."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from helpers import ICT_LANDMARKS_TOML
from scipy.optimize import linprog
from tolerances import (
    EXACT_FLOAT64,
    FEW_ULPS,
    MASKLE_LANDMARK_CM,
    MASKLE_LIP_LEAK,
    MASKLE_PAINT,
    MASKLE_PARTING_CM,
    MASKLE_SIMILAR_HITS,
    MASKLE_SIMILAR_PLACED,
    MASKLE_SIMILAR_SCALE_REL,
    MASKLE_SIMILAR_WEIGHTS,
    MESH_EXACT,
)

from basis.maskle import (
    CHANNEL_KINDS,
    FIT_STATUSES,
    Mask,
    fit_mask,
    landmark_points,
    load_default_mask,
    load_mask,
    maskle_weights,
    paint_mask,
    save_mask,
    shepard_coefficients,
    smoothing_operator,
    transfer_operator,
)
from basis.maskle._geometry import TriangleIndex, nearest_ray_hits, triangles_intersect
from basis.maskle.build_default import BONES, build_default_mask
from basis.maskle.gold import LIP_SIDES, mouth_sides
from fit.cli.main import main
from mocap.anatomy import MASKLE_POINTS
from mocap.errors import FileFormatError, InputError
from mocap.markerset import REQUIRED_REGIONS


@pytest.fixture(scope="module")
def mask():
    return build_default_mask()


def _random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q * np.linalg.det(q)


# --- asset -----------------------------------------------------------------------------

def test_default_mask_file_is_the_built_mask(mask):
    shipped = load_default_mask()
    np.testing.assert_array_equal(shipped.vertices, mask.vertices)
    np.testing.assert_array_equal(shipped.weights, mask.weights)
    assert set(REQUIRED_REGIONS) <= set(shipped.channel_names)
    regions = shipped.weights[:, [shipped.channel_names.index(r) for r in REQUIRED_REGIONS]]
    np.testing.assert_allclose(regions.sum(axis=1), 1.0, atol=EXACT_FLOAT64)


def test_mask_round_trip(mask, tmp_path):
    path = tmp_path / "m.npz"
    save_mask(mask, path)
    back = load_mask(path)
    for name in ("vertices", "polygons", "weights", "origins", "tongue_root", "tongue_tip"):
        np.testing.assert_array_equal(getattr(back, name), getattr(mask, name))
    assert back.channel_names == mask.channel_names
    assert back.channel_kinds == mask.channel_kinds
    assert back.landmarks == mask.landmarks


def test_mask_landmarks_are_the_maskle_points(mask):
    assert set(mask.landmarks) == set(MASKLE_POINTS)
    assert set(mask.channel_kinds) <= set(CHANNEL_KINDS)


@pytest.mark.parametrize("change, match", [
    (dict(weights="over"), "mask weights must lie in"),
    (dict(landmarks="drop"), "mask lacks landmarks"),
    (dict(channel_kinds="bad"), "channel kind 'muscle' unknown"),
    (dict(polygons="out"), "index vertices outside"),
])
def test_mask_validation(mask, change, match):
    kw = dict(vertices=mask.vertices, polygons=mask.polygons, channel_names=mask.channel_names,
              channel_kinds=mask.channel_kinds, weights=mask.weights, origins=mask.origins,
              landmarks=dict(mask.landmarks), tongue_root=mask.tongue_root,
              tongue_tip=mask.tongue_tip)
    if "weights" in change:
        kw["weights"] = mask.weights + 0.5
    if "landmarks" in change:
        kw["landmarks"].pop("eye_inner_left")
    if "channel_kinds" in change:
        kw["channel_kinds"] = ("muscle",) + mask.channel_kinds[1:]
    if "polygons" in change:
        kw["polygons"] = mask.polygons + mask.n_vertices
    with pytest.raises(InputError, match=match):
        Mask(**kw)


def test_lip_bands_are_the_two_sides_of_the_lip_line(mask):
    upper, lower = mask.lip_bands
    x, y, _ = mask.vertices.T
    mouth = y < 3.0                                  # template cm: below the eye patches
    line = -0.15 * (x / 2.5) ** 2                    # the builder's lip line
    np.testing.assert_array_equal(upper, mouth & (y > line))
    np.testing.assert_array_equal(lower, mouth & (y < line))
    assert upper[mask.tongue_tip].sum() == lower[mask.tongue_tip].sum() > 0


def test_tongue_seam_pairs_the_strips_column_by_column(mask):
    """The builder's strips: same columns, upper 0.02 cm above and lower 0.02 cm below the lip line."""
    seam = mask.tongue_seam
    upper, lower = mask.lip_bands
    assert len(seam) == len(mask.tongue_root)              # each root and each tip paired once
    assert upper[seam[:, 0]].all() and lower[seam[:, 1]].all()
    gap = mask.vertices[seam[:, 0]] - mask.vertices[seam[:, 1]]
    np.testing.assert_allclose(gap, np.tile([0.0, 0.04, 0.0], (len(seam), 1)), atol=EXACT_FLOAT64)
    tongue = np.union1d(mask.tongue_root, mask.tongue_tip)
    np.testing.assert_array_equal(np.sort(seam.ravel()), tongue)


def test_paint_reproduces_weights_the_mask_can_carry(ict_mesh, ict_landmarks, mask):
    """Face weights made by transferring a band-limited mask channel are painted back."""
    mesh, marks = ict_mesh, ict_landmarks
    fit = fit_mask(mask, mesh, marks)
    upper, lower = mask.lip_bands
    k = mask.channel_names.index("upper_lip_left")
    want = transfer_operator(mask, fit, mesh).apply(mask.weights[:, [k]])
    truth = mask.with_weights(np.where(np.arange(len(mask.channel_names)) == k, 0.0,
                                       mask.weights))
    painted = paint_mask(truth, fit, mesh, want, ["upper_lip_left"], support=~lower[:, None],
                         regularization=1e-6)
    got = transfer_operator(painted, fit, mesh).apply(painted.weights[:, [k]])
    hit = ~np.isnan(want[:, 0])
    assert np.abs(got[hit] - want[hit]).max() < MASKLE_PAINT
    assert np.all(painted.weights[lower, k] == 0) and painted.weights[upper, k].max() > 0.9
    with pytest.raises(InputError, match="support must have shape"):
        paint_mask(truth, fit, mesh, want, ["upper_lip_left"], support=upper)


def test_load_mask_rejects_other_files(tmp_path):
    path = tmp_path / "x.npz"
    np.savez(path, a=np.zeros(3))
    with pytest.raises(FileFormatError, match="not a mask file"):
        load_mask(path)


# --- geometry kernels ------------------------------------------------------------------

def _lp_intersect(a, b) -> bool:
    """Oracle: do convex hulls of two triangles meet? (feasibility LP on barycentrics)."""
    a_eq = np.zeros((5, 6))
    a_eq[:3, :3], a_eq[:3, 3:] = a.T, -b.T
    a_eq[3, :3] = a_eq[4, 3:] = 1
    res = linprog(np.zeros(6), A_eq=a_eq, b_eq=[0, 0, 0, 1, 1], bounds=(0, None),
                  method="highs")
    return res.status == 0


def test_triangle_intersection_matches_lp_oracle():
    rng = np.random.default_rng(3)
    a = rng.random((300, 3, 3))
    b = rng.random((300, 3, 3)) * 0.8 + 0.1
    got = triangles_intersect(a, b)
    want = np.array([_lp_intersect(x, y) for x, y in zip(a, b)])
    np.testing.assert_array_equal(got, want)
    assert 20 < got.sum() < 280        # both outcomes are exercised


def test_ray_hits_match_trimesh():
    rng = np.random.default_rng(4)
    sphere = trimesh.creation.icosphere(subdivisions=2)
    tri = sphere.vertices[sphere.faces]
    origins = rng.normal(size=(200, 3)) * 0.3
    dirs = rng.normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    face, t = nearest_ray_hits(origins, dirs, TriangleIndex(tri), 10.0)
    inter = trimesh.ray.ray_triangle.RayMeshIntersector(sphere)
    for sign in (1, -1):
        loc, ray, _ = inter.intersects_location(origins, sign * dirs, multiple_hits=False)
        dist = np.full(len(origins), np.inf)
        dist[ray] = np.linalg.norm(loc - origins[ray], axis=1)
        if sign == 1:
            best = dist
        else:
            best = np.minimum(best, dist)
    assert np.all(face >= 0)
    np.testing.assert_allclose(np.abs(t), best, atol=MESH_EXACT)


def test_facing_ray_hits_take_the_surface_facing_the_ray():
    """From inside a sphere, only the exit point faces the ray (outward normals)."""
    rng = np.random.default_rng(9)
    sphere = trimesh.creation.icosphere(subdivisions=2)
    origins = rng.uniform(-0.5, 0.5, size=(200, 3))           # inside the unit sphere
    dirs = rng.normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    index = TriangleIndex(sphere.vertices[sphere.faces])
    face, t = nearest_ray_hits(origins, dirs, index, 10.0, min_cosine=0.0)
    inter = trimesh.ray.ray_triangle.RayMeshIntersector(sphere)
    loc, ray, tri = inter.intersects_location(origins, dirs, multiple_hits=False)
    assert np.all(face >= 0) and np.all(t > 0)
    np.testing.assert_allclose(t[ray], np.linalg.norm(loc - origins[ray], axis=1),
                               atol=MESH_EXACT)
    np.testing.assert_array_equal(face[ray], tri)
    assert len(ray) == len(origins)
    either = nearest_ray_hits(origins, dirs, index, 10.0)[1]     # the nearer of both exits
    assert 50 < (either < 0).sum() < 150


def test_rays_that_meet_nothing_are_misses():
    """Lines beside a sphere, inside its index box: no hit (and no error)."""
    sphere = trimesh.creation.icosphere(subdivisions=1)
    origins = np.array([[1.5, 0.0, 0.0], [0.0, -1.2, 0.3]])
    dirs = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    face, t = nearest_ray_hits(origins, dirs, TriangleIndex(sphere.vertices[sphere.faces]), 10.0)
    np.testing.assert_array_equal(face, -1)
    assert np.isnan(t).all()


def test_shepard_reproduces_corners_and_constants():
    rng = np.random.default_rng(5)
    corners = rng.random((50, 4, 3))
    valid = np.ones((50, 4), bool)
    valid[::3, 3] = False
    coef = shepard_coefficients(corners[:, 1], corners, valid)
    np.testing.assert_array_equal(coef, np.eye(4)[np.ones(50, int)])
    points = rng.random((50, 3))
    coef = shepard_coefficients(points, corners, valid)
    np.testing.assert_allclose(coef @ np.ones(4), 1.0, atol=FEW_ULPS)
    assert np.all(coef[~valid] == 0)


def test_smoothing_keeps_unit_interval_and_constants():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    rng = np.random.default_rng(6)
    defined = rng.random(len(sphere.vertices)) < 0.8
    op = smoothing_operator(sphere.faces, defined, iterations=5)
    w = rng.random(len(defined))
    out = op @ w
    assert out.min() >= 0 and out.max() <= 1
    np.testing.assert_allclose(op @ np.ones(len(defined)), 1.0, atol=EXACT_FLOAT64)
    np.testing.assert_array_equal(out[~defined], w[~defined])   # undefined untouched


# --- fitting and transfer on the ICT face --------------------------------------------

def test_placement_maps_landmarks_on_a_scaled_face(ict_mesh, ict_landmarks, mask):
    mesh, marks = ict_mesh, ict_landmarks
    fit = fit_mask(mask, mesh, marks, max_iterations=1)
    copy = mesh.with_vertices(mesh.vertices * 2.5 + [3.0, -1.0, 7.0])
    fit2 = fit_mask(mask, copy, marks, max_iterations=1)
    assert fit2.scale == pytest.approx(2.5 * fit.scale, rel=MASKLE_SIMILAR_SCALE_REL)
    np.testing.assert_allclose(fit2.placed, fit.placed * 2.5 + [3.0, -1.0, 7.0],
                               atol=MASKLE_SIMILAR_PLACED)
    # landmarks land on the face landmarks in the face's plane (in front by the standoff)
    ids = [mask.landmarks[p] for p in MASKLE_POINTS]
    offset = fit.placed[ids] - landmark_points(mesh, marks)
    sideways = offset - np.outer(offset @ fit.forward, fit.forward)
    lip = [MASKLE_POINTS.index("upper_lip_bottom"), MASKLE_POINTS.index("lower_lip_top")]
    others = np.setdiff1d(np.arange(10), lip)
    assert np.abs(sideways[others]).max() < MASKLE_LANDMARK_CM * fit.scale


def test_fit_freezes_every_vertex(ict_mesh, ict_landmarks, mask):
    mesh, marks = ict_mesh, ict_landmarks
    fit = fit_mask(mask, mesh, marks)
    assert fit.status in FIT_STATUSES
    assert fit.status == "all_frozen" and fit.frozen.all()
    # the mask moved back towards the face and stays in front of the face's back
    assert np.all((fit.vertices - fit.placed) @ fit.forward <= EXACT_FLOAT64)


def test_tongue_enters_the_closed_mouth(ict_mesh, ict_landmarks, mask):
    """ICT's lips touch; the tongue slides between them, the lip row reaches the lips."""
    mesh, marks = ict_mesh, ict_landmarks
    fit = fit_mask(mask, mesh, marks)
    contact = (mesh.vertices[marks["upper_lip_bottom"]]
               + mesh.vertices[marks["lower_lip_top"]]) / 2
    depth = (fit.vertices - contact) @ fit.forward / fit.scale         # template cm, + = in front
    assert depth[mask.tongue_tip].max() < -1.0
    assert depth[[mask.landmarks["upper_lip_bottom"], mask.landmarks["lower_lip_top"]]].max() \
        < 0.8


def test_demo_face_lips_keep_their_bones(demo_face, mask):
    """The demo face's mouth is a slit with touching corners (its own topology, mm).

    Reference sides from its mouth loop (:func:`basis.maskle.gold.mouth_sides`,
    which the Maskle never uses): no vertex clearly on one side may get more than
    0.1 of a bone of the other lip. When the two tongue strips parted while the
    mask shrank (1.3 mm here), lower-lip vertices by the corners saw neither
    band through the parting and read the upper strip: 9 crossings with this
    analytic paint, 3 with the bench's painted mask.
    """
    demo = demo_face
    fit = fit_mask(mask, demo.mesh, demo.landmarks)
    seam = mask.tongue_seam
    to_template = (fit.vertices - fit.translation) @ fit.rotation / fit.scale
    parting = to_template[seam[:, 0], :2] - to_template[seam[:, 1], :2]
    assert np.linalg.norm(parting,
                          axis=1).max() < MASKLE_PARTING_CM          # template cm; placed 0.04
    w = transfer_operator(mask, fit, demo.mesh).apply(mask.weights)
    side = mouth_sides(demo.mesh, demo.landmarks)
    lip = {s: [mask.channel_names.index(b) for b in BONES if LIP_SIDES.get(b) == s]
           for s in ("upper", "lower")}
    hit = ~np.isnan(w[:, 0])
    upper, lower = hit & (side > 0.9), hit & (side < 0.1)
    assert upper.sum() > 100 and lower.sum() > 100
    assert w[upper][:, lip["lower"]].max() <= MASKLE_LIP_LEAK
    assert w[lower][:, lip["upper"]].max() <= MASKLE_LIP_LEAK


def test_transfer_is_invariant_to_similarity(ict_mesh, ict_landmarks, mask):
    mesh, marks = ict_mesh, ict_landmarks
    rng = np.random.default_rng(8)
    rot = _random_rotation(rng)
    moved = mesh.with_vertices(3.0 * mesh.vertices @ rot.T + [10.0, 2.0, -5.0])
    a = maskle_weights(mesh, marks, mask)
    b = maskle_weights(moved, marks, mask)
    both = a.hit & b.hit
    assert (a.hit != b.hit).sum() <= MASKLE_SIMILAR_HITS * a.hit.sum()
    diff = np.abs(a.weights[both] - b.weights[both])
    assert diff.mean() < MASKLE_SIMILAR_WEIGHTS
    assert a.fit.n_iterations == b.fit.n_iterations
    regions = a.region_masks()
    np.testing.assert_allclose(regions[a.hit].sum(axis=1), 1.0, atol=EXACT_FLOAT64)
    assert np.isnan(regions[~a.hit]).all()
    assert np.all((a.weights[a.hit] >= 0) & (a.weights[a.hit] <= 1))


def test_missing_landmark_is_an_error(ict_mesh, ict_landmarks, mask):
    mesh, marks = ict_mesh, ict_landmarks
    partial = {k: v for k, v in marks.items() if k != "mouth_corner_left"}
    with pytest.raises(InputError, match="face landmarks lack mouth_corner_left"):
        fit_mask(mask, mesh, partial)


def test_coincident_landmarks_are_an_error(ict_mesh, ict_landmarks, mask):
    mesh, marks = ict_mesh, ict_landmarks
    same = {p: marks["nose_tip"] for p in MASKLE_POINTS}
    with pytest.raises(InputError, match="collinear or coincident"):
        fit_mask(mask, mesh, same)


def test_bad_option_is_an_error(ict_mesh, ict_landmarks, mask):
    mesh, marks = ict_mesh, ict_landmarks
    with pytest.raises(InputError, match="b must be positive"):
        fit_mask(mask, mesh, marks, b=0.0)
    fit = fit_mask(mask, mesh, marks, max_iterations=1)
    with pytest.raises(InputError, match=r"min_facing must lie in \[-1, 1\), got 1.0"):
        transfer_operator(mask, fit, mesh, min_facing=1.0)
    with pytest.raises(InputError, match="min_facing must be a numeric array"):
        transfer_operator(mask, fit, mesh, min_facing="facing")


def test_region_masks_need_regions(mask):
    from basis.maskle import MaskleWeights
    w = MaskleWeights(("jaw",), ("bone",), np.zeros((3, 1)), np.ones(3, bool),
                      np.zeros(0, np.int64))
    with pytest.raises(InputError, match="paints no region"):
        w.region_masks()


# --- command line ----------------------------------------------------------------------

def test_cli_writes_weights(ict_mesh, ict_neutral_path, tmp_path, capsys):
    out, csv, png = tmp_path / "w.npz", tmp_path / "w.csv", tmp_path / "w.png"
    mesh_path = str(ict_neutral_path)
    assert main(["maskle", mesh_path, "--landmarks", str(ICT_LANDMARKS_TOML), "-o", str(out),
                 "--csv", str(csv), "--picture", str(png)]) == 0
    with np.load(out) as doc:
        weights, hit, regions = doc["weights"], doc["hit"], doc["region_masks"]
    assert weights.shape == (ict_mesh.n_vertices, len(load_default_mask().channel_names))
    assert np.isnan(weights[~hit]).all() and not np.isnan(weights[hit]).any()
    np.testing.assert_allclose(regions[hit].sum(axis=1), 1.0, atol=EXACT_FLOAT64)
    rows = csv.read_text().splitlines()
    assert len(rows) == ict_mesh.n_vertices + 1 and png.stat().st_size > 0


def test_cli_bad_landmarks_exit_1(ict_neutral_path, tmp_path, capsys):
    bad = tmp_path / "l.toml"
    bad.write_text("[landmarks]\nnose_tip = 4857\n")
    mesh_path = str(ict_neutral_path)
    assert main(["maskle", mesh_path, "--landmarks", str(bad), "-o",
                 str(tmp_path / "o.npz")]) == 1
    assert "face landmarks lack" in capsys.readouterr().err


def test_cli_output_must_be_npz(ict_neutral_path, tmp_path, capsys):
    mesh_path = str(ict_neutral_path)
    assert main(["maskle", mesh_path, "--landmarks", str(ICT_LANDMARKS_TOML), "-o",
                 str(tmp_path / "o.txt")]) == 1
    assert "must be an .npz file" in capsys.readouterr().err
