"""Leave-one-marker-out cross-validation of the RBF operator against refitting it per marker."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.sparse as sp
from helpers import one_variant_at_a_time, slit_grid
from tolerances import BATCHED_VS_ONE_AT_A_TIME, EXACT_FLOAT64, LOO_VS_REFIT

from mocap import InputError
from mocap.retarget import _system
from mocap.retarget.cross_validation import (
    CrossValidation,
    LeaveOneOut,
    MarkerGeometry,
    cross_validate,
    gram_matrix,
    leave_one_out,
    leave_one_out_many,
)
from mocap.retarget.rbf import build_rbf_operator

RNG = np.random.default_rng(5)
N_MARKERS = 16
REGIONS = {"upper_lip": [0, 1, 2, 3, 4], "lower_lip": [5, 6, 7, 8, 9],
           "other": list(range(10, N_MARKERS))}
WIDTH = 0.15


def _bumpy_slit_grid():
    v, f, _, _ = slit_grid()
    v = v.copy()
    v[:, 2] = 0.3 * np.sin(3.0 * v[:, 0]) * np.cos(2.0 * v[:, 1])
    return v, f


@pytest.fixture(scope="module")
def geometry():
    """16 markers at random points of random triangles of a bumpy grid with a slit."""
    v, f = _bumpy_slit_grid()
    faces = RNG.choice(len(f), N_MARKERS, replace=False)
    bary = RNG.dirichlet([2.0, 2.0, 2.0], N_MARKERS)
    corners = f[faces]
    centers = np.einsum("mk,mkd->md", bary, v[corners])
    return MarkerGeometry(centers, corners, bary, faces, v, f,
                          tuple(f"m{i}" for i in range(N_MARKERS)))


def _dense(matrix):
    return matrix.toarray() if sp.issparse(matrix) else np.asarray(matrix)


def _refit_predictions(geometry, data, *, regions=None, width=None, precomputed=None,
                       **options):
    """The oracle: build the operator without marker k, read the mesh at k's bound point."""
    g = geometry
    out = np.zeros((g.n_markers,) + data.shape[1:])
    for k in range(g.n_markers):
        keep = np.delete(np.arange(g.n_markers), k)
        labels = [g.labels[i] for i in keep]
        held_regions = None if regions is None else {
            name: [g.labels[i] for i in idx if i != k] for name, idx in regions.items()}
        extra = {}
        if precomputed is not None:
            fields, between = precomputed
            extra["precomputed"] = (fields[keep], between[np.ix_(keep, keep)])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            op = build_rbf_operator(g.centers[keep], g.vertices, labels=labels,
                                    regions=held_regions, region_width=width, **extra,
                                    **options)
        out[k] = g.bary[k] @ (_dense(op.matrix)[g.corners[k]] @ data[keep])
    return out


OPTIONS = [dict(kernel="thin_plate_spline"), dict(kernel="gaussian", epsilon=3.0),
           dict(kernel="wendland_c2", epsilon=2.0), dict(kernel="inverse_multiquadric",
                                                          epsilon=2.0, degree=1),
           dict(kernel="thin_plate_spline", smoothing=0.01)]


@pytest.mark.parametrize("options", OPTIONS, ids=lambda o: "-".join(map(str, o.values())))
@pytest.mark.parametrize("with_regions", [False, True])
def test_closed_form_equals_refitting_without_each_marker(geometry, options, with_regions):
    data = RNG.normal(size=(N_MARKERS, 6))
    regions = REGIONS if with_regions else None
    width = WIDTH if with_regions else None
    loo = leave_one_out(geometry, regions=regions, region_width=width, **options)
    expected = _refit_predictions(geometry, data, regions=regions, width=width, **options)
    np.testing.assert_allclose(loo.matrix @ data, expected, atol=LOO_VS_REFIT)
    np.testing.assert_allclose(np.diag(loo.matrix), 0.0, atol=EXACT_FLOAT64)  # k never predicts k
    assert loo.singular == {} and loo.region_width == width


@pytest.mark.parametrize("options", OPTIONS[1:3], ids=["gaussian", "wendland"])
@pytest.mark.parametrize("with_regions", [False, True])
def test_geodesic_closed_form_equals_refitting_on_the_same_distances(geometry, options,
                                                                     with_regions):
    """Geodesic: the distances of the whole layout, held fixed (a refit would re-run the heat
    method's symmetrization without the held-out marker)."""
    between, _, fields = geometry.distances("geodesic")
    data = RNG.normal(size=(N_MARKERS, 4))
    regions = REGIONS if with_regions else None
    width = WIDTH if with_regions else None
    loo = leave_one_out(geometry, distance="geodesic", regions=regions, region_width=width,
                        **options)
    assert set(loo.shifts.values()) == {0.0}
    expected = _refit_predictions(geometry, data, regions=regions, width=width,
                                  precomputed=(fields, between), distance="geodesic",
                                  **options)
    np.testing.assert_allclose(loo.matrix @ data, expected, atol=LOO_VS_REFIT)


@pytest.mark.parametrize("with_regions", [False, True])
def test_no_condition_number_is_computed(geometry, monkeypatch, with_regions):
    # the held-out residuals never read it, and it costs an SVD of every system
    def refused(*args, **kwargs):
        raise AssertionError("a condition number was computed")
    monkeypatch.setattr(np.linalg, "cond", refused)
    loo = leave_one_out(geometry, regions=REGIONS if with_regions else None,
                        region_width=WIDTH if with_regions else None)
    assert np.isfinite(loo.matrix).all()


def test_a_regularized_system_keeps_its_shift_when_a_marker_is_out(geometry):
    """The geodesic TPS kernel is indefinite: its diagonal shift is the full layout's."""
    between, _, fields = geometry.distances("geodesic")
    with pytest.warns(UserWarning, match="not positive definite"):
        loo = leave_one_out(geometry, distance="geodesic")
    shift = loo.shifts["all"]
    assert shift > 0.0
    data = RNG.normal(size=(N_MARKERS, 3))
    expected = _refit_predictions(geometry, data, precomputed=(fields, between),
                                  distance="geodesic", smoothing=shift)
    np.testing.assert_allclose(loo.matrix @ data, expected, atol=LOO_VS_REFIT)


@pytest.mark.parametrize("distance", ["euclidean", "geodesic"])
def test_rows_are_the_operator_at_the_vertices_asked_for(geometry, distance):
    ids = np.arange(0, len(geometry.vertices), 7)
    options = dict(kernel="gaussian", epsilon=3.0, regions=REGIONS, region_width=WIDTH)
    loo = leave_one_out(geometry, distance=distance, vertices=ids, **options)
    extra = {}
    if distance == "geodesic":
        between, _, fields = geometry.distances("geodesic")
        extra["precomputed"] = (fields, between)
    op = build_rbf_operator(geometry.centers, geometry.vertices, distance=distance,
                            labels=geometry.labels, **extra, **options)
    np.testing.assert_allclose(loo.rows, _dense(op.matrix)[ids], atol=EXACT_FLOAT64)


def test_a_marker_the_polynomial_cannot_spare_is_reported(geometry):
    """Degree 1 needs 4 centers in general position: a 4-marker region without support
    cannot lose one."""
    regions = {"four": [0, 1, 2, 3], "rest": list(range(4, N_MARKERS))}
    loo = leave_one_out(geometry, kernel="thin_plate_spline", regions=regions,
                        region_width=WIDTH, support_region=None)
    assert set(loo.singular) == {"m0", "m1", "m2", "m3"}
    assert "3 other centers of region 'four' cannot fit the degree-1" in loo.singular["m0"]
    assert np.isnan(loo.matrix[:4]).all() and np.isfinite(loo.matrix[4:]).all()


def _assert_same_variants(batched, oracle):
    """Entry by entry: the same error message, or the same held-out matrices, rows, shifts
    and singular markers (to rounding)."""
    assert len(batched) == len(oracle)
    for got, expected in zip(batched, oracle):
        assert type(got) is type(expected)
        if isinstance(expected, InputError):
            assert str(got) == str(expected)
            continue
        assert got.singular == expected.singular and got.region_width == expected.region_width
        np.testing.assert_allclose(got.matrix, expected.matrix, rtol=BATCHED_VS_ONE_AT_A_TIME,
                                   atol=BATCHED_VS_ONE_AT_A_TIME)
        if expected.rows is None:
            assert got.rows is None
        else:
            np.testing.assert_allclose(got.rows, expected.rows, rtol=BATCHED_VS_ONE_AT_A_TIME,
                                       atol=BATCHED_VS_ONE_AT_A_TIME)
        assert got.shifts.keys() == expected.shifts.keys()
        for name, shift in expected.shifts.items():
            assert got.shifts[name] == pytest.approx(shift, rel=BATCHED_VS_ONE_AT_A_TIME, abs=0)


@pytest.mark.parametrize("kernel, epsilons", [
    ("gaussian", (1.0, 2.0, 3.0, 6.0)),
    ("inverse_multiquadric", (0.5, 2.0, 8.0)),
    ("wendland_c2", (0.5, 1.0, 2.0)),
    ("thin_plate_spline", (None, 2.0)),
])
@pytest.mark.parametrize("distance", ["euclidean", "geodesic"])
@pytest.mark.parametrize("with_regions", [False, True])
def test_variants_solved_together_equal_each_solved_alone(geometry, kernel, epsilons, distance,
                                                          with_regions):
    options = dict(kernel=kernel, distance=distance, vertices=np.arange(0, 60, 3),
                   regions=REGIONS if with_regions else None,
                   region_width=WIDTH if with_regions else None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")               # the geodesic TPS's shift
        batched = leave_one_out_many(geometry, epsilons=epsilons, **options)
        oracle = one_variant_at_a_time(geometry, epsilons=epsilons, **options)
    assert all(isinstance(x, LeaveOneOut) for x in batched)
    _assert_same_variants(batched, oracle)
    if kernel != "thin_plate_spline":        # scale-invariant: the shape may not matter
        # the shape parameter matters: the variants are not one solve repeated
        assert not np.allclose(batched[0].matrix, batched[-1].matrix)


def test_variants_solved_together_keep_each_shift_and_warning(geometry):
    """Geodesic Gaussians: the wide one is not positive definite and is shifted, alone or
    in a stack, the narrow one is not."""
    epsilons = (0.05, 3.0)
    with pytest.warns(UserWarning, match="not positive definite") as caught:
        batched = leave_one_out_many(geometry, kernel="gaussian", epsilons=epsilons,
                                     distance="geodesic")
    assert len(caught) == 1
    assert batched[0].shifts["all"] > 0.0 and batched[1].shifts["all"] == 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _assert_same_variants(batched, one_variant_at_a_time(
            geometry, kernel="gaussian", epsilons=epsilons, distance="geodesic"))


def test_variants_solved_together_fail_as_each_alone(geometry):
    """A bad shape parameter fails its variant only; a polynomial the centers cannot fit,
    every variant; markers the polynomial cannot spare are reported for each."""
    batched = leave_one_out_many(geometry, kernel="gaussian", epsilons=(2.0, -1.0, None))
    assert isinstance(batched[0], LeaveOneOut)
    assert "epsilon" in str(batched[1]) and "epsilon is required" in str(batched[2])
    _assert_same_variants(batched, one_variant_at_a_time(
        geometry, kernel="gaussian", epsilons=(2.0, -1.0, None)))
    few = {"three": [0, 1, 2], "rest": list(range(3, N_MARKERS))}
    options = dict(kernel="inverse_multiquadric", degree=1, regions=few, region_width=WIDTH,
                   support_region=None)
    batched = leave_one_out_many(geometry, epsilons=(1.0, 2.0), **options)
    assert all(isinstance(x, InputError) for x in batched)
    assert "region 'three': 3 centers, but a degree-1 polynomial needs at least 4" in str(
        batched[0])
    _assert_same_variants(batched, one_variant_at_a_time(geometry, epsilons=(1.0, 2.0),
                                                         **options))
    four = {"four": [0, 1, 2, 3], "rest": list(range(4, N_MARKERS))}
    options.update(regions=four)
    batched = leave_one_out_many(geometry, epsilons=(1.0, 2.0), **options)
    assert [set(x.singular) for x in batched] == [{"m0", "m1", "m2", "m3"}] * 2
    _assert_same_variants(batched, one_variant_at_a_time(geometry, epsilons=(1.0, 2.0),
                                                         **options))
    with pytest.raises(InputError, match="geometry must be a MarkerGeometry"):
        leave_one_out_many("geometry", epsilons=(1.0,))


def test_a_singular_system_of_a_stack_fails_alone():
    """One singular kernel matrix among three: its error is solve_system's, the others are
    solved as solve_system solves them."""
    m = 5
    kcc = np.stack([np.eye(m), np.zeros((m, m)), 2.0 * np.eye(m)])
    kxc = RNG.normal(size=(3, 4, m))
    empty = np.zeros((m, 0)), np.zeros((4, 0))
    stack = _system.solve_systems("lips", kcc, kxc, *empty, np.zeros(m), -1, False)
    assert stack.errors[0] is None and stack.errors[2] is None
    with pytest.raises(InputError) as alone:
        _system.solve_system("lips", kcc[1], kxc[1], *empty, np.zeros(m), -1, False)
    assert str(stack.errors[1]) == str(alone.value)
    assert "region 'lips': the RBF system is singular" in str(alone.value)
    assert np.isnan(stack.matrix[1]).all()
    for i in (0, 2):
        solved = _system.solve_system("lips", kcc[i], kxc[i], *empty, np.zeros(m), -1, False)
        np.testing.assert_array_equal(stack.matrix[i], solved.matrix)
        np.testing.assert_array_equal(stack.inverse[i], solved.inverse)


def test_sum_squares_from_the_gram_matrix_equals_the_residuals(geometry):
    d = RNG.normal(size=(40, N_MARKERS, 3))
    loo = leave_one_out(geometry, kernel="gaussian", epsilon=3.0)
    residuals = loo.residuals(d)
    brute = np.array([[d[t, k] - sum(loo.matrix[k, j] * d[t, j] for j in range(N_MARKERS))
                       for k in range(N_MARKERS)] for t in range(3)])
    np.testing.assert_allclose(residuals[:3], brute, atol=EXACT_FLOAT64)
    np.testing.assert_allclose(loo.sum_squares(gram_matrix(d)),
                               np.sum(residuals ** 2, axis=(0, 2)), rtol=1e-10)


def test_gram_matrix_sums_every_frame_and_coordinate():
    """Against the sum of outer products frame by frame, coordinate by coordinate, for a
    C-ordered take and a view that is not one."""
    d = RNG.normal(size=(50, N_MARKERS, 3))
    brute = sum(np.outer(d[t, :, c], d[t, :, c]) for t in range(len(d)) for c in range(3))
    np.testing.assert_allclose(gram_matrix(d), brute, rtol=1e-12, atol=0)
    np.testing.assert_allclose(gram_matrix(d[::2]), sum(
        np.outer(d[t, :, c], d[t, :, c]) for t in range(0, len(d), 2) for c in range(3)),
        rtol=1e-12, atol=0)


def test_cross_validate_scores_in_mm_per_marker_and_region(geometry):
    d = RNG.normal(size=(25, N_MARKERS, 3))
    cv = cross_validate(geometry, d, mm_per_unit=10.0, variant="gaussian",
                        kernel="gaussian", epsilon=3.0)
    assert isinstance(cv, CrossValidation) and cv.n_frames == 25
    norms = cv.residual_norms(d)
    np.testing.assert_allclose(cv.marker_rms, np.sqrt(np.mean(norms ** 2, axis=0)), rtol=1e-10)
    np.testing.assert_allclose(cv.motion_rms, 10 * np.sqrt(np.mean(np.sum(d ** 2, -1), 0)),
                               rtol=1e-12)
    assert cv.rms == pytest.approx(np.sqrt(np.mean(norms ** 2)), rel=1e-10)
    table = cv.by_region({"upper": ["m0", "m1", "m2"], "nobody": ["x"], "rest": ["m3"]})
    assert [r["region"] for r in table] == ["upper", "rest"]
    assert table[0]["rms_mm"] == pytest.approx(np.sqrt(np.mean(norms[:, :3] ** 2)), rel=1e-10)
    assert table[1]["relative"] == pytest.approx(cv.marker_rms[3] / cv.motion_rms[3])
    summary = cv.summary()
    assert summary["variant"] == "gaussian" and set(summary["markers"]) == set(cv.labels)


def test_geometry_from_a_binding_reads_its_surface_points():
    from mocap.bind import Binding
    from mocap.mesh.mesh import Mesh

    v, f = _bumpy_slit_grid()
    faces = np.array([10, 200, 400])
    bary = np.array([[0.2, 0.3, 0.5], [1.0, 0.0, 0.0], [0.1, 0.1, 0.8]])
    binding = Binding(labels=("a", "b", "c"), scale=0.1, rotation=np.eye(3),
                      translation=np.zeros(3), face_ids=faces, vertex_ids=f[faces],
                      barycentric=bary, distances=np.zeros(3), rms=0.0, skin_offset=0.0,
                      n_landmarks=0, n_iterations=0, converged=True, message="test")
    geo = MarkerGeometry.from_binding(binding, Mesh(v, f), ["c", "a"])
    np.testing.assert_allclose(geo.centers, np.einsum("mk,mkd->md", bary[[2, 0]],
                                                      v[f[faces[[2, 0]]]]))
    assert geo.labels == ("c", "a") and geo.corners.tolist() == f[faces[[2, 0]]].tolist()
    with pytest.raises(InputError, match=r"marker 'z' is not in the binding \(1 absent\)"):
        MarkerGeometry.from_binding(binding, Mesh(v, f), ["a", "z"])
    with pytest.raises(InputError, match="bound to another topology"):
        MarkerGeometry.from_binding(binding, Mesh(v[:50], f[np.all(f < 50, axis=1)]), ["a"])


def test_errors(geometry):
    with pytest.raises(InputError, match="geometry must be a MarkerGeometry"):
        leave_one_out("geometry")
    with pytest.raises(InputError, match="distance must be one of"):
        leave_one_out(geometry, distance="manhattan")
    with pytest.raises(InputError, match="epsilon is required for kernel 'gaussian'"):
        leave_one_out(geometry, kernel="gaussian")
    loo = leave_one_out(geometry)
    with pytest.raises(InputError, match=r"displacements must have shape \(any, 16, 3\)"):
        loo.residuals(np.zeros((3, 15, 3)))
    with pytest.raises(InputError, match="displacements contains NaN"):
        loo.residuals(np.full((3, 16, 3), np.nan))
    with pytest.raises(InputError, match=r"gram must have shape \(16, 16\)"):
        loo.sum_squares(np.eye(3))
    with pytest.raises(InputError, match="vertex_ids must be a 1-D array of vertex ids"):
        geometry.to_vertices("euclidean", [10 ** 6])
    with pytest.raises(InputError, match="displacements contains NaN"):
        cross_validate(geometry, np.full((2, 16, 3), np.nan), mm_per_unit=1.0)


@pytest.mark.parametrize("precomputed, match", [
    ("fields", r"precomputed must be a pair"),
    ((np.zeros((16, 5)), np.zeros((16, 16))), r"precomputed to_points must have shape"),
    ("negative", "precomputed distances must be >= 0"),
    ("asymmetric", "precomputed between-center distances must be symmetric"),
])
def test_precomputed_distance_errors(geometry, precomputed, match):
    to_points = np.ones((N_MARKERS, len(geometry.vertices)))
    if precomputed == "negative":
        precomputed = (to_points, -np.ones((N_MARKERS, N_MARKERS)))
    elif precomputed == "asymmetric":
        precomputed = (to_points, np.triu(np.ones((N_MARKERS, N_MARKERS))))
    with pytest.raises(InputError, match=match):
        build_rbf_operator(geometry.centers, geometry.vertices, precomputed=precomputed)
