"""The RBF retargeting operator against scipy, exact fields, and brute-force loops."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.sparse as sp
import threadpoolctl
from helpers import slit_grid
from scipy.interpolate import BSpline, RBFInterpolator
from scipy.spatial.distance import cdist
from tolerances import (
    EXACT_FLOAT64,
    FEW_ULPS,
    RBF_ACROSS_CUT,
    RBF_AFFINE_EXACT,
    RBF_AFFINE_ICT_CM,
    RBF_APPLY_FLOAT32,
    RBF_REGION_SUM,
    RBF_RETILED_EPS,
    RBF_VS_SCIPY_RTOL,
)

from mocap import InputError
from mocap.mesh.regions import painted_region_weights, region_weights
from mocap.retarget._kernels import COMPACT_KERNELS, KERNELS, MIN_DEGREE, evaluate
from mocap.retarget.rbf import _interleave, build_rbf_operator

SCIPY_KERNELS = tuple(k for k in KERNELS if k not in COMPACT_KERNELS)
RNG = np.random.default_rng(11)
CENTERS = RNG.uniform(-1.0, 1.0, (25, 3))
POINTS = RNG.uniform(-1.2, 1.2, (150, 3))


def _surface(faces, vertex_ids):
    """center_faces/center_bary at vertices: closest-point lookup cannot tell the two
    sides of a cut apart, so the tests on the slit grid locate centers explicitly."""
    face_ids = np.array([np.flatnonzero((faces == v).any(axis=1))[0] for v in vertex_ids])
    bary = (faces[face_ids] == np.asarray(vertex_ids)[:, None]).astype(float)
    return {"center_faces": face_ids, "center_bary": bary}


def _dense(matrix):
    return matrix.toarray() if sp.issparse(matrix) else matrix


def _degrees(kernel):
    low = MIN_DEGREE.get(kernel, 0)
    return [None, -1] + list(range(low, 3))


@pytest.mark.parametrize("kernel, degree", [(k, d) for k in SCIPY_KERNELS
                                            for d in _degrees(k)])
@pytest.mark.parametrize("smoothing", [0.0, 0.05])
def test_matches_scipy(kernel, degree, smoothing):
    data = RNG.normal(size=(len(CENTERS), 3))
    epsilon = 1.7
    ref = RBFInterpolator(CENTERS, data, kernel=kernel, epsilon=epsilon, degree=degree,
                          smoothing=smoothing)(POINTS)
    op = build_rbf_operator(CENTERS, POINTS, kernel=kernel, epsilon=epsilon, degree=degree,
                            smoothing=smoothing)
    np.testing.assert_allclose(op.matrix @ data, ref,
                               atol=RBF_VS_SCIPY_RTOL * np.abs(ref).max())


@pytest.mark.parametrize("kernel", ["linear", "thin_plate_spline", "cubic"])
def test_default_epsilon_and_degree_match_scipy(kernel):
    data = RNG.normal(size=(len(CENTERS), 2))
    ref = RBFInterpolator(CENTERS, data, kernel=kernel)(POINTS)
    op = build_rbf_operator(CENTERS, POINTS, kernel=kernel)
    assert (op.epsilon, op.degree) == (1.0, max(MIN_DEGREE[kernel], 0))
    np.testing.assert_allclose(op.matrix @ data, ref, atol=RBF_VS_SCIPY_RTOL * np.abs(ref).max())


@pytest.mark.parametrize("kernel, degree", [(k, d) for k in SCIPY_KERNELS for d in (1, 2)
                                            if d >= MIN_DEGREE.get(k, 0)])
def test_affine_fields_reproduced(kernel, degree):
    a, b = RNG.normal(size=(3, 3)), RNG.normal(size=3)
    op = build_rbf_operator(CENTERS, POINTS, kernel=kernel, epsilon=0.9, degree=degree)
    np.testing.assert_allclose(op.matrix @ (CENTERS @ a.T + b), POINTS @ a.T + b,
                               atol=RBF_AFFINE_EXACT)


@pytest.mark.parametrize("kernel", ["thin_plate_spline", "wendland_c2"])
@pytest.mark.parametrize("dtype, atol", [(np.float64, EXACT_FLOAT64), (np.float32,
                                                                       RBF_APPLY_FLOAT32)])
def test_apply_equals_per_frame_loop(kernel, dtype, atol):
    op = build_rbf_operator(CENTERS, POINTS, kernel=kernel, epsilon=0.8)
    d = RNG.normal(size=(23, len(CENTERS), 3))
    dense = _dense(op.matrix)
    expected = np.stack([dense @ frame for frame in d])          # brute force, per frame
    got = op.apply(d, chunk_frames=5, dtype=dtype)
    assert got.dtype == dtype and got.shape == (23, len(POINTS), 3)
    np.testing.assert_allclose(got, expected, atol=atol)
    out = np.empty_like(got)
    assert op.apply(d, chunk_frames=5, dtype=dtype, out=out) is out
    np.testing.assert_array_equal(out, got)
    assert_retiled(op.apply(d, dtype=dtype), got)
    blocks = list(op.iter_chunks(d, chunk_frames=10, dtype=dtype))
    assert [fr for fr, _ in blocks] == [slice(0, 10), slice(10, 20), slice(20, 23)]
    assert_retiled(np.concatenate([blk for _, blk in blocks]), got)


def test_apply_over_several_tiles_matches_scipy():
    # more vertices and frames than one tile of the product holds, with partial tiles
    # at both ends, against scipy interpolating every frame's x, y and z at once
    points = RNG.uniform(-1.2, 1.2, (1300, 3))
    d = RNG.normal(size=(150, len(CENTERS), 3))
    ref = RBFInterpolator(CENTERS, d.transpose(1, 0, 2).reshape(len(CENTERS), -1))(points)
    ref = ref.reshape(len(points), len(d), 3).transpose(1, 0, 2)
    op = build_rbf_operator(CENTERS, points)
    np.testing.assert_allclose(op.apply(d, dtype=np.float64), ref,
                               atol=RBF_VS_SCIPY_RTOL * np.abs(ref).max())
    got = op.apply(d)
    np.testing.assert_allclose(got, ref, atol=RBF_APPLY_FLOAT32 * np.abs(ref).max())
    assert_retiled(op.apply(d, chunk_frames=70), got)


def test_apply_shares_tiles_among_blas_threads():
    # with a BLAS of two threads the tiles are shared between two Python threads, each
    # on a one-thread BLAS: the same tiles, so the same bits as on one thread
    points = RNG.uniform(-1.2, 1.2, (1300, 3))
    d = RNG.normal(size=(150, len(CENTERS), 3))
    op = build_rbf_operator(CENTERS, points)
    with threadpoolctl.threadpool_limits(1, user_api="blas"):
        one = op.apply(d)
    with threadpoolctl.threadpool_limits(2, user_api="blas"):
        assert _blas_threads() == 2, "the BLAS did not take a limit of two threads"
        two = op.apply(d)
        assert _blas_threads() == 2                 # the tiles' one-thread limit is undone
    np.testing.assert_array_equal(two, one)


def _blas_threads() -> int:
    return max(lib["num_threads"] for lib in threadpoolctl.threadpool_info()
               if lib["user_api"] == "blas")


def assert_retiled(actual, desired):
    """The same product cut into other tiles: equal but for the BLAS's order of sums."""
    assert actual.dtype == desired.dtype
    eps = np.finfo(desired.dtype).eps
    np.testing.assert_allclose(actual, desired, rtol=0,
                               atol=RBF_RETILED_EPS * eps * np.abs(desired).max())


def test_apply_does_not_touch_input():
    op = build_rbf_operator(CENTERS, POINTS)
    d = RNG.normal(size=(4, len(CENTERS), 3))
    before = d.copy()
    op.apply(d)
    np.testing.assert_array_equal(d, before)


def test_wendland_is_sparse_positive_definite_and_interpolates():
    epsilon = 1.5                                         # support radius 2/3
    op = build_rbf_operator(CENTERS, np.r_[CENTERS, POINTS], kernel="wendland_c2",
                            epsilon=epsilon)
    dist = cdist(CENTERS, CENTERS)
    k = evaluate("wendland_c2", epsilon * dist)
    assert 0.0 < np.mean(k == 0.0) < 1.0                  # sparse, yet coupled
    assert np.linalg.eigvalsh(k).min() > 0.0
    np.testing.assert_allclose(op.diagnostics[0].min_eigenvalue, np.linalg.eigvalsh(k)[0])
    assert sp.issparse(op.matrix)
    data = RNG.normal(size=(len(CENTERS), 3))
    np.testing.assert_allclose(op.matrix[:len(CENTERS)] @ data, data, atol=EXACT_FLOAT64)
    far = np.min(cdist(POINTS, CENTERS), axis=1) >= 1 / epsilon
    assert far.any()
    assert op.matrix[len(CENTERS):][far].nnz == 0
    # the sparse product applied to frames, against the dense matrix frame by frame
    frames = RNG.normal(size=(11, len(CENTERS), 3))
    expected = np.stack([_dense(op.matrix) @ frame for frame in frames])
    for dtype, atol in ((np.float64, EXACT_FLOAT64), (np.float32, RBF_APPLY_FLOAT32)):
        got = op.apply(frames, chunk_frames=4, dtype=dtype)
        assert got.dtype == dtype
        np.testing.assert_allclose(got, expected, atol=atol * max(1.0, np.abs(expected).max()))


@pytest.mark.parametrize("kernel, epsilon", [("gaussian", 2.0), ("wendland_c2", 1.5)])
def test_condition_is_the_solved_systems(kernel, epsilon):
    # without a polynomial the system is the kernel matrix: its condition number is NumPy's
    # (the oracle) of the matrix made here; dense and compact (sparse) systems alike
    op = build_rbf_operator(CENTERS, POINTS, kernel=kernel, epsilon=epsilon, degree=-1)
    k = evaluate(kernel, epsilon * cdist(CENTERS, CENTERS))
    np.testing.assert_allclose(op.diagnostics[0].condition, np.linalg.cond(k), rtol=1e-8)


def test_wendland_formula_is_c2_at_the_support_edge():
    r = np.array([0.0, 0.5, 1.0 - 1e-4, 1.0, 1.3])
    values = evaluate("wendland_c2", r)
    np.testing.assert_allclose(values[:2], [1.0, 0.5 ** 4 * 3.0])
    assert values[2] < FEW_ULPS and values[3] == values[4] == 0.0


def test_bspline_bell_is_the_cubic_bspline_with_compact_support():
    r = np.linspace(0.0, 1.5, 301)
    bell = BSpline.basis_element([-2, -1, 0, 1, 2], extrapolate=False)   # oracle
    expected = np.nan_to_num(bell(2 * r)) / bell(0.0)
    np.testing.assert_allclose(evaluate("bspline_bell", r), expected, atol=FEW_ULPS)
    assert np.all(evaluate("bspline_bell", r[r >= 1.0]) == 0.0)
    assert np.all(evaluate("bspline_bell", r[r < 1.0]) > 0.0)


def test_bspline_bell_operator_without_polynomial():
    op = build_rbf_operator(CENTERS, POINTS, kernel="bspline_bell", epsilon=1.2)
    assert op.degree == -1
    far = np.min(cdist(POINTS, CENTERS), axis=1) >= 1 / 1.2
    assert far.any() and np.all(_dense(op.matrix)[far] == 0.0)   # no polynomial term


def test_indefinite_matrix_is_shifted_and_reported():
    # Wide Gaussians on the slit grid with geodesic distance: not positive definite.
    v, f, upper, lower = slit_grid(n=17)
    centers = np.r_[upper[1:9:2], lower[1:9:2], [200, 230, 260]]    # cut: x < 10/16
    with pytest.warns(UserWarning, match="not positive definite"):
        op = build_rbf_operator(v[centers], v, kernel="gaussian", epsilon=0.3, degree=-1,
                                distance="geodesic", mesh=(v, f),
                                **_surface(f, centers))
    info = op.diagnostics[0]
    assert info.min_eigenvalue < 0.0
    assert info.shift >= -2.0 * info.min_eigenvalue
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        narrow = build_rbf_operator(v[centers], v, kernel="gaussian", epsilon=8.0,
                                    degree=-1, distance="geodesic", mesh=(v, f),
                                    **_surface(f, centers))
    assert narrow.diagnostics[0].shift == 0.0 and narrow.diagnostics[0].min_eigenvalue > 0


def test_euclidean_scipy_kernels_are_never_shifted():
    op = build_rbf_operator(CENTERS, POINTS, kernel="thin_plate_spline", degree=-1)
    assert op.diagnostics[0].min_eigenvalue < 0.0 and op.diagnostics[0].shift == 0.0


def test_geodesic_operator_interpolates_and_respects_the_slit():
    v, f, upper, lower = slit_grid()
    centers = np.r_[upper[2:14:3], lower[3:14:3]]
    op = build_rbf_operator(v[centers], v, kernel="wendland_c2", epsilon=1 / 0.15,
                            distance="geodesic", mesh=(v, f), **_surface(f, centers))
    data = RNG.normal(size=(len(centers), 3))
    np.testing.assert_allclose(op.matrix[centers] @ data, data, atol=EXACT_FLOAT64)
    # Upper-lip centers do not reach across the cut (support 0.15 < the way around).
    below = np.abs(_dense(op.matrix)[lower[4], :4]).max()
    euclid = build_rbf_operator(v[centers], v, kernel="wendland_c2", epsilon=1 / 0.15)
    assert below < RBF_ACROSS_CUT < 1e-3 < np.abs(_dense(euclid.matrix)[lower[4], :4]).max()


def _lip_regions():
    v, f, upper, lower = slit_grid()
    centers = np.r_[upper[2:14:3], lower[3:14:3], [600, 610, 620, 30, 40]]
    regions = {"upper_lip": [0, 1, 2, 3], "lower_lip": [4, 5, 6, 7], "other": [8, 9, 10, 11, 12]}
    return v, f, centers, regions


def test_region_markers_have_no_influence_outside_their_region():
    v, f, centers, regions = _lip_regions()
    op = build_rbf_operator(v[centers], v, kernel="wendland_c2", epsilon=2.0,
                            distance="geodesic", mesh=(v, f), regions=regions,
                            **_surface(f, centers))
    weights = op.region_weights.weights
    np.testing.assert_allclose(weights.sum(axis=1), 1.0)
    dense = _dense(op.matrix)
    for col, name in enumerate(op.region_weights.names):
        if name == "other":
            continue
        outside = weights[:, col] == 0.0
        assert outside.any() and (~outside).any()
        assert np.all(dense[np.ix_(outside, regions[name])] == 0.0)
    assert op.region_weights["upper_lip"][slit_grid()[3][5]] == 0.0   # across the cut
    assert [d.region for d in op.diagnostics] == ["upper_lip", "lower_lip", "other"]


def test_region_operator_is_the_weighted_sum_of_region_operators():
    v, f, centers, regions = _lip_regions()
    masks = np.zeros((len(v), 3))
    masks[:, 0] = v[:, 1] > 0.5
    masks[:, 1] = v[:, 1] < 0.5
    masks[:, 2] = 0.5
    options = dict(kernel="gaussian", epsilon=3.0, degree=0)    # the grid is flat: no z term
    op = build_rbf_operator(v[centers], v, regions=regions, region_weights=masks, **options)
    weights = masks / masks.sum(axis=1, keepdims=True)
    expected = np.zeros((len(v), len(centers)))
    for col, name in enumerate(regions):
        subset = np.union1d(regions[name], regions["other"])
        w_r = build_rbf_operator(v[centers[subset]], v, **options).matrix
        expected[:, subset] += weights[:, col, None] * w_r
    np.testing.assert_allclose(op.matrix, expected, atol=RBF_REGION_SUM)


def test_region_weights_blend_smoothly():
    dist = np.array([[0.0, 1.0, 2.0, 3.0, 4.0], [4.0, 3.0, 2.0, 1.0, 0.0]])
    w = region_weights(dist, {"a": [0], "b": [1]}, width=2.5)
    np.testing.assert_allclose(w["a"], np.array([1.0, 1.0, 0.5, 0.104, 0.0])
                               / [1, 1.104, 1, 1.104, 1])
    np.testing.assert_allclose(w.weights.sum(axis=1), 1.0)
    painted = painted_region_weights([[2.0, 2.0], [0.0, 3.0]], ["a", "b"])
    np.testing.assert_allclose(painted.weights, [[0.5, 0.5], [0.0, 1.0]])


@pytest.mark.parametrize("kwargs, match", [
    (dict(kernel="spline"), "kernel must be one of"),
    (dict(kernel="gaussian"), "epsilon is required for kernel 'gaussian'"),
    (dict(kernel="wendland_c2", epsilon=1.0, degree=1), "used without a polynomial term"),
    (dict(smoothing=[1.0, 2.0]), "smoothing must be a scalar or an array of shape"),
    (dict(distance="manhattan"), "distance must be one of"),
    (dict(distance="geodesic"), r"needs mesh=\(vertices, faces\)"),
    (dict(labels=["a"]), "labels must name the 25 centers"),
    (dict(regions={"a": list(range(24))}), "marker 24 is in no region"),
    (dict(regions={"a": [0], "b": [0] + list(range(1, 25))}),
     "marker 0 is in regions 'a' and 'b'"),
    (dict(regions={"a": list(range(24)) + [99]}), "99 is not a marker"),
    (dict(regions={"a": list(range(25))}, region_weights=np.ones((150, 2))),
     r"masks must have shape \(any, 1\)"),
])
def test_option_errors(kwargs, match):
    with pytest.raises(InputError, match=match):
        build_rbf_operator(CENTERS, POINTS, **kwargs)


def test_degree_below_minimum_warns_like_scipy():
    with pytest.warns(UserWarning, match="below the minimum 1"):
        build_rbf_operator(CENTERS, POINTS, kernel="thin_plate_spline", degree=0)


def test_geometry_errors():
    with pytest.raises(InputError, match="degree-2 polynomial needs at least 10"):
        build_rbf_operator(CENTERS[:6], POINTS, kernel="quintic")
    with pytest.raises(InputError, match="centers 'a' and 'c' coincide"):
        build_rbf_operator(CENTERS[[0, 1, 0, 2, 3]], POINTS, labels="abcde")
    flat = CENTERS.copy()
    flat[:, 2] = 0.0
    with pytest.raises(InputError, match="polynomial block has rank 3 < 4"):
        build_rbf_operator(flat, POINTS)
    v, f, upper, _ = slit_grid(n=9)
    with pytest.raises(InputError, match="points must be the mesh vertices"):
        build_rbf_operator(v[upper], v[:-1], distance="geodesic", mesh=(v, f))
    with pytest.raises(InputError, match="center 0 is .* from its surface point"):
        build_rbf_operator(v[upper], v, distance="geodesic", mesh=(v, f),
                           center_faces=np.arange(9), center_bary=np.tile([1.0, 0, 0], (9, 1)))
    with pytest.raises(InputError, match="give both center_faces and center_bary"):
        build_rbf_operator(v[upper], v, distance="geodesic", mesh=(v, f),
                           center_faces=np.arange(9))
    regions = {"a": [0, 1, 2, 3, 4], "empty": [], "b": [5, 6, 7, 8]}
    with pytest.raises(InputError, match="region 'empty' has no markers but positive"):
        build_rbf_operator(v[upper], v, regions=regions, region_weights=np.ones((len(v), 3)),
                           kernel="gaussian", epsilon=1.0)


def test_apply_errors():
    op = build_rbf_operator(CENTERS, POINTS, labels=[f"m{i}" for i in range(25)])
    d = np.zeros((5, 25, 3))
    d[3, 7] = np.nan
    with pytest.raises(InputError, match=r"marker 'm7' \(index 7\) is NaN in frame 3"):
        op.apply(d)
    with pytest.raises(InputError, match=r"marker 'm7' \(index 7\) is NaN in frame 3"):
        op.iter_chunks(d)
    with pytest.raises(InputError, match=r"displacements must have shape \(any, 25, 3\)"):
        op.apply(np.zeros((5, 24, 3)))
    with pytest.raises(InputError, match="dtype must be float32 or float64"):
        op.apply(np.zeros((5, 25, 3)), dtype=np.int32)
    with pytest.raises(InputError, match="out must be a writeable C-contiguous float32"):
        op.apply(np.zeros((5, 25, 3)), out=np.zeros((5, 150, 3)))
    with pytest.raises(InputError, match="chunk_frames must be at least 1"):
        op.apply(np.zeros((5, 25, 3)), chunk_frames=0)


def test_painted_mask_errors():
    with pytest.raises(InputError, match="vertex 1 has a negative weight in region 'b'"):
        painted_region_weights([[1.0, 0.0], [1.0, -1.0]], ["a", "b"])
    with pytest.raises(InputError, match="vertex 0 has no weight in any region"):
        painted_region_weights([[0.0, 0.0]], ["a", "b"])
    with pytest.raises(InputError, match="names must be distinct strings"):
        painted_region_weights([[1.0, 0.0]], ["a", "a"])


def test_geodesic_thin_plate_spline_on_the_ict_face(ict_neutral_path):
    """Heat-method distances of ~-1e-16 at a source must not turn the TPS log into NaN.

    The geodesic TPS kernel is indefinite on this mesh, so it is shifted (and no
    longer interpolates), but an affine field stays exact: it lies in the span of
    the polynomial part, whatever the kernel.
    """
    import trimesh

    mesh = trimesh.load(ict_neutral_path, process=False)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    idx = np.random.default_rng(0).choice(len(vertices), 30, replace=False)
    with pytest.warns(UserWarning, match="positive definite"):
        op = build_rbf_operator(vertices[idx], vertices, kernel="thin_plate_spline",
                                distance="geodesic", mesh=(vertices, faces))
    assert np.isfinite(op.matrix).all()
    affine = np.random.default_rng(1).normal(size=(3, 3))
    field = op.apply((vertices[idx] @ affine)[None], dtype=np.float64)[0]
    np.testing.assert_allclose(field, vertices @ affine, atol=RBF_AFFINE_ICT_CM)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_interleave_writes_planes_into_a_strided_view(dtype):
    # a tile of frames and points of a larger output, written in place: against numpy
    planes = RNG.normal(size=(3, 7, 11)).astype(dtype)
    whole = np.zeros((9, 20, 3), dtype)
    _interleave(planes, whole[1:8, 4:15])
    np.testing.assert_array_equal(whole[1:8, 4:15], np.stack(list(planes), axis=-1))
    whole[1:8, 4:15] = 0
    assert not whole.any()                          # nothing written outside the tile
