"""Decomposition of a stabilized take into blend weights, head motion and feature details.

Ju & Lee (2008), sec. 4: F(t) = R(t) N + Σ_i c_i(t) B_i + P(t) + Σ_j D_j(t) + T(t).
R and T come from head stabilization; c_i from the moving average of the
stabilized markers (window 2k + 1 = 41), bounded to −ε ≤ c_i ≤ 1 + ε; P (lips)
and D_j (left/right brow, left/right eye) are the residual of the blend-shape
fit on their non-overlapping marker groups, the rest is the error term ε(t).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from fit.solve.sampling_estimator import estimate_weights_by_sampling
from fit.solve.temporal import moving_average
from fit.solve.weights import solve_weights
from mocap.errors import InputError, MarkerError
from mocap.markerset import MarkerSet
from mocap.stabilize import Stabilization
from mocap.util.arrays import read_only
from mocap.util.validation import as_choice, as_float_array, as_int

__all__ = ["GestureAnalysis", "analyze_gestures", "DETAIL_GROUPS",
           "LIP_REGIONS", "ESTIMATORS"]

#: Marker-set regions whose residuals are the independent features D_j.
DETAIL_GROUPS = ("left_brow", "right_brow", "left_eye", "right_eye")
#: Marker-set regions whose residual is the lip movement P.
LIP_REGIONS = ("upper_lip", "lower_lip")
#: How the blend weights are found: exact bounded least squares
#: (:func:`fit.solve.weights.solve_weights`) or the paper's sampling estimator
#: (:func:`fit.solve.sampling_estimator.estimate_weights_by_sampling`).
ESTIMATORS = ("exact", "sampling")


@dataclass(frozen=True, eq=False)
class GestureAnalysis:
    """A take decomposed into head motion, blend weights and per-group residuals.

    Attributes
    ----------
    weights : ndarray of shape (n_frames, n_shapes)
        c_i(t), within ``[−ε, 1 + ε]``; NaN in frames whose averaged markers are all missing.
    rotation : ndarray of shape (n_frames, 3, 3)
        R(t) from the stabilization (``world = R head + T``).
    translation : ndarray of shape (n_frames, 3), mm
        T(t).
    lips : ndarray of shape (n_frames, n_lip_markers, 3), mm
        P(t): residual of the lip markers (:data:`LIP_REGIONS`), head frame.
    details : dict of str to ndarray of shape (n_frames, n_group_markers, 3), mm
        D_j(t) for each group of :data:`DETAIL_GROUPS` with markers.
    rest : ndarray of shape (n_frames, n_rest_markers, 3), mm
        ε(t): residual of the markers in no group.
    groups : dict of str to tuple of str
        Marker labels of ``"lips"``, each detail group and ``"rest"``.
    labels : tuple of str
        The M markers of `neutral` and `basis`, in their order.
    neutral : ndarray of shape (M, 3), mm
        N, head frame.
    basis : ndarray of shape (n_shapes, M, 3), mm
        B_i, displacements from N.
    names : tuple of str
        Shape names.
    rate : float, Hz
    cost : ndarray of shape (n_frames,), mm²
        ½‖Σ c_i B_i − (F̄ − N)‖² of the weight fit, on the averaged markers.
    estimator : str
    message : str

    Notes
    -----
    NaN policy: a missing stabilized marker gives NaN residuals at that
    marker and frame; the weights use the average over the window's visible
    samples of each marker.
    """

    weights: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    lips: np.ndarray
    details: Mapping[str, np.ndarray]
    rest: np.ndarray
    groups: Mapping[str, tuple]
    labels: tuple
    neutral: np.ndarray
    basis: np.ndarray
    names: tuple
    rate: float
    cost: np.ndarray
    estimator: str
    message: str

    @property
    def n_frames(self) -> int:
        """Number of frames T."""
        return len(self.weights)

    def blend(self) -> np.ndarray:
        """Σ_i c_i(t) B_i of every frame, shape (n_frames, M, 3), mm."""
        flat = self.basis.reshape(len(self.names), -1)
        return (self.weights @ flat).reshape(self.n_frames, *self.neutral.shape)

    def residual(self) -> np.ndarray:
        """P + Σ_j D_j + ε scattered back to the M markers, shape (n_frames, M, 3), mm."""
        out = np.empty((self.n_frames,) + self.neutral.shape)
        parts = {"lips": self.lips, "rest": self.rest, **self.details}
        for group, labels in self.groups.items():
            out[:, [self.labels.index(label) for label in labels]] = parts[group]
        return out


def _groups(regions, labels: tuple) -> dict:
    """Labels of lips, each detail group and the rest, checked against `labels`."""
    if isinstance(regions, MarkerSet):
        regions = regions.regions
    if not isinstance(regions, Mapping):
        raise InputError(f"regions must be a MarkerSet or a mapping of region to labels, "
                         f"got {type(regions).__name__}")
    known = set(labels)
    groups = {"lips": tuple(x for r in LIP_REGIONS for x in regions.get(r, ()))}
    groups.update({g: tuple(regions.get(g, ())) for g in DETAIL_GROUPS if regions.get(g)})
    seen = {}
    for group, members in groups.items():
        for label in members:
            if label not in known:
                raise MarkerError(label, f"is in region group {group!r} but not among the "
                                         "markers of the basis")
            if label in seen:
                raise MarkerError(label, f"is in both {seen[label]!r} and {group!r}: the "
                                         "gesture groups must not overlap")
            seen[label] = group
    groups["rest"] = tuple(label for label in labels if label not in seen)
    return groups


def analyze_gestures(stabilization: Stabilization, neutral, basis, regions, *, labels=None,
                     names=None, epsilon: float = 0.1, window: int = 41,
                     estimator: str = "exact", n_samples: int = 1000, n_neighbors: int = 60,
                     seed=0) -> GestureAnalysis:
    """Decompose a stabilized take into c(t), R(t), T(t), P(t) and D_j(t).

    Parameters
    ----------
    stabilization : Stabilization
        From :func:`mocap.stabilize.stabilize`; its ``take`` is in the head frame.
    neutral : array_like of shape (M, 3), mm
        N: the M markers of the neutral expression in the head frame. No NaN.
    basis : array_like of shape (n_shapes, M, 3), mm
        B_i: displacements of the markers from N (e.g. shapes sampled at the
        bound marker points, brought to capture mm). No NaN.
    regions : MarkerSet or mapping of str to sequence of str
        Facial regions; :data:`LIP_REGIONS` form P, :data:`DETAIL_GROUPS` the D_j.
    labels : sequence of str, optional
        Labels of the M markers (default: the markers of `regions` in order).
    names : sequence of str, optional
        Shape names (default ``shape0``, ...).
    epsilon : float, default 0.1
        Bounds −ε ≤ c_i ≤ 1 + ε (paper: 0 ≤ ε ≤ 1).
    window : int, default 41
        Odd number of frames of the moving average (paper: 41 at 30 Hz).
    estimator : {"exact", "sampling"}
        See :data:`ESTIMATORS`. ``"sampling"`` needs no missing averaged marker.
    n_samples, n_neighbors, seed :
        Of the sampling estimator (paper: 1000 and 60).

    Returns
    -------
    GestureAnalysis

    Raises
    ------
    InputError
        Shapes inconsistent, bad options, missing averaged markers with ``"sampling"``.
    MarkerError
        A marker of `labels` not in the take, a group marker not in `labels`,
        a marker in two groups.

    Notes
    -----
    F̄ = moving average of the stabilized markers; c = argmin ‖Σ c_i B_i − (F̄ − N)‖²
    in the box, every frame at once. The residual ``F − N − Σ c_i B_i`` (F not
    averaged) is split by group: by construction N + Σ c_i B_i + P + Σ D_j + ε = F.

    References
    ----------
    Ju & Lee, "Expressive facial gestures from motion capture data", sec. 4.
    """
    if not isinstance(stabilization, Stabilization):
        raise InputError(f"stabilization must be a Stabilization, got "
                         f"{type(stabilization).__name__}")
    take = stabilization.take
    if labels is None:
        source = regions.regions if isinstance(regions, MarkerSet) else regions
        labels = [x for members in (source or {}).values() for x in members]
    labels = tuple(str(x) for x in labels)
    neutral = as_float_array(neutral, "neutral", shape=(len(labels), 3), allow_nan=False)
    basis = as_float_array(basis, "basis", shape=(None, len(labels), 3), allow_nan=False)
    names = tuple(f"shape{i}" for i in range(len(basis))) if names is None \
        else tuple(str(x) for x in names)
    if len(names) != len(basis):
        raise InputError(f"names must name the {len(basis)} shapes, got {len(names)}")
    epsilon = float(epsilon)
    if not np.isfinite(epsilon) or epsilon < 0:
        raise InputError(f"epsilon must be finite and >= 0, got {epsilon}")
    estimator = as_choice(estimator, "estimator", ESTIMATORS)
    window = as_int(window, "window", minimum=1)
    groups = _groups(regions, labels)

    markers = take.positions[:, take.indices(labels)]
    averaged = moving_average(markers, window=window) - neutral
    weights, cost = _blend_weights(basis, averaged, epsilon, estimator, n_samples,
                                   n_neighbors, seed)
    residual = markers - neutral - np.tensordot(weights, basis, axes=1)
    parts = {g: read_only(residual[:, [labels.index(x) for x in members]])
             for g, members in groups.items()}
    lips, rest = parts.pop("lips"), parts.pop("rest")
    rms = np.sqrt(np.nanmean(residual ** 2)) if np.isfinite(residual).any() else np.nan
    message = (f"{len(weights)} frames, {len(names)} shapes ({estimator}, window {window}, "
               f"epsilon {epsilon:g}); residual RMS {rms:.3g} mm per coordinate")
    return GestureAnalysis(
        weights=read_only(weights, copy=True),
        rotation=read_only(stabilization.rotation, copy=True),
        translation=read_only(stabilization.translation, copy=True), lips=lips,
        details=parts, rest=rest, groups=groups, labels=labels, neutral=read_only(neutral),
        basis=read_only(basis), names=names, rate=take.rate,
        cost=read_only(cost, copy=True), estimator=estimator, message=message)


def _blend_weights(basis, averaged, epsilon, estimator, n_samples, n_neighbors, seed):
    """Weights (T, n) and cost (T,) of the averaged displacements (T, M, 3), NaN-aware."""
    n_frames, n = len(averaged), len(basis)
    seen = ~np.isnan(averaged[..., 0])
    if estimator == "sampling":
        if not seen.all():
            t, m = np.argwhere(~seen)[0]
            raise InputError(f"marker index {m} is missing in the averaged frame {t}: the "
                             "sampling estimator needs every marker (fill gaps first)")
        est = estimate_weights_by_sampling(basis, averaged, lower=-epsilon,
                                           upper=1.0 + epsilon, n_samples=n_samples,
                                           n_neighbors=n_neighbors, seed=seed)
        return est.weights, est.cost
    weights = np.full((n_frames, n), np.nan)
    cost = np.full(n_frames, np.nan)
    some = seen.any(axis=1)
    if some.any():
        mask = None if seen[some].all() else seen[some]
        sol = solve_weights(basis, averaged[some], lower=-epsilon, upper=1.0 + epsilon,
                            mask=mask)
        weights[some], cost[some] = sol.weights, sol.cost
    return weights, cost
