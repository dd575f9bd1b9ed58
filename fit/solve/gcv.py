"""Choosing the temporal smoothness λ without ground truth: generalized cross-validation.

``solve_weights(..., smoothness="gcv")`` picks λ by minimizing the GCV score of
the *unbounded* smooth problem (closed form in the spectral basis of
:class:`fit.solve._smooth.Spectrum`), then solves the bounded problem at that λ.

References
----------
Craven & Wahba, "Smoothing noisy data with spline functions", Numer. Math. 31
(1979); Golub, Heath & Wahba, "Generalized cross-validation as a method for
choosing a good ridge parameter", Technometrics 21 (1979).
"""

from __future__ import annotations

import functools

import numpy as np

from fit.solve._active_set import RANK_RTOL
from fit.solve._smooth import Spectrum
from mocap.util.optional import compiled, compiled_if_worth

__all__ = ["SMOOTHNESS_RULES", "gcv_score", "gcv_smoothness"]

#: Rules that choose λ from the data, accepted as ``smoothness`` by
#: :func:`fit.solve.weights.solve_weights` and ``[fit] smoothness`` of ``run``.
SMOOTHNESS_RULES = ("gcv",)

#: Grid points of log λ searched before the bounded Brent refinement.
_GRID = 61
#: The search spans λ from _SPAN_LOW · Λ_min / 4 (no smoothing at any frequency)
#: to _SPAN_HIGH · Λ_max / μ_1 (every weight curve all but constant), Λ the
#: eigenvalues of G and μ_1 the lowest nonzero frequency of the take.
_SPAN_LOW, _SPAN_HIGH = 1e-3, 1e3
#: Frequencies × directions of a problem for which loading numba (about half a second,
#: once a process) pays for itself in its scores (about 2 ns saved each, 80 scores a
#: choice of λ); in a process that has loaded it, the compiled sums serve any problem.
_TERMS_WORTH_COMPILING = 3_000_000


class _Score:
    """GCV(λ) of one problem, from its spectral coefficients (built once)."""

    def __init__(self, basis, data):
        G = basis.T @ basis
        C = data @ basis
        spectrum = Spectrum.build(G, len(data))
        eig = spectrum.eig
        keep = eig > RANK_RTOL * max(eig[-1], np.finfo(float).tiny)
        self.eig, self.mu = eig[keep], spectrum.mu
        # (Qᵀ C V)² / Λ per coefficient, (T, r): the data's power in each kept direction
        self.power = spectrum.transform(C)[:, keep] ** 2 / self.eig
        # out-of-span residual Σ_t ‖d_t − B B⁺ d_t‖², independent of λ (the
        # data's part no weights can fit), from the frames' least-squares fit
        fitted = (C @ np.linalg.pinv(G, rcond=RANK_RTOL, hermitian=True)) @ basis.T
        self.base = float(np.sum((data - fitted) ** 2))
        self.n_obs = data.size
        self.sums = compiled_if_worth(_compiled_sums, self.power.size,
                                      _TERMS_WORTH_COMPILING) or _sums

    def __call__(self, lam: float) -> float:
        trace, weighted = self.sums(lam * self.mu, self.eig, self.power)
        return self.n_obs * (self.base + weighted) / (self.n_obs - trace) ** 2

    def span(self) -> tuple[float, float]:
        eig, mu = self.eig, self.mu
        lowest = mu[1] if len(mu) > 1 else 1.0
        return _SPAN_LOW * eig[0] / 4.0, _SPAN_HIGH * eig[-1] / lowest


def _sums(a, eig, power) -> tuple[float, float]:
    """tr A(λ) and the RSS less its part outside the span, from ``a`` = λ μ (T,), Λ (r,)
    and the power (T, r): :func:`fit.solve._gcv_kernel.gcv_sums` by NumPy."""
    # with q_kj = 1 / (Λ_j + a_k): 1 − influence = a_k q_kj, so
    # RSS = base + Σ_k a_k² Σ_j power_kj q_kj² and tr A = Σ_j Λ_j Σ_k q_kj
    q = np.add.outer(a, eig)
    np.reciprocal(q, out=q)
    trace = float(eig @ q.sum(axis=0))
    np.square(q, out=q)
    return trace, float(np.square(a) @ np.einsum("kj,kj->k", power, q))


@functools.cache
def _compiled_sums():
    """:func:`fit.solve._gcv_kernel.gcv_sums`, or None (NumPy sums the scores' terms):
    :func:`mocap.util.optional.compiled`."""
    return compiled("fit.solve._gcv_kernel", "gcv_sums", what="GCV score",
                    fallback="NumPy sums its terms, about a third as fast")


def gcv_score(basis, data, smoothness) -> np.ndarray:
    """GCV score of the unbounded smooth problem at each λ in `smoothness`.

    Parameters
    ----------
    basis : ndarray, shape (K, n)
        B, in data units (mm for markers).
    data : ndarray, shape (T, K)
        Displacements d_t; no NaN.
    smoothness : float or array_like of float
        λ ≥ 0.

    Returns
    -------
    ndarray, shape of `smoothness`
        ``N · RSS(λ) / (N − tr A(λ))²``, N = T · K observations, A(λ) the
        influence matrix taking the data to the fitted B w_t of the unbounded
        minimizer of Σ_t ½‖B w_t − d_t‖² + ½ λ Σ_t ‖w_t − w_{t−1}‖²
        (data units², inf where tr A = N).

    Notes
    -----
    With G = BᵀB = V Λ Vᵀ and the DCT-II Q of the path Laplacian (eigenvalues
    μ_k), the coefficient s_kj of Qᵀ C V (C rows c_t = Bᵀd_t) is shrunk by
    Λ_j / (Λ_j + λ μ_k): tr A = Σ_kj Λ_j / (Λ_j + λ μ_k) and
    RSS = R₀ + Σ_kj (s_kj² / Λ_j) (λ μ_k / (Λ_j + λ μ_k))², R₀ the residual
    of the frames' own least-squares fits (outside the span of B). Directions
    with Λ_j = 0 carry no data and are left out. O(T n) per λ.
    """
    score = _Score(np.asarray(basis, float), np.asarray(data, float))
    lam = np.asarray(smoothness, dtype=float)
    with np.errstate(divide="ignore"):
        return np.vectorize(score, otypes=[float])(lam)


def gcv_smoothness(basis, data) -> float:
    """The λ minimizing :func:`gcv_score` (a grid over log λ, then bounded Brent).

    Parameters
    ----------
    basis : ndarray, shape (K, n)
    data : ndarray, shape (T, K)
        As in :func:`gcv_score`.

    Returns
    -------
    float
        λ > 0. The search spans λ from "smooths no frequency" to "all weights
        nearly constant" (see ``_SPAN_LOW``, ``_SPAN_HIGH``); a λ at the low
        end says the data asks for no smoothing.

    Notes
    -----
    ``_GRID`` log-spaced λ are scored (GCV can have several local minima),
    then :func:`scipy.optimize.minimize_scalar` (method "bounded") refines
    log λ between the best grid point's neighbours.
    """
    import scipy.optimize  # here: a run without "gcv" does not pay for its import (0.1 s)

    score = _Score(np.asarray(basis, float), np.asarray(data, float))
    low, high = np.log(score.span())
    grid = np.linspace(low, high, _GRID)
    with np.errstate(divide="ignore"):
        values = [score(np.exp(x)) for x in grid]
        best = int(np.argmin(values))
        lo, hi = grid[max(best - 1, 0)], grid[min(best + 1, _GRID - 1)]
        found = scipy.optimize.minimize_scalar(lambda x: score(np.exp(x)), bounds=(lo, hi),
                                               method="bounded",
                                               options={"xatol": 1e-6})
    x = found.x if found.fun <= values[best] else grid[best]
    return float(np.exp(x))
