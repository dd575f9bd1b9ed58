"""Exact batched weight solving against scipy's lsq_linear(bvls) and numpy's lstsq."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear
from tolerances import (
    EXACT_FLOAT64,
    SOLVE_AT_BOUND,
    SOLVE_KKT_LOOP_REL,
    SOLVE_KKT_RECOMPUTED,
    SOLVE_KKT_REL,
    SOLVE_OBJECTIVE_REL,
    SOLVE_REFINED_STATIONARITY,
    SOLVE_ROUTES,
    SOLVE_ROUTES_ILL_CONDITIONED,
    SOLVE_SAME_MINIMIZER,
    SOLVE_TOL,
)

import fit.solve._active_set as active_set
from fit.solve.sampling_estimator import estimate_weights_by_sampling
from fit.solve.weights import WeightSolution, solve_weights
from mocap.errors import InputError

N_SHAPES, N_ROWS, N_FRAMES = 12, 30, 60

BOUNDS = {
    "none": (-np.inf, np.inf),
    "unit": (0.0, 1.0),
    "epsilon": (-0.1, 1.1),
    "per-shape": (np.r_[np.zeros(6), np.full(6, -np.inf)],
                  np.r_[np.full(6, np.inf), np.linspace(0.2, 1.0, 6)]),
}
BASES = ("random", "ill-conditioned", "rank-deficient")
#: The box QP's iterations compiled frame by frame (numba: the `speed` extra, in .[test]).
COMPILED_SOLVE, ITERATE_COMPILED = active_set._compiled_solve, active_set._iterate_compiled


@pytest.fixture(params=["compiled", "numpy"], autouse=True)
def solver_path(request, monkeypatch):
    """Every test here runs on both paths of the box QP's iterations: compiled frame by
    frame, and NumPy's, all frames at once; a test that sets the paths itself takes
    ``"both"`` (indirect parametrization) and runs once."""
    if request.param == "numpy":
        monkeypatch.setattr(active_set, "_compiled_solve", lambda: None)
    elif request.param == "compiled":
        assert COMPILED_SOLVE() is not None, "numba (the speed extra, in .[test]) is missing"
    return request.param


#: For a test that chooses the solver's path itself: one run, not one per path.
BOTH_PATHS = pytest.mark.parametrize("solver_path", ["both"], indirect=True)


def make_basis(kind: str, rng) -> np.ndarray:
    basis = rng.standard_normal((N_ROWS, N_SHAPES))
    if kind == "ill-conditioned":
        u, _, vt = np.linalg.svd(basis, full_matrices=False)
        basis = u @ np.diag(np.logspace(0, -5, N_SHAPES)) @ vt
    elif kind == "rank-deficient":
        basis[:, 3] = basis[:, 4] + basis[:, 5]
        basis[:, 7] = basis[:, 8]
    return basis


def make_data(basis, rng, n_frames=N_FRAMES):
    truth = rng.uniform(-0.4, 1.4, (n_frames, basis.shape[1]))
    return truth @ basis.T + 0.1 * rng.standard_normal((n_frames, basis.shape[0]))


def half_cost(basis, w, data):
    return 0.5 * np.sum((w @ basis.T - data) ** 2, axis=1)


def oracle_cost(basis, data, lo, hi):
    """Per-frame optimum: lstsq when unbounded, else lsq_linear(bvls) to convergence."""
    if np.isinf(lo).all() and np.isinf(hi).all():
        return half_cost(basis, np.linalg.lstsq(basis, data.T, rcond=None)[0].T, data)
    results = [lsq_linear(basis, d, bounds=(lo, hi), method="bvls", max_iter=10_000)
               for d in data]
    assert all(r.status > 0 for r in results), "the oracle did not converge"
    return half_cost(basis, np.array([r.x for r in results]), data)


def assert_kkt(basis, data, w, lo, hi):
    """KKT conditions checked from scratch: feasibility, stationarity, multiplier signs."""
    lo, hi = np.broadcast_to(lo, w.shape[1:]), np.broadcast_to(hi, w.shape[1:])
    assert np.all(w >= lo) and np.all(w <= hi)
    grad = (w @ basis.T - data) @ basis
    size = np.abs(w) @ np.abs(basis.T @ basis) + np.abs(data @ basis)
    rel = grad / size
    at_lo, at_hi = np.isclose(w, lo, rtol=0, atol=SOLVE_AT_BOUND), np.isclose(w, hi, rtol=0,
                                                                              atol=SOLVE_AT_BOUND)
    interior = ~at_lo & ~at_hi
    assert np.abs(rel[interior]).max(initial=0) < SOLVE_KKT_REL
    assert rel[at_lo].min(initial=0) > -SOLVE_KKT_REL
    assert rel[at_hi].max(initial=0) < SOLVE_KKT_REL


@pytest.mark.filterwarnings("ignore:the basis has rank:RuntimeWarning")
@pytest.mark.parametrize("kind", BASES)
@pytest.mark.parametrize("bounds", BOUNDS, ids=str)
def test_objective_equals_oracle(kind, bounds):
    rng = np.random.default_rng([BASES.index(kind), list(BOUNDS).index(bounds)])
    basis = make_basis(kind, rng)
    data = make_data(basis, rng)
    lo, hi = (np.broadcast_to(np.asarray(b, float), (N_SHAPES,)) for b in BOUNDS[bounds])
    sol = solve_weights(basis, data, lower=BOUNDS[bounds][0], upper=BOUNDS[bounds][1])
    assert isinstance(sol, WeightSolution)
    assert sol.status == 0 and sol.converged.all()
    assert sol.rank == (10 if kind == "rank-deficient" else N_SHAPES)
    np.testing.assert_allclose(sol.cost, half_cost(basis, sol.weights, data), rtol=EXACT_FLOAT64)
    np.testing.assert_allclose(sol.cost, oracle_cost(basis, data, lo, hi),
                               rtol=SOLVE_OBJECTIVE_REL)
    assert_kkt(basis, data, sol.weights, lo, hi)


@pytest.mark.parametrize("bounds", ["unit", "epsilon"])
def test_warm_and_cold_start_agree(bounds):
    rng = np.random.default_rng(3)
    basis = make_basis("random", rng)
    # A smooth sequence: the start (clipped unconstrained minimizer or all free) must not matter.
    t = np.linspace(0, 4 * np.pi, 200)[:, None]
    truth = 0.5 + 0.8 * np.sin(t + np.arange(N_SHAPES))
    data = truth @ basis.T + 0.05 * rng.standard_normal((len(t), N_ROWS))
    lo, hi = BOUNDS[bounds]
    warm = solve_weights(basis, data, lower=lo, upper=hi, warm_start=True)
    cold = solve_weights(basis, data, lower=lo, upper=hi, warm_start=False)
    assert warm.status == cold.status == 0
    np.testing.assert_allclose(warm.cost, cold.cost, rtol=SOLVE_OBJECTIVE_REL)
    # a given start (its active set): the answer's, a wrong one, a neighbour's
    for start in (warm.weights, np.full_like(warm.weights, hi), np.roll(warm.weights, 1, 0)):
        given = solve_weights(basis, data, lower=lo, upper=hi, start=start)
        assert given.status == 0
        np.testing.assert_allclose(given.cost, warm.cost, rtol=SOLVE_OBJECTIVE_REL)
    exact = solve_weights(basis, data, lower=lo, upper=hi, start=warm.weights)
    assert (exact.n_iter == 1).all()                      # the right active set: one solve


def test_marker_layout_equals_flat_layout():
    rng = np.random.default_rng(4)
    basis = make_basis("random", rng)
    data = make_data(basis, rng)
    flat = solve_weights(basis, data, lower=0, upper=1)
    markers = solve_weights(basis.T.reshape(N_SHAPES, N_ROWS // 3, 3),
                            data.reshape(N_FRAMES, N_ROWS // 3, 3), lower=0, upper=1)
    np.testing.assert_allclose(markers.cost, flat.cost, rtol=EXACT_FLOAT64)
    np.testing.assert_allclose(markers.weights, flat.weights, atol=SOLVE_SAME_MINIMIZER)


def test_mask_leaves_rows_out_exactly():
    rng = np.random.default_rng(5)
    basis = make_basis("random", rng)
    data = make_data(basis, rng, n_frames=30)
    markers = np.ones((30, N_ROWS // 3), bool)
    markers[5:12, 2] = False
    markers[20:, [0, 7]] = False
    data3 = data.reshape(30, -1, 3).copy()
    data3[~markers] = np.nan
    sol = solve_weights(basis.T.reshape(N_SHAPES, -1, 3), data3, lower=0, upper=1,
                        mask=markers)
    rows = np.repeat(markers, 3, axis=1)
    expected = []
    for valid, d in zip(rows, data):
        x = lsq_linear(basis[valid], d[valid], bounds=(0, 1), method="bvls").x
        expected.append(0.5 * np.sum((basis[valid] @ x - d[valid]) ** 2))
    assert sol.status == 0
    np.testing.assert_allclose(sol.cost, expected, rtol=SOLVE_OBJECTIVE_REL)


def test_rank_deficient_basis_warns():
    rng = np.random.default_rng(6)
    basis = make_basis("rank-deficient", rng)
    with pytest.warns(RuntimeWarning, match=r"rank 10 < 12 shapes"):
        solve_weights(basis, make_data(basis, rng), lower=0, upper=1)


def test_unconverged_frames_are_reported():
    rng = np.random.default_rng(7)
    basis = make_basis("ill-conditioned", rng)
    data = make_data(basis, rng)
    with pytest.warns(RuntimeWarning, match="did not converge"):
        sol = solve_weights(basis, data, lower=0, upper=1, max_iter=1, warm_start=False)
    assert sol.status == 1
    assert not sol.converged.all()
    assert np.all(sol.kkt_residual[~sol.converged] > SOLVE_TOL)
    assert np.all((sol.weights >= 0) & (sol.weights <= 1))


def test_inputs_are_not_mutated():
    rng = np.random.default_rng(8)
    basis = make_basis("random", rng)
    data = make_data(basis, rng)
    before = basis.copy(), data.copy()
    solve_weights(basis, data, lower=0, upper=1)
    np.testing.assert_array_equal(basis, before[0])
    np.testing.assert_array_equal(data, before[1])


BAD_INPUTS = [
    ({"data": "nan"}, r"data is NaN in frame 3 \(row 4, marker 1\)"),
    ({"data": "inf"}, r"data contains infinite values"),
    ({"data": "inf", "mask": "all but inf"}, r"data contains infinite values"),
    ({"data": "short"}, r"data must be \(n_frames, 30\)"),
    ({"basis": "4d"}, r"basis must be \(K, n_shapes\) or \(n_shapes, n_markers, 3\)"),
    ({"lower": 1.0, "upper": 0.0}, r"bounds of shape 0 are empty"),
    ({"lower": np.zeros(3)}, r"lower must be a number or an array of 12 bounds"),
    ({"upper": np.nan}, r"upper contains NaN"),
    ({"smoothness": -1.0}, r"smoothness must be a finite number >= 0 or one of 'gcv', got -1.0"),
    ({"smoothness": "auto"}, r"smoothness must be a number >= 0 or one of 'gcv', got 'auto'"),
    ({"smoothness": "gcv", "mask": "ones"}, r"smoothness cannot be combined with mask"),
    ({"smoothness": 1.0, "start": "wrong"}, r"start must have shape \(5, 12\), got \(5, 3\)"),
    ({"smoothness": 1.0, "mask": "ones"}, r"smoothness cannot be combined with mask"),
    ({"mask": "wrong"}, r"mask must have shape"),
    ({"tol": 0.0}, r"tol must be a positive number"),
    ({"max_iter": 0}, r"max_iter must be at least 1"),
]


@pytest.mark.parametrize("change, message", BAD_INPUTS, ids=lambda x: str(x)[:40])
def test_bad_input_raises(change, message):
    rng = np.random.default_rng(9)
    basis = make_basis("random", rng)
    data = make_data(basis, rng, n_frames=5)
    kwargs = dict(change)
    bad = kwargs.pop("data", None)
    if bad in ("nan", "inf"):
        data[3, 4] = np.nan if bad == "nan" else np.inf
    elif bad == "short":
        data = data[:, :-1]
    if kwargs.pop("basis", None) == "4d":
        basis = basis[None, None]
    if kwargs.get("mask") == "ones":
        kwargs["mask"] = np.ones(data.shape, bool)
    elif kwargs.get("mask") == "wrong":
        kwargs["mask"] = np.ones((5, 2), bool)
    if kwargs.get("start") == "wrong":
        kwargs["start"] = np.zeros((5, 3))
    if str(kwargs.get("mask")).startswith("all but"):
        kwargs["mask"] = np.isfinite(data)
    with pytest.raises(InputError, match=message):
        solve_weights(basis, data, **kwargs)


@pytest.mark.filterwarnings("ignore:the basis has rank:RuntimeWarning")
def test_real_basis_against_bvls(ict_neutral_path, ict_expressions_dir):
    """The 53 ICT shapes at 30 vertices (mm), sparse weights in [0, 1]."""
    import trimesh
    paths = sorted(ict_expressions_dir.glob("*.obj"))
    neutral = trimesh.load(ict_neutral_path, process=False).vertices
    rng = np.random.default_rng(10)
    picked = rng.choice(len(neutral), 30, replace=False)
    basis = 10.0 * np.stack([trimesh.load(p, process=False).vertices[picked] - neutral[picked]
                             for p in paths])
    weights = np.clip(rng.normal(0.1, 0.3, (8, len(paths))), 0, 1)
    data = np.einsum("tn,nmk->tmk", weights, basis) + 0.2 * rng.standard_normal((8, 30, 3))
    sol = solve_weights(basis, data, lower=0, upper=1)
    flat = basis.reshape(len(paths), -1).T
    expected = oracle_cost(flat, data.reshape(8, -1), np.zeros(len(paths)), np.ones(len(paths)))
    assert sol.status == 0
    np.testing.assert_allclose(sol.cost, expected, rtol=SOLVE_OBJECTIVE_REL)


@pytest.mark.parametrize("kind", ["random", "ill-conditioned"])
@pytest.mark.parametrize("bound_fraction", [0.2, 0.8], ids=["few-bound", "most-bound"])
def test_reduced_solve_matches_dense_solve(kind, bound_fraction):
    """Both paths (Schur complement of G⁻¹ over few bound weights, direct over few
    free ones) against a dense solve of each frame's reduced system."""
    from fit.solve._active_set import BoxQP, reduced_solve

    rng = np.random.default_rng([11, BASES.index(kind), int(10 * bound_fraction)])
    basis = make_basis(kind, rng)
    G, c = basis.T @ basis, make_data(basis, rng, n_frames=150) @ basis
    qp = BoxQP.build(G, np.zeros(N_SHAPES), np.ones(N_SHAPES))
    bound = rng.random(c.shape) < bound_fraction
    state = np.where(bound, np.where(rng.random(c.shape) < 0.5, -1, 1), 0).astype(np.int8)
    w, grad = reduced_solve(qp, state, c, refine=True)
    np.testing.assert_array_equal(w[bound], np.where(state[bound] < 0, 0.0, 1.0))
    np.testing.assert_allclose(grad, w @ G - c, rtol=0, atol=EXACT_FLOAT64 * np.abs(c).max())
    scale = np.abs(w) @ np.abs(G) + np.abs(c)
    assert np.all(np.abs(grad[~bound]) <= SOLVE_REFINED_STATIONARITY * scale[~bound])
    if kind == "random":
        for t in range(len(c)):
            f, a = ~bound[t], bound[t]
            wf = np.linalg.solve(G[np.ix_(f, f)], c[t, f] - G[np.ix_(f, a)] @ w[t, a])
            np.testing.assert_allclose(w[t, f], wf, rtol=SOLVE_ROUTES, atol=EXACT_FLOAT64)


def test_mostly_bound_frames_against_bvls():
    """Weights far outside [0, 1]: most end at a bound (the direct, |F| × |F| path)."""
    rng = np.random.default_rng(12)
    basis = make_basis("random", rng)
    truth = rng.uniform(-3.0, 4.0, (N_FRAMES, N_SHAPES))
    data = truth @ basis.T + 0.1 * rng.standard_normal((N_FRAMES, N_ROWS))
    sol = solve_weights(basis, data, lower=0, upper=1)
    at_bound = np.count_nonzero((sol.weights == 0) | (sol.weights == 1), axis=1)
    assert np.mean(2 * at_bound > N_SHAPES) > 0.5
    assert sol.status == 0
    lo, hi = np.zeros(N_SHAPES), np.ones(N_SHAPES)
    np.testing.assert_allclose(sol.cost, oracle_cost(basis, data, lo, hi),
                               rtol=SOLVE_OBJECTIVE_REL)
    assert_kkt(basis, data, sol.weights, lo, hi)


def test_frames_are_solved_independently():
    """Batching (sorting by set size, chunks, blocks) does not couple frames."""
    rng = np.random.default_rng(13)
    basis = make_basis("random", rng)
    data = make_data(basis, rng, n_frames=700)
    whole = solve_weights(basis, data, lower=0, upper=1)
    order = rng.permutation(len(data))
    parts = [solve_weights(basis, data[idx], lower=0, upper=1)
             for idx in np.array_split(order, 7)]
    weights = np.empty_like(whole.weights)
    for idx, part in zip(np.array_split(order, 7), parts):
        weights[idx] = part.weights
    np.testing.assert_allclose(weights, whole.weights, rtol=0, atol=SOLVE_ROUTES)


@pytest.mark.parametrize("bounds", BOUNDS, ids=str)
def test_kkt_residual_matches_elementwise_loop(bounds, monkeypatch):
    """The vectorized KKT residual against the case-by-case definition, element by
    element, with weights inside, on, within 1e-12 of and outside each bound; the
    frames checked in blocks of 7 (and a remainder)."""
    from fit.solve import _active_set
    from fit.solve._active_set import kkt_residual

    monkeypatch.setattr(_active_set, "_KKT_ROWS", 7)

    rng = np.random.default_rng([14, list(BOUNDS).index(bounds)])
    lo, hi = (np.broadcast_to(np.asarray(b, float), (N_SHAPES,)) for b in BOUNDS[bounds])
    pick = rng.integers(0, 6, (40, N_SHAPES))
    inside = rng.uniform(-0.5, 1.5, pick.shape)
    lo_f, hi_f = np.where(np.isfinite(lo), lo, 0.0), np.where(np.isfinite(hi), hi, 0.0)
    w = np.choose(pick, [inside, lo_f + 0 * inside, hi_f + 0 * inside,
                         lo_f + 1e-13 + 0 * inside, lo_f - 0.25 + 0 * inside,
                         hi_f + 0.25 + 0 * inside])
    g = rng.standard_normal(w.shape) * (rng.random(w.shape) < 0.8)
    scale = np.abs(g) + rng.uniform(0.1, 2.0, w.shape)
    expected = np.zeros(len(w))
    for t, j in np.ndindex(*w.shape):
        at_lo = np.isfinite(lo[j]) and w[t, j] <= lo[j] + SOLVE_AT_BOUND * max(1.0, abs(lo[j]))
        at_hi = np.isfinite(hi[j]) and w[t, j] >= hi[j] - SOLVE_AT_BOUND * max(1.0, abs(hi[j]))
        if at_lo and at_hi:
            viol = 0.0
        elif at_lo:
            viol = max(-g[t, j], 0.0)
        elif at_hi:
            viol = max(g[t, j], 0.0)
        else:
            viol = abs(g[t, j])
        feas = max(lo[j] - w[t, j], w[t, j] - hi[j], 0.0) / max(1.0, abs(w[t, j]))
        expected[t] = max(expected[t], viol / scale[t, j], feas)
    np.testing.assert_allclose(kkt_residual(w, g, scale, lo, hi), expected,
                               rtol=SOLVE_KKT_LOOP_REL, atol=0)


@pytest.mark.parametrize("kind", ["random", "ill-conditioned"])
def test_update_by_one_variable_matches_fresh_solve(kind):
    """Bordering the factored systems with one bound or freed variable per frame
    (or none) gives the weights and gradient of solving the new state from scratch."""
    from fit.solve._active_set import BoxQP, reduced_solve
    from fit.solve._reduced import ReducedSystems, schur_weights

    rng = np.random.default_rng([15, BASES.index(kind)])
    basis = make_basis(kind, rng)
    G, c = basis.T @ basis, make_data(basis, rng, n_frames=400) @ basis
    lo, hi = np.r_[np.zeros(10), -np.inf, 0.0], np.r_[np.ones(10), 2.0, np.inf]
    qp = BoxQP.build(G, lo, hi)
    bound = rng.random(c.shape) < rng.uniform(0.05, 0.45, (len(c), 1))
    state = np.where(bound, np.where(rng.random(c.shape) < 0.5, -1, 1), 0).astype(np.int8)
    state[:, 10], state[:, 11] = bound[:, 10], -1 * bound[:, 11]  # at their finite bound
    systems = ReducedSystems(qp, state)
    systems.solve(c)
    var = rng.integers(0, N_SHAPES, len(c))
    var[::7] = N_SHAPES  # frames with no change
    new = state.copy()
    rows = np.flatnonzero(var < N_SHAPES)
    freed = state[rows, var[rows]] != 0
    side = np.where(var[rows] == 10, 1, np.where(var[rows] == 11, -1,
                                                  np.where(rng.random(rows.size) < 0.5, -1, 1)))
    new[rows, var[rows]] = np.where(freed, 0, side)
    lam, updated = systems.update(var, new[np.arange(len(c)), np.minimum(var, N_SHAPES - 1)])
    w = schur_weights(qp, new, lam, systems.unconstrained)
    # the frames factored through the Schur complement (fewer than half bound)
    np.testing.assert_array_equal(updated, 2 * np.count_nonzero(state, axis=1) < N_SHAPES)
    assert 100 < np.count_nonzero(updated) < 390
    w, lam, new = w[updated], lam[updated], new[updated]
    expected_w, expected_grad = reduced_solve(qp, new, c[updated], refine=True)
    scale = np.abs(expected_w) @ np.abs(G) + np.abs(c[updated])
    np.testing.assert_array_equal(w[new != 0], qp.bound_values(new)[new != 0])
    tol = SOLVE_ROUTES if kind == "random" else SOLVE_ROUTES_ILL_CONDITIONED
    np.testing.assert_allclose(w, expected_w, rtol=0, atol=tol * np.abs(expected_w).max())
    assert np.all(lam[new == 0] == 0)
    assert np.all(np.abs(lam - expected_grad)[new != 0] <= tol * scale[new != 0])


def test_update_leaves_direct_and_refined_systems_alone():
    """Frames solved directly (most weights bound) or refined cannot be updated."""
    from fit.solve._active_set import BoxQP
    from fit.solve._reduced import ReducedSystems

    rng = np.random.default_rng(16)
    basis = make_basis("ill-conditioned", rng)
    G, c = basis.T @ basis, make_data(basis, rng, n_frames=50) @ basis
    qp = BoxQP.build(G, np.zeros(N_SHAPES), np.ones(N_SHAPES))
    state = np.zeros(c.shape, np.int8)
    state[:25, 0] = -1  # one bound: the Schur path
    state[25:] = -1  # all bound: the direct path
    systems = ReducedSystems(qp, state)
    systems.solve(c)
    var, now = np.full(len(c), 5), np.ones(len(c), np.int8)  # bind a free weight
    assert systems.update(var, now)[1].tolist() == [True] * 25 + [False] * 25
    systems.solve(c, refine=True)
    assert not systems.update(var, now)[1].any()


def test_fixed_weights_against_bvls_on_the_rest():
    """Shapes with lower == upper stay at that value; the others match bvls solving
    for them alone with the fixed shapes' contribution taken off the data."""
    rng = np.random.default_rng(17)
    basis = make_basis("random", rng)
    data = make_data(basis, rng)
    lo, hi = np.zeros(N_SHAPES), np.ones(N_SHAPES)
    lo[[2, 9]] = hi[[2, 9]] = [0.3, 1.0]
    sol = solve_weights(basis, data, lower=lo, upper=hi)
    assert sol.status == 0
    np.testing.assert_array_equal(sol.weights[:, [2, 9]],
                                  np.broadcast_to([0.3, 1.0], (N_FRAMES, 2)))
    rest = np.setdiff1d(np.arange(N_SHAPES), [2, 9])
    residual_data = data - np.array([0.3, 1.0]) @ basis[:, [2, 9]].T
    np.testing.assert_allclose(sol.cost,
                               oracle_cost(basis[:, rest], residual_data, lo[rest], hi[rest]),
                               rtol=SOLVE_OBJECTIVE_REL)


def real_sparse_frames(neutral_path, expressions_dir):
    """The 53 ICT shapes at 66 vertices (mm, K = 198 rows) and 300 noisy frames of
    sparse weights in [0, 1] (many at a bound)."""
    import trimesh
    paths = sorted(expressions_dir.glob("*.obj"))
    neutral = trimesh.load(neutral_path, process=False).vertices
    rng = np.random.default_rng(18)
    picked = rng.choice(len(neutral), 66, replace=False)
    flat = 10.0 * np.stack([(trimesh.load(p, process=False).vertices[picked]
                             - neutral[picked]).ravel() for p in paths], axis=1)
    weights = np.clip(rng.normal(0.15, 0.3, (300, len(paths))), 0, 1)
    return flat, weights @ flat.T + 0.2 * rng.standard_normal((300, flat.shape[0]))


@pytest.mark.filterwarnings("ignore:the basis has rank:RuntimeWarning")
def test_many_real_frames_against_bvls(ict_neutral_path, ict_expressions_dir):
    """Most of these frames go through the monotone phase (factored and updated systems)."""
    flat, data = real_sparse_frames(ict_neutral_path, ict_expressions_dir)
    sol = solve_weights(flat, data, lower=0, upper=1)
    assert sol.status == 0
    assert np.mean(sol.n_iter > 2) > 0.5
    lo, hi = np.zeros(flat.shape[1]), np.ones(flat.shape[1])
    np.testing.assert_allclose(sol.cost, oracle_cost(flat, data, lo, hi), rtol=SOLVE_OBJECTIVE_REL)
    assert_kkt(flat, data, sol.weights, lo, hi)


def test_converging_frames_go_on_with_primal_dual_steps(ict_neutral_path, ict_expressions_dir,
                                                        monkeypatch):
    """Frames whose primal-dual steps still change many variables, fewer each step,
    take more of them instead of the monotone phase's one change an iteration: fewer
    iterations, the same optimum (against lsq_linear)."""
    import fit.solve._active_set as active_set

    flat, data = real_sparse_frames(ict_neutral_path, ict_expressions_dir)
    sol = solve_weights(flat, data, lower=0, upper=1)
    monkeypatch.setattr(active_set, "_PDAS_MANY", flat.shape[1] + 1)     # none goes on
    monotone = solve_weights(flat, data, lower=0, upper=1)
    assert sol.status == monotone.status == 0
    assert np.count_nonzero(sol.n_iter != monotone.n_iter) > 0
    assert sol.n_iter.sum() < monotone.n_iter.sum()
    lo, hi = np.zeros(flat.shape[1]), np.ones(flat.shape[1])
    np.testing.assert_allclose(sol.cost, oracle_cost(flat, data, lo, hi), rtol=SOLVE_OBJECTIVE_REL)
    assert_kkt(flat, data, sol.weights, lo, hi)


@pytest.mark.filterwarnings("ignore:the basis has rank:RuntimeWarning")
@pytest.mark.parametrize("kind", BASES)
def test_reported_kkt_residual_is_that_of_the_weights(kind):
    """Each frame's KKT residual (kept from where it converged) equals the residual
    of its final weights computed afresh, up to the rounding of the gradient."""
    from fit.solve._active_set import BoxQP, residual

    rng = np.random.default_rng([19, BASES.index(kind)])
    basis = make_basis(kind, rng)
    data = make_data(basis, rng, n_frames=200)
    sol = solve_weights(basis, data, lower=0, upper=1)
    qp = BoxQP.build(basis.T @ basis, np.zeros(N_SHAPES), np.ones(N_SHAPES))
    expected = residual(qp, sol.weights, data @ basis)
    np.testing.assert_allclose(sol.kkt_residual, expected, rtol=0, atol=SOLVE_KKT_RECOMPUTED)
    assert np.all(expected <= SOLVE_TOL)


def test_update_leaves_frames_with_nothing_bound_alone():
    """Frames with every weight free have no factored system to border (enough of
    them make a batch of their own, which is never factored): not updated."""
    from fit.solve._active_set import BoxQP, reduced_solve
    from fit.solve._reduced import ReducedSystems, schur_weights

    rng = np.random.default_rng(20)
    basis = make_basis("random", rng)
    G, c = basis.T @ basis, make_data(basis, rng, n_frames=1200) @ basis
    qp = BoxQP.build(G, np.zeros(N_SHAPES), np.ones(N_SHAPES))
    state = np.zeros(c.shape, np.int8)
    state[600:, 0] = -1
    systems = ReducedSystems(qp, state)
    systems.solve(c)
    new = state.copy()
    new[:, 3] = 1
    lam, updated = systems.update(np.full(len(c), 3), new[:, 3])
    np.testing.assert_array_equal(updated, np.arange(len(c)) >= 600)
    w = schur_weights(qp, new[updated], lam[updated], systems.unconstrained[updated])
    np.testing.assert_allclose(w, reduced_solve(qp, new[updated], c[updated])[0],
                               rtol=0, atol=SOLVE_ROUTES)


def test_solve_weights_leaves_its_arguments_alone():
    """Basis and data are read in place (not copied): the solve must not write to them."""
    rng = np.random.default_rng(7)
    basis, data = rng.standard_normal((5, 4, 3)), rng.standard_normal((30, 4, 3))
    kept = basis.copy(), data.copy()
    for smoothness in (0.0, 0.3, "gcv"):
        solve_weights(basis, data, lower=0.0, upper=1.0, smoothness=smoothness)
        estimate_weights_by_sampling(basis, data, lower=0.0, upper=1.0, n_samples=50,
                                     n_neighbors=10)
        np.testing.assert_array_equal(basis, kept[0])
        np.testing.assert_array_equal(data, kept[1])


@pytest.mark.parametrize("lower", [True, False], ids=["lower-triangle", "whole"])
def test_principal_submatrices_match_indexing_each_frame(lower):
    """The gathered systems against ``mat[np.ix_(sel, sel)]`` frame by frame, padded
    entries (index n) selecting the identity's row and column."""
    from fit.solve._reduced import _principal

    rng = np.random.default_rng(17)
    n, m, frames = 9, 5, 40
    mat = rng.standard_normal((n, n))
    ext = np.eye(n + 1)
    ext[:n, :n] = mat
    sel = np.stack([np.sort(rng.choice(n + 1, m, replace=False)) for _ in range(frames)], 1)
    out = _principal(mat, sel, lower=lower)
    assert out.shape == (m + 1, m, frames)
    rows, cols = np.tril_indices(m) if lower else np.indices((m, m)).reshape(2, -1)
    for t in range(frames):
        expected = ext[np.ix_(sel[:, t], sel[:, t])]
        np.testing.assert_array_equal(out[rows, cols, t], expected[rows, cols])


@BOTH_PATHS
@pytest.mark.parametrize("kind", ["moderate", "ill-conditioned"])
@pytest.mark.parametrize("bounds", ["unit", "per-shape", "fixed"])
def test_compiled_iterations_are_numpys(kind, bounds, monkeypatch):
    """Frame by frame, compiled, the box QP takes the NumPy path's iterations: the same
    number in every frame, through both phases (many frames reach the monotone one), with
    the refinement of an ill-conditioned G (cond 1e10, in either phase: 2,000 frames, for
    the few the primal-dual phase refines) or without it (cond 1e5); the same optimum
    (cost to rounding, weights to rounding times the condition), against bvls."""
    from fit.solve._reduced import BoxQP

    rng = np.random.default_rng([20, len(kind), len(bounds)])
    if kind == "moderate":
        u, _, vt = np.linalg.svd(rng.standard_normal((N_ROWS, N_SHAPES)), full_matrices=False)
        basis = u @ np.diag(np.logspace(0, -2.5, N_SHAPES)) @ vt
    else:
        basis = make_basis(kind, rng)
    data = make_data(basis, rng, n_frames=2000)
    lo, hi = BOUNDS["unit" if bounds == "fixed" else bounds]
    if bounds == "fixed":
        lo, hi = np.zeros(N_SHAPES), np.ones(N_SHAPES)
        lo[4] = hi[4] = 0.5
    qp = BoxQP.build(basis.T @ basis, *np.broadcast_arrays(lo, hi))
    assert (qp.refinements > 0) == (kind == "ill-conditioned")
    calls = []
    monkeypatch.setattr(active_set, "_iterate_compiled", lambda *a: calls.append(1) or
                        ITERATE_COMPILED(*a))
    monkeypatch.setattr(active_set, "_compiled_solve", COMPILED_SOLVE)
    monkeypatch.setattr(active_set, "_FOLLOW_TRIAL", 0)     # every frame from its own start
    compiled = solve_weights(basis, data, lower=lo, upper=hi)
    monkeypatch.setattr(active_set, "_compiled_solve", lambda: None)
    numpy = solve_weights(basis, data, lower=lo, upper=hi)
    assert calls, "the compiled iterations did not run"
    assert compiled.status == numpy.status == 0
    np.testing.assert_array_equal(compiled.n_iter, numpy.n_iter)
    assert np.mean(compiled.n_iter > active_set._PDAS_MAX_ITER) > 0.1     # the monotone phase
    np.testing.assert_allclose(compiled.cost, numpy.cost, rtol=SOLVE_OBJECTIVE_REL)
    np.testing.assert_allclose(compiled.weights, numpy.weights, rtol=0,
                               atol=SOLVE_SAME_MINIMIZER * qp.cond / 1e5)
    if bounds == "fixed":                           # (bvls needs lower < upper)
        assert np.all(compiled.weights[:, 4] == 0.5)
    else:
        np.testing.assert_allclose(compiled.cost[:200], oracle_cost(basis, data[:200], lo, hi),
                                   rtol=SOLVE_OBJECTIVE_REL)
        assert_kkt(basis, data, compiled.weights, lo, hi)



def own_and_trial_starts(basis, data, monkeypatch):
    """Compiled solves in [0, 1] with every frame from its own start, and with the trial
    of the frame before's state: both converge, to the same weights bit for bit."""
    monkeypatch.setattr(active_set, "_compiled_solve", COMPILED_SOLVE)
    fits = []
    for trial in (0, active_set._FOLLOW_TRIAL):
        monkeypatch.setattr(active_set, "_FOLLOW_TRIAL", trial)
        fits.append(solve_weights(basis, data, lower=0.0, upper=1.0))
    own, trying = fits
    assert own.status == trying.status == 0
    np.testing.assert_array_equal(trying.weights, own.weights)
    return own, trying


@BOTH_PATHS
@pytest.mark.parametrize("order", ["in time", "shuffled"])
def test_frames_in_order_start_where_the_frame_before_ended_when_that_pays(
        order, ict_basis, ict_layout, arkit_performance, monkeypatch):
    """A take whose rest pose is not the basis' neutral (every weight 0.1 lower: a neutral
    frame with a trace of expression) ends with many weights at 0, which the frames' own
    starts (their clipped unconstrained minimizers) miss. Compiled, frames in time order
    try both starts and take the state the frame before ended in: the same weights, bit
    for bit, in far fewer iterations; shuffled, the trial costs little. The weights are
    NumPy's (which takes every frame from its own start) and the answer's (KKT)."""
    from mocap.synth.performance import match_shape_names

    columns = match_shape_names(arkit_performance.names, ict_basis.names)
    truth = np.zeros((1000, len(ict_basis.names)))
    for i, name in enumerate(ict_basis.names):
        if name in columns:
            truth[:, i] = np.clip(arkit_performance.weights[:1000, columns[name]], 0.0, 1.0)
    V0, E = ict_basis.neutral.vertices, ict_basis.displacements
    rest = ict_layout.positions(V0)
    basis = np.stack([(ict_layout.positions(V0 + e) - rest).ravel() for e in E], axis=1)
    data = (ict_layout.positions_under_weights(V0, E, truth - 0.1) - rest).reshape(1000, -1)
    data += 0.02 * np.random.default_rng(9).standard_normal(data.shape)   # 0.2 mm, in cm
    if order == "shuffled":
        data = data[np.random.default_rng(10).permutation(len(data))]
    own, trying = own_and_trial_starts(basis, data, monkeypatch)
    if order == "in time":
        assert trying.n_iter.sum() < 0.6 * own.n_iter.sum()
    else:
        assert trying.n_iter.sum() < 1.05 * own.n_iter.sum()
    monkeypatch.setattr(active_set, "_compiled_solve", lambda: None)
    numpy = solve_weights(basis, data, lower=0.0, upper=1.0)
    cond = np.linalg.cond(basis.T @ basis)
    np.testing.assert_allclose(trying.weights, numpy.weights, rtol=0,
                               atol=SOLVE_SAME_MINIMIZER * cond / 1e5)
    assert_kkt(basis, data, trying.weights, np.zeros(len(E)), np.ones(len(E)))


@BOTH_PATHS
def test_frames_that_are_no_sequence_keep_their_own_starts(monkeypatch):
    """Independent frames, whose neighbours' states are a poor start (about twice the
    iterations): the trial keeps their own starts, at the cost of its few frames."""
    rng = np.random.default_rng(11)
    basis = make_basis("random", rng)
    data = make_data(basis, rng, n_frames=4000)
    own, trying = own_and_trial_starts(basis, data, monkeypatch)
    assert trying.n_iter.sum() < 1.05 * own.n_iter.sum()


@BOTH_PATHS
def test_numba_without_a_cache_folder_falls_back_to_numpy_with_a_warning(monkeypatch):
    """numba raises RuntimeError when it can write its compiled code nowhere (a read-only
    install and home): NumPy then iterates, with a warning saying so; a missing module
    (numba not installed) is None without one."""
    import warnings

    from helpers import numba_cannot_cache

    from mocap.util.optional import compiled

    rng = np.random.default_rng(23)
    basis = make_basis("random", rng)
    data = make_data(basis, rng)
    monkeypatch.setattr(active_set, "_compiled_solve", lambda: None)
    expected = solve_weights(basis, data, lower=0, upper=1)
    monkeypatch.undo()
    numba_cannot_cache(monkeypatch, "fit.solve._box_qp_kernel")
    active_set._compiled_solve.cache_clear()
    try:
        with pytest.warns(UserWarning, match="compiled box-QP iteration is off .*no locator"):
            got = solve_weights(basis, data, lower=0, upper=1)
        assert active_set._compiled_solve() is None
    finally:
        monkeypatch.undo()
        active_set._compiled_solve.cache_clear()
    np.testing.assert_array_equal(got.weights, expected.weights)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert compiled("fit.solve.no_such_kernel", "f", what="x", fallback="y") is None
