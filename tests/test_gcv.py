"""Choosing the smoothness λ by GCV, against dense oracles and the truth."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize
from tolerances import (
    GCV_ARGMIN_RTOL,
    GCV_ERROR_FACTOR,
    GCV_SCORE_RTOL,
    GCV_VS_TRUTH_LOG10,
    GCV_VS_UNSMOOTHED,
)

import fit.solve.gcv
from fit.solve.gcv import gcv_score, gcv_smoothness
from fit.solve.weights import solve_weights


@pytest.fixture(params=["numpy", "compiled"])
def score_sums(request, monkeypatch):
    """The scores' terms summed by NumPy, or by the compiled loop (whatever the size)."""
    if request.param == "numpy":
        monkeypatch.setattr(fit.solve.gcv, "compiled_if_worth", lambda loader, work, worth: None)
    else:                           # (the tests install the speed extra: numba)
        assert fit.solve.gcv._compiled_sums() is not None
        monkeypatch.setattr(fit.solve.gcv, "compiled_if_worth",
                            lambda loader, work, worth: loader())
    return request.param


def dense_gcv(basis, data, lam):
    """N ‖(I − A) y‖² / (N − tr A)², A = X (XᵀX + λ DᵀD)⁺ Xᵀ, X = I_T ⊗ B, D differences."""
    T, n = len(data), basis.shape[1]
    X = np.kron(np.eye(T), basis)
    diff = np.kron(np.diff(np.eye(T), axis=0), np.eye(n))
    influence = X @ np.linalg.pinv(X.T @ X + lam * diff.T @ diff, hermitian=True) @ X.T
    y = data.ravel()
    resid = y - influence @ y
    return y.size * resid @ resid / (y.size - np.trace(influence)) ** 2


def smooth_truth(rng, T, n, lo=0.0, hi=1.0):
    """Smooth weight curves (sums of a few slow sinusoids) within [lo, hi]."""
    t = np.arange(T)[:, None]
    w = sum(np.sin(2 * np.pi * t / rng.uniform(30, 200, n) + rng.uniform(0, 6.3, n))
            for _ in range(3))
    w = (w - w.min(0)) / np.ptp(w, 0)
    return lo + (hi - lo) * w


@pytest.mark.parametrize("rank", [None, 2])
def test_score_matches_dense_influence_matrix(rank, score_sums):
    rng = np.random.default_rng(3 if rank is None else 4)
    T, n, K = 7, 3, 6
    basis = rng.standard_normal((K, n))
    if rank is not None:
        basis = basis[:, :rank] @ rng.standard_normal((rank, n))
    data = smooth_truth(rng, T, n) @ basis.T + 0.3 * rng.standard_normal((T, K))
    lams = np.array([1e-3, 0.1, 1.0, 7.0, 100.0])
    np.testing.assert_allclose(gcv_score(basis, data, lams),
                               [dense_gcv(basis, data, lam) for lam in lams],
                               rtol=GCV_SCORE_RTOL)


def test_chosen_smoothness_minimizes_dense_gcv(score_sums):
    rng = np.random.default_rng(5)
    T, n, K = 12, 3, 5
    basis = rng.standard_normal((K, n))
    data = smooth_truth(rng, T, n) @ basis.T + 0.5 * rng.standard_normal((T, K))
    grid = np.linspace(-6, 6, 121)
    dense = [dense_gcv(basis, data, np.exp(x)) for x in grid]
    best = int(np.argmin(dense))
    ref = scipy.optimize.minimize_scalar(lambda x: dense_gcv(basis, data, np.exp(x)),
                                         bounds=(grid[best - 1], grid[best + 1]),
                                         method="bounded", options={"xatol": 1e-6})
    assert 0 < best < len(grid) - 1           # an interior minimum, so the test means something
    np.testing.assert_allclose(gcv_smoothness(basis, data), np.exp(ref.x),
                               rtol=GCV_ARGMIN_RTOL)


def test_compiled_sums_are_numpys_to_rounding():
    """The compiled loop's two sums are NumPy's to rounding, from no smoothing to a λ that
    flattens every direction, for one direction or many."""
    from fit.solve._gcv_kernel import gcv_sums

    rng = np.random.default_rng(8)
    for T, r in [(1, 1), (50, 1), (3870, 53)]:
        mu = 4.0 * np.sin(np.pi * np.arange(T) / (2 * T)) ** 2
        eig = np.sort(10.0 ** rng.uniform(-6, 2, r))
        power = rng.exponential(size=(T, r))
        for lam in (0.0, 1e-9, 0.8, 1e4):
            np.testing.assert_allclose(gcv_sums(lam * mu, eig, power),
                                       fit.solve.gcv._sums(lam * mu, eig, power),
                                       rtol=1e-12, atol=0)


def test_gcv_without_numbas_cache_is_scored_by_numpy(monkeypatch):
    """Where numba can keep its compiled code nowhere, NumPy sums the scores, with a
    warning saying so, and the same λ is chosen (to the rounding of the sums)."""
    from helpers import numba_cannot_cache

    rng = np.random.default_rng(9)
    basis = rng.standard_normal((6, 3))
    data = smooth_truth(rng, 40, 3) @ basis.T + 0.3 * rng.standard_normal((40, 6))
    monkeypatch.setattr(fit.solve.gcv, "compiled_if_worth", lambda loader, work, worth: loader())
    fit.solve.gcv._compiled_sums.cache_clear()
    expected = gcv_smoothness(basis, data)
    numba_cannot_cache(monkeypatch, "fit.solve._gcv_kernel")
    fit.solve.gcv._compiled_sums.cache_clear()
    try:
        with pytest.warns(UserWarning, match="compiled GCV score is off .*no locator"):
            got = gcv_smoothness(basis, data)
        assert fit.solve.gcv._compiled_sums() is None
    finally:
        monkeypatch.undo()
        fit.solve.gcv._compiled_sums.cache_clear()
    np.testing.assert_allclose(got, expected, rtol=1e-9)


@pytest.mark.parametrize("noise", [0.05, 0.3])
def test_gcv_lands_near_the_truth_optimum(noise):
    """Known smooth weights + white noise: GCV's λ is near the λ of least true
    weight error (a brute-force sweep against the truth, the oracle)."""
    rng = np.random.default_rng(int(100 * noise))
    T, n, K = 600, 5, 15
    basis = rng.standard_normal((K, n))
    truth = smooth_truth(rng, T, n)
    data = truth @ basis.T + noise * rng.standard_normal((T, K))
    sweep = np.logspace(-3, 5, 81)
    error = [np.sqrt(np.mean((solve_weights(basis, data, smoothness=lam).weights - truth) ** 2))
             for lam in sweep]
    best = int(np.argmin(error))
    assert 0 < best < len(sweep) - 1
    chosen = solve_weights(basis, data, smoothness="gcv")
    chosen_error = np.sqrt(np.mean((chosen.weights - truth) ** 2))
    assert abs(np.log10(chosen.smoothness / sweep[best])) < GCV_VS_TRUTH_LOG10  # within a factor 3
    assert chosen_error <= GCV_ERROR_FACTOR * error[best]
    unsmoothed = np.sqrt(np.mean((solve_weights(basis, data).weights - truth) ** 2))
    assert chosen_error < GCV_VS_UNSMOOTHED * unsmoothed


def test_gcv_option_solves_the_bounded_problem_at_the_chosen_smoothness():
    rng = np.random.default_rng(8)
    T, n, K = 200, 4, 12
    basis = rng.standard_normal((K, n))
    data = smooth_truth(rng, T, n, -0.2, 1.2) @ basis.T + 0.2 * rng.standard_normal((T, K))
    chosen = solve_weights(basis, data, lower=0, upper=1, smoothness="gcv")
    lam = gcv_smoothness(basis, data)
    assert chosen.smoothness == lam and chosen.status == 0
    at_lam = solve_weights(basis, data, lower=0, upper=1, smoothness=lam)
    np.testing.assert_array_equal(chosen.weights, at_lam.weights)
    assert at_lam.smoothness == lam and solve_weights(basis, data).smoothness == 0.0
