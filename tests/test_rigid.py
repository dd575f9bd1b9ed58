"""Batched weighted rigid / similarity fits against per-frame SVD and scipy oracles."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from tolerances import (
    EXACT_FLOAT64,
    RIGID_DROPPED_MM,
    RIGID_DROPPED_ROT,
    RIGID_EXACT_DEG,
    RIGID_EXACT_MM,
    RIGID_MIRRORED_SCALE,
    RIGID_RMS_MM,
    RIGID_VS_ORACLE,
    RIGID_VS_ORACLE_MM,
    RIGID_VS_ORACLE_SCALE,
)

from mocap import InputError
from mocap.rigid import fit_rigid


def svd_oracle(x, y, w, scale):
    """Per-frame weighted Kabsch / Umeyama by a dense SVD, one frame at a time."""
    cx = w @ x / w.sum()
    cy = w @ y / w.sum()
    cov = ((x - cx) * w[:, None]).T @ (y - cy)
    u, sv, vt = np.linalg.svd(cov)
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))])
    rot = vt.T @ d @ u.T
    s = (sv * np.diag(d)).sum() / (w @ ((x - cx) ** 2).sum(axis=1)) if scale else 1.0
    return rot, cy - s * rot @ cx, s


def random_problem(rng, n_frames=40, n_points=6, shared=False, noise=2.0):
    x = rng.normal(size=(n_points, 3) if shared else (n_frames, n_points, 3)) * 60
    rot = Rotation.random(n_frames, random_state=rng).as_matrix()
    s = rng.uniform(0.5, 2.0, n_frames)
    xs = np.broadcast_to(x, (n_frames, n_points, 3))
    y = s[:, None, None] * np.einsum("tij,tnj->tni", rot, xs) + rng.normal(size=(n_frames, 1, 3)) * 300
    y += rng.normal(size=y.shape) * noise
    w = rng.uniform(0.1, 2.0, (n_frames, n_points))
    return x, y, w


@pytest.mark.parametrize("scale", [False, True])
@pytest.mark.parametrize("shared", [False, True])
def test_batched_fit_matches_per_frame_svd(scale, shared):
    rng = np.random.default_rng(1)
    x, y, w = random_problem(rng, shared=shared)
    fit = fit_rigid(x, y, w, scale=scale)
    for t in range(len(y)):
        rot, trans, s = svd_oracle(x if shared else x[t], y[t], w[t], scale)
        np.testing.assert_allclose(fit.rotation[t], rot, atol=RIGID_VS_ORACLE)
        np.testing.assert_allclose(fit.translation[t], trans, atol=RIGID_VS_ORACLE_MM)
        np.testing.assert_allclose(fit.scale[t], s, rtol=RIGID_VS_ORACLE_SCALE)
    assert fit.valid.all()
    np.testing.assert_allclose(np.linalg.det(fit.rotation), 1.0, atol=EXACT_FLOAT64)


def test_rigid_fit_matches_scipy_align_vectors_weighted():
    rng = np.random.default_rng(2)
    x, y, w = random_problem(rng, n_frames=10, noise=5.0)
    fit = fit_rigid(x, y, w)
    for t in range(10):
        cx = w[t] @ x[t] / w[t].sum()
        cy = w[t] @ y[t] / w[t].sum()
        rot, _ = Rotation.align_vectors(y[t] - cy, x[t] - cx, weights=w[t])
        np.testing.assert_allclose(fit.rotation[t], rot.as_matrix(), atol=RIGID_VS_ORACLE)


def test_rms_is_the_weighted_residual():
    rng = np.random.default_rng(3)
    x, y, w = random_problem(rng)
    fit = fit_rigid(x, y, w)
    resid = fit.apply(x) - y
    rms = np.sqrt((w * (resid ** 2).sum(axis=-1)).sum(axis=1) / w.sum(axis=1))
    np.testing.assert_allclose(fit.rms, rms, atol=RIGID_RMS_MM)


@pytest.mark.parametrize("shared", [False, True])
def test_exact_transform_recovered_and_inverted(shared):
    rng = np.random.default_rng(4)
    x, _, _ = random_problem(rng, n_frames=20, shared=shared)
    rot = Rotation.random(20, random_state=5)
    trans = rng.normal(size=(20, 3)) * 500
    y = np.einsum("tij,tnj->tni", rot.as_matrix(), np.broadcast_to(x, (20, 6, 3)))
    y += trans[:, None]
    fit = fit_rigid(x, y)
    err = Rotation.from_matrix(fit.rotation) * rot.inv()
    assert np.degrees(err.magnitude()).max() < RIGID_EXACT_DEG
    np.testing.assert_allclose(fit.translation, trans, atol=RIGID_EXACT_MM)
    np.testing.assert_allclose(fit.apply_inverse(y), np.broadcast_to(x, y.shape),
                               atol=RIGID_EXACT_MM)


def test_half_turn_is_recovered():
    x = np.array([[0.0, 0, 0], [50, 0, 0], [0, 70, 0], [0, 0, 90], [20, 30, 40]])
    for axis in np.eye(3):
        rot = Rotation.from_rotvec(np.pi * axis)
        fit = fit_rigid(x, rot.apply(x))
        np.testing.assert_allclose(fit.rotation, rot.as_matrix(), atol=EXACT_FLOAT64)


def test_reflection_is_never_returned():
    rng = np.random.default_rng(6)
    x = rng.normal(size=(30, 5, 3)) * 50
    mirror = np.diag([1.0, 1.0, -1.0])
    y = x @ mirror                                   # best orthogonal map has det -1
    fit = fit_rigid(x, y, scale=True)
    np.testing.assert_allclose(np.linalg.det(fit.rotation), 1.0, atol=EXACT_FLOAT64)
    for t in range(30):
        rot, trans, s = svd_oracle(x[t], y[t], np.ones(5), True)
        np.testing.assert_allclose(fit.rotation[t], rot, atol=RIGID_VS_ORACLE)
        np.testing.assert_allclose(fit.scale[t], s, rtol=RIGID_MIRRORED_SCALE)


def test_zero_weight_and_nan_points_are_dropped():
    rng = np.random.default_rng(7)
    x, y, w = random_problem(rng, n_frames=15, n_points=7)
    w[:, 3] = 0.0
    y_nan = y.copy()
    y_nan[:, 3] = np.nan
    keep = [0, 1, 2, 4, 5, 6]
    dropped = fit_rigid(x[:, keep], y[:, keep], w[:, keep])
    for fit in (fit_rigid(x, y, w), fit_rigid(x, y_nan, np.where(w > 0, w, 1.0))):
        np.testing.assert_allclose(fit.rotation, dropped.rotation, atol=RIGID_DROPPED_ROT)
        np.testing.assert_allclose(fit.translation, dropped.translation, atol=RIGID_DROPPED_MM)
        assert (fit.n_points == 6).all()


def test_too_few_or_collinear_points_have_no_fit():
    x = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]])
    y = np.broadcast_to(x, (3, 4, 3)).copy()
    w = np.ones((3, 4))
    w[0, 2:] = 0.0                                   # two points left
    y[1, [2, 3]] = [[20, 0, 0], [30, 0, 0]]
    xs = np.broadcast_to(x, (3, 4, 3)).copy()
    xs[1, [2, 3]] = [[20, 0, 0], [30, 0, 0]]         # all four on the x axis
    fit = fit_rigid(xs, y, w)
    assert fit.valid.tolist() == [False, False, True]
    assert np.isnan(fit.rotation[:2]).all() and np.isnan(fit.translation[:2]).all()
    np.testing.assert_allclose(fit.rotation[2], np.eye(3), atol=EXACT_FLOAT64)


@pytest.mark.parametrize("args, kwargs, match", [
    ((np.zeros((4, 2)), np.zeros((4, 2))), {}, r"source must have shape \(\.\.\., n_points, 3\)"),
    ((np.zeros((4, 3)), np.zeros((5, 3))), {}, "source has 4 points but target has 5"),
    ((np.zeros((4, 3)), np.zeros((4, 3)), -np.ones(4)), {}, "weights must be non-negative"),
    ((np.zeros((4, 3)), np.zeros((4, 3)), np.ones(3)), {}, r"weights must have shape \(\.\.\., 4\)"),
    ((np.zeros((2, 4, 3)), np.zeros((3, 4, 3))), {}, "do not broadcast"),
])
def test_errors(args, kwargs, match):
    with pytest.raises(InputError, match=match):
        fit_rigid(*args, **kwargs)
