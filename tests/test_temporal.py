"""Moving average, temporally smooth weights, and the sampling estimator."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.linalg
from scipy.optimize import lsq_linear
from tolerances import (
    EXACT_FLOAT64,
    LOOP_ORACLE,
    SMOOTH_VS_STACKED,
    SOLVE_KKT_REL,
    SOLVE_OBJECTIVE_REL,
    SOLVE_SAME_MINIMIZER,
)

import fit.solve._smooth
from fit.solve.sampling_estimator import estimate_weights_by_sampling
from fit.solve.temporal import EDGE_MODES, moving_average
from fit.solve.weights import solve_weights
from mocap.errors import InputError


def brute_moving_average(data, window, edge):
    half = window // 2
    out = np.full(data.shape, np.nan)
    for t in range(len(data)):
        idx = np.arange(t - half, t + half + 1)
        if edge == "nearest":
            idx = np.clip(idx, 0, len(data) - 1)
        else:
            idx = idx[(idx >= 0) & (idx < len(data))]
        win = data[idx]
        count = np.sum(~np.isnan(win), axis=0)
        out[t] = np.where(count > 0, np.nansum(win, axis=0) / np.maximum(count, 1), np.nan)
    return out


@pytest.mark.parametrize("edge", EDGE_MODES)
@pytest.mark.parametrize("window", [1, 3, 41])
def test_moving_average_matches_loop(edge, window):
    rng = np.random.default_rng(window)
    data = 100 * rng.standard_normal((90, 4, 3))
    data[rng.random((90, 4)) < 0.2] = np.nan
    data[10:70, 1] = np.nan  # a gap longer than the window
    got = moving_average(data, window=window, edge=edge)
    np.testing.assert_allclose(got, brute_moving_average(data, window, edge), atol=LOOP_ORACLE)
    assert np.isnan(got).any() == (window < 60)


def test_moving_average_keeps_constant_and_input():
    data = np.full((50, 2), 3.0)
    before = data.copy()
    np.testing.assert_allclose(moving_average(data), 3.0)
    np.testing.assert_array_equal(data, before)


@pytest.mark.parametrize("kwargs, message", [
    ({"window": 4}, "window must be an odd number of frames"),
    ({"window": 0}, "window must be at least 1"),
    ({"edge": "wrap"}, "edge must be one of"),
])
def test_moving_average_bad_input(kwargs, message):
    with pytest.raises(InputError, match=message):
        moving_average(np.zeros((5, 3)), **kwargs)


def stacked_problem(basis, data, lam):
    """The whole sequence as one least-squares problem: data rows, then √λ (w_t − w_{t−1})."""
    T, n = len(data), basis.shape[1]
    diff = np.diff(np.eye(T), axis=0)
    big = np.vstack([np.kron(np.eye(T), basis), np.sqrt(lam) * np.kron(diff, np.eye(n))])
    rhs = np.concatenate([data.ravel(), np.zeros((T - 1) * n)])
    return big, rhs


def sequence_cost(basis, data, lam, w):
    return 0.5 * np.sum((w @ basis.T - data) ** 2) + 0.5 * lam * np.sum(np.diff(w, axis=0) ** 2)


@pytest.mark.parametrize("bounds", [(-np.inf, np.inf), (0.0, 1.0), (-0.1, 1.1)])
@pytest.mark.parametrize("lam", [0.3, 10.0])
def test_smoothness_matches_stacked_oracle(bounds, lam):
    rng = np.random.default_rng(int(lam * 10))
    T, n, K = 9, 5, 12
    basis = rng.standard_normal((K, n))
    data = rng.uniform(-0.3, 1.3, (T, n)) @ basis.T + 0.2 * rng.standard_normal((T, K))
    sol = solve_weights(basis, data, lower=bounds[0], upper=bounds[1], smoothness=lam)
    big, rhs = stacked_problem(basis, data, lam)
    if np.isinf(bounds[0]):
        ref = np.linalg.lstsq(big, rhs, rcond=None)[0]
    else:
        ref = lsq_linear(big, rhs, bounds=bounds, method="bvls", max_iter=10_000).x
    assert sol.status == 0
    expected = sequence_cost(basis, data, lam, ref.reshape(T, n))
    got = sequence_cost(basis, data, lam, sol.weights)
    assert abs(got - expected) <= SOLVE_OBJECTIVE_REL * expected
    np.testing.assert_allclose(sol.cost, 0.5 * np.sum((sol.weights @ basis.T - data) ** 2, 1))


def _smooth_problem(rng, T, n, K, *, rank=None, spread=(-0.3, 1.3), noise=0.2,
                    collinear=False):
    """A basis (rank-deficient with ``rank``, ill-conditioned if ``collinear``) and
    data from smooth weights in ``spread``."""
    basis = rng.standard_normal((K, n))
    if collinear:
        basis = rng.standard_normal((K, 1)) + 0.05 * basis
    if rank is not None:
        basis = basis[:, :rank] @ rng.standard_normal((rank, n))
    phase = rng.uniform(0, 2 * np.pi, n)
    t = np.arange(T)[:, None]
    lo, hi = spread
    truth = lo + (hi - lo) * 0.5 * (1 + np.sin(2 * np.pi * t / rng.uniform(8, 40, n) + phase))
    return basis, truth @ basis.T + noise * rng.standard_normal((T, K))


@pytest.mark.parametrize("case", ["upper active", "one-sided", "singular", "fixed shape"])
@pytest.mark.parametrize("lam", [0.5, 50.0])
def test_smoothness_matches_stacked_oracle_hard_cases(case, lam):
    """Weights pushed above 1, a one-sided box, a rank-deficient basis, a shape with
    lower = upper: the sequence objective equals lsq_linear's on the stacked problem."""
    rng = np.random.default_rng(int(lam) + len(case))
    T, n, K = 14, 4, 10
    lower, upper = np.zeros(n), np.ones(n)
    basis, data = _smooth_problem(rng, T, n, K, rank=3 if case == "singular" else None,
                                  spread=(0.2, 1.6) if case == "upper active" else (-0.3, 1.3))
    if case == "one-sided":
        upper[:] = np.inf
    if case == "fixed shape":
        lower[1] = upper[1] = 0.25
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)    # the singular basis
        sol = solve_weights(basis, data, lower=lower, upper=upper, smoothness=lam)
    big, rhs = stacked_problem(basis, data, lam)
    lo, hi = np.tile(lower, T), np.tile(upper, T)
    ref = lo.copy()                   # lsq_linear needs lower < upper: fixed columns out
    var = lo < hi
    ref[var] = lsq_linear(big[:, var], rhs - big[:, ~var] @ lo[~var], bounds=(lo[var], hi[var]),
                          method="bvls", max_iter=10_000).x
    ref = ref.reshape(T, n)
    assert sol.status == 0
    if case == "upper active":
        assert (sol.weights == 1.0).sum() > T      # the case is what it says
    expected = sequence_cost(basis, data, lam, ref)
    got = sequence_cost(basis, data, lam, sol.weights)
    assert got - expected <= SOLVE_OBJECTIVE_REL * expected
    if case != "singular":                         # unique minimizer
        np.testing.assert_allclose(sol.weights, ref, atol=SMOOTH_VS_STACKED)


@pytest.mark.parametrize("admm_steps", [0, fit.solve._smooth._ADMM_ITER])
@pytest.mark.parametrize("bounds", [(0.0, 1.0), (-0.05, 1.05)])
@pytest.mark.parametrize("lam", [0.1, 3.0, 300.0])
def test_long_smooth_sequence_meets_dense_kkt(bounds, lam, admm_steps, monkeypatch):
    """A take long enough for the local phase (windows around state changes), from
    the ADMM start or (0 steps) the clipped unbounded minimizer, on a basis of
    nearly collinear shapes: the KKT conditions of the whole sequence, from the
    dense Hessian, hold to tol."""
    monkeypatch.setattr(fit.solve._smooth, "_ADMM_ITER", admm_steps)
    rng = np.random.default_rng(int(10 * lam))
    T, n, K = 400, 5, 12
    basis, data = _smooth_problem(rng, T, n, K, collinear=True)
    sol = solve_weights(basis, data, lower=bounds[0], upper=bounds[1], smoothness=lam)
    assert sol.status == 0
    w = sol.weights.ravel()
    lap = np.diag(np.r_[1.0, np.full(T - 2, 2.0), 1.0]) - np.eye(T, k=1) - np.eye(T, k=-1)
    hess = np.kron(np.eye(T), basis.T @ basis) + lam * np.kron(lap, np.eye(n))
    grad = hess @ w - (data @ basis).ravel()
    scale = np.abs(hess) @ np.abs(w) + np.abs(data @ basis).ravel()
    rel = grad / scale
    lo_on, hi_on = w <= bounds[0], w >= bounds[1]
    assert np.all((w >= bounds[0]) & (w <= bounds[1]))
    assert np.abs(rel[~lo_on & ~hi_on]).max() <= SOLVE_KKT_REL
    assert rel[lo_on].min(initial=0) >= -SOLVE_KKT_REL
    assert rel[hi_on].max(initial=0) <= SOLVE_KKT_REL
    assert (lo_on | hi_on).any()
    if admm_steps == 0:    # the local phase ran: some frames took part in more solves
        assert sol.n_iter.max() > sol.n_iter.min()


@pytest.mark.parametrize("start", ["frames", "zeros", "ones", "answer"])
def test_smooth_start_changes_the_work_not_the_result(start):
    rng = np.random.default_rng(21)
    T, n, K = 300, 5, 12
    basis, data = _smooth_problem(rng, T, n, K, collinear=True)
    ref = solve_weights(basis, data, lower=0, upper=1, smoothness=2.0)
    given = {"frames": solve_weights(basis, data, lower=0, upper=1).weights,
             "zeros": np.zeros((T, n)), "ones": np.ones((T, n)), "answer": ref.weights}[start]
    sol = solve_weights(basis, data, lower=0, upper=1, smoothness=2.0, start=given)
    assert sol.status == 0
    np.testing.assert_allclose(sol.weights, ref.weights, rtol=0, atol=SOLVE_SAME_MINIMIZER)
    if start == "answer":           # the optimal active set: one global solve
        assert sol.n_iter.max() == 1


class _Moves:
    """A ``follow`` of solve_weights that walks through `datas`, one per global step, then
    holds the last data until the solve is optimal; records what it was called with."""

    def __init__(self, datas):
        self.datas, self.calls = list(datas), []

    def __call__(self, w, optimal):
        self.calls.append((w.copy(), optimal))
        if len(self.calls) < len(self.datas):
            return self.datas[len(self.calls)]
        return None if optimal else self.datas[-1]


@pytest.mark.parametrize("bounds", [(0.0, 1.0), (-np.inf, np.inf)])
def test_followed_problem_ends_at_the_minimizer_of_its_last_data(bounds):
    """Data that move after every global step (far at first, active set and all): the
    result is the smooth minimizer of the last data, solved on its own, with the cost and
    KKT residual of those data; every step was seen with its weights."""
    rng = np.random.default_rng(31)
    T, n, K = 200, 5, 12
    basis, data = _smooth_problem(rng, T, n, K, collinear=True)
    datas = [data + 0.5 * 0.3 ** j * rng.standard_normal(data.shape) for j in range(6)]
    moves = _Moves(datas)
    sol = solve_weights(basis, datas[0], lower=bounds[0], upper=bounds[1], smoothness=2.0,
                        follow=moves)
    alone = solve_weights(basis, datas[-1], lower=bounds[0], upper=bounds[1], smoothness=2.0)
    assert sol.status == 0, sol.message
    np.testing.assert_allclose(sol.weights, alone.weights, rtol=0, atol=SOLVE_SAME_MINIMIZER)
    np.testing.assert_allclose(sol.cost, 0.5 * np.sum((sol.weights @ basis.T - datas[-1]) ** 2,
                                                      axis=1))
    assert sol.kkt_residual.max() <= SOLVE_KKT_REL
    assert len(moves.calls) >= len(datas) and moves.calls[-1][1]
    assert np.isinf(bounds[0]) or not moves.calls[0][1]  # moved while not yet optimal
    assert np.all(sol.n_iter >= len(moves.calls))        # a global solve per call at least
    np.testing.assert_allclose(np.clip(moves.calls[-1][0], *bounds), sol.weights,
                               rtol=0, atol=EXACT_FLOAT64)


def test_a_cycle_while_the_data_move_holds_them_and_ends_optimal(monkeypatch):
    """Global steps that go back and forth between two states (forced) while the data
    move: the first repeat turns the local phase off, the second holds the data (no
    calls of follow until the state is optimal) instead of stopping; the solve then
    ends at the minimizer of the last data."""
    rng = np.random.default_rng(12)
    T, n, K = 150, 5, 12
    basis, data = _smooth_problem(rng, T, n, K, collinear=True)
    real = fit.solve._smooth._step
    forced = []

    def back_and_forth(qp, state, w, grad):
        if len(state) == T and len(forced) < 4:
            forced.append(1)
            return np.full_like(state, 0 if len(forced) % 2 else -1)
        return real(qp, state, w, grad)
    monkeypatch.setattr(fit.solve._smooth, "_step", back_and_forth)
    solve, global_solves = fit.solve._smooth._reduced, []

    def counted(qp, band, c, state, w, frames=None, whole=None):
        global_solves.append(frames is None)
        return solve(qp, band, c, state, w, frames, whole)
    monkeypatch.setattr(fit.solve._smooth, "_reduced", counted)
    datas = [data + 0.3 ** j * rng.standard_normal(data.shape) for j in range(12)]
    moves = _Moves(datas)
    sol = solve_weights(basis, datas[0], lower=0, upper=1, smoothness=2.0,
                        start=np.zeros((T, n)), follow=moves)
    n_global = sum(global_solves)
    alone = solve_weights(basis, moves.datas[min(len(moves.calls), len(datas)) - 1],
                          lower=0, upper=1, smoothness=2.0)
    assert len(forced) == 4 and sol.status == 0, sol.message
    np.testing.assert_allclose(sol.weights, alone.weights, rtol=0, atol=SOLVE_SAME_MINIMIZER)
    assert n_global > len(moves.calls)                   # global solves without a call


def test_gradient_is_the_sequence_hessians_product():
    """The smooth solve's gradient and term magnitudes, of the whole sequence (by slices)
    and of a window of frames (by index), against the dense Hessian I ⊗ G + λ L ⊗ I."""
    rng = np.random.default_rng(12)
    T, n, lam = 9, 4, 0.7
    B = rng.standard_normal((7, n))
    G = B.T @ B
    c, w = rng.standard_normal((T, n)), rng.standard_normal((T, n))
    lap = np.diag(np.r_[1.0, np.full(T - 2, 2.0), 1.0]) - np.eye(T, k=1) - np.eye(T, k=-1)
    hessian = np.kron(np.eye(T), G) + lam * np.kron(lap, np.eye(n))
    grad = (hessian @ w.ravel() - c.ravel()).reshape(T, n)
    magnitude = (np.abs(hessian) @ np.abs(w).ravel() + np.abs(c).ravel()).reshape(T, n)
    whole = fit.solve._smooth.gradient(G, c, lam, w)
    every = fit.solve._smooth.gradient(G, c, lam, w, np.arange(T))
    for got, want in zip(whole, (grad, magnitude)):
        np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-13)
    for got, want in zip(every, whole):
        np.testing.assert_array_equal(got, want)
    frames = np.array([0, 1, 4, 8])
    window = fit.solve._smooth.gradient(G, c, lam, w, frames)
    for got, want in zip(window, (grad, magnitude)):
        np.testing.assert_allclose(got, want[frames], rtol=1e-13, atol=1e-13)
    assert fit.solve._smooth.gradient(G, c, lam, w, frames, scale=False)[1] is None


def test_banded_matrix_without_numbas_cache_is_formed_by_numpy(monkeypatch):
    """Where numba can keep its compiled code nowhere, the banded matrix is NumPy's, with a
    warning saying so; the smooth solve's weights are the same."""
    from helpers import numba_cannot_cache

    rng = np.random.default_rng(14)
    basis, data = _smooth_problem(rng, 40, 5, 12, collinear=True)
    expected = solve_weights(basis, data, lower=0, upper=1, smoothness=2.0)
    numba_cannot_cache(monkeypatch, "fit.solve._band_kernel")
    fit.solve._smooth._compiled_band.cache_clear()
    try:
        with pytest.warns(UserWarning, match="compiled banded matrix is off .*no locator"):
            got = solve_weights(basis, data, lower=0, upper=1, smoothness=2.0)
        assert fit.solve._smooth._compiled_band() is None
    finally:
        monkeypatch.undo()
        fit.solve._smooth._compiled_band.cache_clear()
    np.testing.assert_array_equal(got.weights, expected.weights)


def test_the_rough_start_ends_at_its_bounds_exactly():
    """The ADMM start steps in float32 but ends in float64: within bounds float32 cannot
    hold (-0.01, 1.01), the weights at a bound are at it exactly, so that the active set
    read from them is the start's; and that active set is the one of the same ADMM in
    float64 but for a few weights."""
    rng = np.random.default_rng(21)
    T, n, K = 400, 6, 15
    basis, data = _smooth_problem(rng, T, n, K, spread=(-0.4, 1.4))
    lo, hi = np.full(n, -0.01), np.full(n, 1.01)
    assert np.float32(lo[0]) != lo[0] and np.float32(hi[0]) != hi[0]
    G, c, lam = basis.T @ basis, data @ basis, 3.0
    spectrum = fit.solve._smooth.Spectrum.build(G, T)
    start = fit.solve._smooth.rough(spectrum, spectrum.transform(c), lam, lo, hi, 25)
    assert start.dtype == np.float64 and start.shape == (T, n)
    assert ((start >= lo) & (start <= hi)).all()
    at_lo, at_hi = start <= lo, start >= hi
    assert at_lo.sum() > 100 and at_hi.sum() > 100
    np.testing.assert_array_equal(start[at_lo], lo[0])
    np.testing.assert_array_equal(start[at_hi], hi[0])
    # the same steps in float64 (the oracle: the iteration as the docstring writes it)
    eig = spectrum.eig
    rho = float(np.sqrt(eig[0] * (eig[-1] + 4.0 * lam)))
    denom = eig[None, :] + lam * spectrum.mu[:, None] + rho
    spectral = spectrum.transform(c)
    z = np.clip(fit.solve._smooth.unbounded(spectrum, spectral, lam), lo, hi)
    u = np.zeros_like(z)
    relax = fit.solve._smooth._ADMM_RELAXATION
    for _ in range(25):
        w = relax * spectrum.inverse((spectral + spectrum.transform(rho * (z - u))) / denom) \
            + (1 - relax) * z
        z = np.clip(w + u, lo, hi)
        u += w - z
    differ = ((z <= lo) != at_lo) | ((z >= hi) != at_hi)
    assert differ.mean() < 0.002
    np.testing.assert_allclose(start, z, rtol=0, atol=1e-5)


def _counted_factorizations(monkeypatch) -> list:
    """A list that gets one item per factorization of the whole sequence from now on."""
    factors = []
    real = fit.solve._smooth.cholesky_banded_upper

    def counted(*args, **kwargs):
        factors.append(1)
        return real(*args, **kwargs)
    monkeypatch.setattr(fit.solve._smooth, "cholesky_banded_upper", counted)
    return factors


def test_a_step_in_the_same_state_reuses_the_factor(monkeypatch):
    """Data moved by far less than any weight's distance to its bound keep the optimal
    active set: one factorization serves every step, two triangular solves each."""
    rng = np.random.default_rng(8)
    T, n, K = 120, 5, 12
    basis, data = _smooth_problem(rng, T, n, K, collinear=True)
    answer = solve_weights(basis, data, lower=0, upper=1, smoothness=2.0).weights
    factors = _counted_factorizations(monkeypatch)
    moves = _Moves([data + 1e-12 * j for j in range(5)])
    sol = solve_weights(basis, data, lower=0, upper=1, smoothness=2.0, start=answer,
                        follow=moves)
    assert sol.status == 0
    assert [optimal for _, optimal in moves.calls] == [True] * 5
    assert len(factors) == 1 and np.all(sol.n_iter == 5)


def test_follow_is_refused_without_smoothness_or_with_the_wrong_size():
    basis, data = np.eye(3), np.zeros((4, 3))
    with pytest.raises(InputError, match="follow needs smoothness"):
        solve_weights(basis, data, follow=lambda w, optimal: None)
    with pytest.raises(InputError,
                       match=r"follow must return data of shape \(4, 3\).*got shape \(4, 2\)"):
        solve_weights(basis, data, lower=0, upper=1, smoothness=1.0,
                      follow=lambda w, optimal: np.zeros((4, 2)))


@pytest.mark.parametrize("compiled", [True, False], ids=["compiled", "numpy"])
@pytest.mark.parametrize("n, T, share", [(1, 6, 0.7), (4, 1, 0.7), (5, 300, 0.7), (300, 3, 0.9),
                                          (6, 40, 1.0), (3, 5, 0.0)])
def test_band_matrix_is_the_free_weights_reduced_hessian(n, T, share, compiled,
                                                               monkeypatch):
    """The free weights' band holds the dense oracle's rows and columns of the free
    weights (frame by frame, in order) in LAPACK's upper form with the fewest bands that
    hold every nonzero, Fortran-ordered, in the given buffer's first floats; numba's loop
    writes the same bits as NumPy, the zeros' signs too. Every weight free: the full
    band; none: an empty one."""
    if not compiled:
        monkeypatch.setattr(fit.solve._smooth, "_compiled_band", lambda: None)
    else:
        assert fit.solve._smooth._compiled_band() is not None, \
            "numba (the speed extra, in .[test]) is missing"
    rng = np.random.default_rng(n * T + 7)
    a = rng.standard_normal((2 * n, n))
    G, lam, ridge = a.T @ a, 0.7, 0.01
    free = rng.random((T, n)) < share
    link = rng.random(max(T - 1, 0)) > 0.1
    deg = (np.r_[0, link] + np.r_[link, 0] if T > 1 else np.zeros(1)).astype(float)
    band = fit.solve._smooth._Band(G, lam, ridge)
    buffer = np.full((n + 1) * T * n + 3, np.nan)
    got = band.matrix(free, deg, link, out=buffer)
    lap = np.diag(deg) - np.diag(link.astype(float), 1) - np.diag(link.astype(float), -1)
    dense = np.kron(np.eye(T), G) + lam * np.kron(lap, np.eye(n)) + ridge * np.eye(T * n)
    keep = np.flatnonzero(free.ravel())
    dense = dense[np.ix_(keep, keep)]
    rows, cols = np.nonzero(np.triu(dense))
    kd = int((cols - rows).max(initial=0))
    assert got.shape == (kd + 1, len(keep)) and got.flags.f_contiguous
    assert len(keep) == 0 or np.shares_memory(got, buffer)
    expected = np.zeros((kd + 1, len(keep)))
    for i, j in zip(*np.triu_indices(len(keep))):
        if j - i <= kd:
            expected[kd + i - j, j] = dense[i, j]
    np.testing.assert_allclose(got, expected, rtol=0, atol=EXACT_FLOAT64 * np.abs(G).max())
    monkeypatch.setattr(fit.solve._smooth, "_compiled_band", lambda: None)
    assert band.matrix(free, deg, link).tobytes() == got.tobytes()
    with pytest.raises(ValueError, match="flat float64 array of at least"):
        band.matrix(free, deg, link, out=np.empty(got.size - 1)) if got.size else \
            band.matrix(free, deg, link, out=np.empty((1, 1)))


def _dense_reduced_hessian(band, state):
    """The whole sequence's reduced Hessian of ``state`` (T, n), dense: the oracle."""
    T, n = state.shape
    lap = np.diag(fit.solve._smooth.degree(T)) - np.eye(T, k=1) - np.eye(T, k=-1)
    dense = np.kron(np.eye(T), band.G) + band.lam * np.kron(lap, np.eye(n)) \
        + band.ridge * np.eye(T * n)
    keep = (state == 0).ravel()
    dense = np.where(np.outer(keep, keep), dense, 0.0)
    dense[~keep, ~keep] = band.fill
    return dense


@pytest.mark.parametrize("ridge", [0.0, 0.01])
def test_whole_sequence_solves_nearby_states_through_one_factor(ridge, monkeypatch):
    """States a few variables from the factored one (bound, freed, both, at the take's
    ends, a bound weight moving to its other bound) are solved through its factor, as
    the dense reduced system solves them; more changes, or a residual above the limit,
    factor the whole sequence anew, with the same answers."""
    rng = np.random.default_rng(12)
    T, n = 40, 5
    a = rng.standard_normal((2 * n, n))
    band = fit.solve._smooth._Band(a.T @ a, 0.7, ridge)
    whole = fit.solve._smooth._WholeFactor(band, T)
    factors = _counted_factorizations(monkeypatch)

    def check(state):
        rhs = np.where(state == 0, rng.standard_normal(state.shape), 0.0).ravel()
        expected = np.linalg.solve(_dense_reduced_hessian(band, state), rhs)
        np.testing.assert_allclose(whole.solve(state, rhs), expected, rtol=0,
                                   atol=SOLVE_SAME_MINIMIZER * np.abs(expected).max())

    state = rng.choice(np.array([-1, 0, 0, 0, 1], np.int8), size=(T, n))
    check(state)
    free_at = np.argwhere(state == 0)
    bound_at = np.argwhere(state != 0)
    changes = [
        [(tuple(free_at[0]), -1)],                                    # one bound
        [(tuple(bound_at[1]), 0), (tuple(bound_at[2]), 0)],           # two freed
        [((0, 0), 1 - abs(int(state[0, 0]))), ((T - 1, n - 1), 0),    # the take's ends,
         (tuple(free_at[5]), 1), (tuple(bound_at[6]), 0)],            # bound and freed
        [(tuple(bound_at[7]), -int(state[tuple(bound_at[7])]))],      # other bound
    ]
    for step in changes:
        for at, value in step:
            state[at] = value
        check(state)
    assert len(factors) == 1
    limit = fit.solve._smooth._LOW_RANK_MAX
    far = state.copy()
    far.ravel()[rng.choice(T * n, limit + 1, replace=False)] ^= 1   # 0 <-> 1, -1 <-> -2
    far[far == -2] = 0
    check(far)
    assert len(factors) == 2
    monkeypatch.setattr(fit.solve._smooth, "_LOW_RANK_RESIDUAL", 0.0)
    far[tuple(np.argwhere(far == 0)[0])] = 1
    check(far)
    assert len(factors) == 3


def test_a_reserved_buffer_holds_the_first_factor():
    """``reserve`` allocates the factors' buffer on a thread: the first solve factors the
    free weights' matrix into that very buffer (no second one) and solves as the dense
    reduced system does; a solve right after ``reserve`` waits for it."""
    rng = np.random.default_rng(15)
    T, n = 25, 4
    a = rng.standard_normal((2 * n, n))
    band = fit.solve._smooth._Band(a.T @ a, 0.6, 0.0)
    state = rng.choice(np.array([-1, 0, 0, 1], np.int8), size=(T, n))
    rhs = np.where(state == 0, rng.standard_normal(state.shape), 0.0).ravel()
    whole = fit.solve._smooth._WholeFactor(band, T)
    whole.reserve()
    x = whole.solve(state, rhs)
    kd = whole.band.bandwidth(state == 0, np.ones(T - 1, bool))
    assert whole.factor.shape == (kd + 1, np.count_nonzero(state == 0))
    assert whole.factor.flags.f_contiguous and np.shares_memory(whole.factor, whole.buffer)
    again = fit.solve._smooth._WholeFactor(band, T)
    again.reserve()
    again.wait()
    reserved = again.buffer
    assert reserved.size == (n + 1) * T * n
    np.testing.assert_array_equal(again.solve(state, rhs), x)
    assert again.buffer is reserved and np.shares_memory(again.factor, reserved)
    expected = np.linalg.solve(_dense_reduced_hessian(band, state), rhs)
    np.testing.assert_allclose(x, expected, rtol=0,
                               atol=SOLVE_SAME_MINIMIZER * np.abs(expected).max())
    again.solve(np.where(state == 0, 1, 0).astype(np.int8), np.zeros(T * n))  # refactored
    assert again.buffer is reserved and np.shares_memory(again.factor, reserved)


def test_a_prepared_factor_solves_as_one_made_at_the_solve(monkeypatch):
    """``prepare`` factors a state far from the kept factor on a thread of its own: the
    solve then uses that factor (no second factorization) and gives the same bits; a
    state near the kept factor is not factored (its solve borders the factor): the
    columns that border it are made ahead, and its solve makes no other and gives the
    bits of a solve that made them itself; an error of the background factorization is
    raised by the solve."""
    rng = np.random.default_rng(14)
    T, n = 30, 4
    a = rng.standard_normal((2 * n, n))
    band = fit.solve._smooth._Band(a.T @ a, 0.4, 0.0)
    first = rng.choice(np.array([-1, 0, 0, 1], np.int8), size=(T, n))
    far = rng.choice(np.array([-1, 0, 0, 1], np.int8), size=(T, n))
    rhs = np.where(far == 0, rng.standard_normal(far.shape), 0.0).ravel()
    expected = fit.solve._smooth._WholeFactor(band, T).solve(far, rhs)
    near = far.copy()
    near[tuple(np.argwhere(far == 0)[0])] = 1
    near[tuple(np.argwhere(far != 0)[0])] = 0
    near_rhs = np.where(near == 0, rng.standard_normal(near.shape), 0.0).ravel()
    alone = fit.solve._smooth._WholeFactor(band, T)
    alone.solve(far, rhs)
    near_expected = alone.solve(near, near_rhs)             # bordered, its columns its own
    whole = fit.solve._smooth._WholeFactor(band, T)
    whole.solve(first, np.zeros(T * n))
    factors = _counted_factorizations(monkeypatch)
    whole.prepare(far)
    whole.wait()
    assert len(factors) == 1
    np.testing.assert_array_equal(whole.solve(far, rhs), expected)
    assert len(factors) == 1
    whole.prepare(near)
    whole.wait()
    assert len(factors) == 1 and sorted(whole.columns) == sorted(
        np.flatnonzero((near != 0).ravel() != (far != 0).ravel()).tolist())
    made = []
    monkeypatch.setattr(whole, "_column", lambda j: made.append(j) or whole.columns[int(j)])
    np.testing.assert_array_equal(whole.solve(near, near_rhs), near_expected)
    assert len(factors) == 1 and made and set(made) <= set(whole.columns)
    monkeypatch.undo()

    def broken(ab):
        raise np.linalg.LinAlgError("3-th leading minor not positive definite")
    monkeypatch.setattr(fit.solve._smooth, "cholesky_banded_upper", broken)
    whole.prepare(first)
    with pytest.raises(np.linalg.LinAlgError, match="3-th leading minor"):
        whole.solve(first, np.zeros(T * n))


def test_banded_cholesky_without_the_gil_is_scipys_factor():
    """The GIL-free factorization and solve are LAPACK's dpbtrf and dpbtrs, as SciPy's
    `cholesky_banded` and `cho_solve_banded` call them: the same factor and solution bit
    for bit (the right-hand side left as it was), the same refusal of a matrix that is not
    positive definite, and a clear error for storage LAPACK cannot factor in place."""
    from fit.solve._banded_cholesky import cho_solve_banded_upper, cholesky_banded_upper
    rng = np.random.default_rng(15)
    N, kd = 300, 7
    dense = rng.standard_normal((N, N)) * np.triu(np.tril(np.ones((N, N)), kd), -kd)
    dense = dense @ dense.T + 0.1 * np.eye(N)            # SPD, bandwidth 2 kd
    kd = 2 * kd
    ab = np.zeros((kd + 1, N), order="F")
    for i, j in zip(*np.triu_indices(N)):
        if j - i <= kd:
            ab[kd + i - j, j] = dense[i, j]
    expected = scipy.linalg.cholesky_banded(ab, check_finite=False)
    got = ab.copy(order="F")
    assert cholesky_banded_upper(got) is got
    np.testing.assert_array_equal(got, expected)
    b = rng.standard_normal(N)
    kept = b.copy()
    x = cho_solve_banded_upper(got, b)
    assert x.tobytes() == scipy.linalg.cho_solve_banded((expected, False), b).tobytes()
    np.testing.assert_array_equal(b, kept)
    np.testing.assert_allclose(dense @ x, b, rtol=0, atol=1e-9 * np.abs(b).max())
    indefinite = ab.copy(order="F")
    indefinite[kd, 10] = -1.0                          # A[10, 10]: the 11th minor fails
    for factor in (cholesky_banded_upper, scipy.linalg.cholesky_banded):
        with pytest.raises(np.linalg.LinAlgError, match="^11-th leading minor not positive"):
            factor(indefinite.copy(order="F"))
    with pytest.raises(ValueError, match="Fortran-ordered float64"):
        cholesky_banded_upper(np.ascontiguousarray(ab))


def test_banded_cholesky_of_another_signature_is_scipys(monkeypatch):
    """A SciPy exporting dpbtrf or dpbtrs with another C signature is not called through
    it: SciPy's own `cholesky_banded` factors and `cho_solve_banded` solves, with the same
    results."""
    import fit.solve._banded_cholesky as banded
    rng = np.random.default_rng(16)
    ab = np.asfortranarray(0.01 * rng.standard_normal((4, 50)))
    ab[-1] = 2.0
    expected = banded.cholesky_banded_upper(ab.copy(order="F"))
    assert banded._dpbtrf() is not None
    assert banded._SIGNATURE.fullmatch(
        b"void (char *, int *, int *, __pyx_t_5scipy_6linalg_13cython_lapack_d *, int *, int *)")
    assert not banded._SIGNATURE.fullmatch(
        b"void (char *, int64_t *, int64_t *, double *, int64_t *, int64_t *)")
    monkeypatch.setattr(banded, "_dpbtrf", lambda: None)
    np.testing.assert_array_equal(banded.cholesky_banded_upper(ab.copy(order="F")), expected)
    b = rng.standard_normal(50)
    solved = banded.cho_solve_banded_upper(expected, b)
    assert banded._dpbtrs() is not None
    assert banded._SOLVE_SIGNATURE.fullmatch(
        b"void (char *, int *, int *, int *, __pyx_t_5scipy_6linalg_13cython_lapack_d *, "
        b"int *, __pyx_t_5scipy_6linalg_13cython_lapack_d *, int *, int *)")
    monkeypatch.setattr(banded, "_dpbtrs", lambda: None)
    np.testing.assert_array_equal(banded.cho_solve_banded_upper(expected, b), solved)


def test_smoothness_reduces_frame_to_frame_change():
    rng = np.random.default_rng(11)
    basis = rng.standard_normal((15, 4))
    data = rng.uniform(0, 1, (40, 4)) @ basis.T + 0.5 * rng.standard_normal((40, 15))
    rough = solve_weights(basis, data, lower=0, upper=1)
    smooth = solve_weights(basis, data, lower=0, upper=1, smoothness=5.0)
    assert np.abs(np.diff(smooth.weights, axis=0)).sum() < np.abs(
        np.diff(rough.weights, axis=0)).sum()


@pytest.mark.parametrize("eps", [0.0, 0.2])
def test_sampling_estimator_is_feasible_and_never_beats_exact(eps):
    rng = np.random.default_rng(12)
    basis = rng.standard_normal((24, 6))
    data = rng.uniform(-eps, 1 + eps, (30, 6)) @ basis.T + 0.1 * rng.standard_normal((30, 24))
    est = estimate_weights_by_sampling(basis, data, lower=-eps, upper=1 + eps, seed=1)
    exact = solve_weights(basis, data, lower=-eps, upper=1 + eps)
    assert np.all((est.weights >= -eps) & (est.weights <= 1 + eps))
    assert np.all(est.cost >= exact.cost * (1 - EXACT_FLOAT64))
    again = estimate_weights_by_sampling(basis, data, lower=-eps, upper=1 + eps, seed=1)
    np.testing.assert_array_equal(again.weights, est.weights)


def test_sampling_estimator_matches_brute_force_neighbours():
    rng = np.random.default_rng(13)
    basis = rng.standard_normal((9, 3))
    data = rng.uniform(0, 1, (7, 3)) @ basis.T
    est = estimate_weights_by_sampling(basis, data, n_samples=50, n_neighbors=5, seed=2)
    samples = np.random.default_rng(2).random((50, 3))
    dist = np.linalg.norm(data[:, None, :] - (samples @ basis.T)[None], axis=2)
    near = np.argsort(dist, axis=1)[:, :5]
    inv = 1.0 / np.take_along_axis(dist, near, axis=1)
    expected = np.einsum("tk,tkn->tn", inv / inv.sum(1, keepdims=True), samples[near])
    np.testing.assert_allclose(est.weights, expected, rtol=EXACT_FLOAT64)
    np.testing.assert_allclose(est.distance, dist.min(axis=1), rtol=EXACT_FLOAT64)


@pytest.mark.parametrize("kwargs, message", [
    ({"upper": np.inf}, "needs finite lower and upper bounds"),
    ({"n_samples": 10, "n_neighbors": 11}, r"n_neighbors \(11\) must not exceed"),
])
def test_sampling_estimator_bad_input(kwargs, message):
    with pytest.raises(InputError, match=message):
        estimate_weights_by_sampling(np.eye(3), np.zeros((2, 3)), **kwargs)
