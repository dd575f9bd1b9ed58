"""The exact marker-centre model: centres 2 mm off the ICT skin, against the true weights."""

from __future__ import annotations

import numpy as np
import pytest
import threadpoolctl
from tolerances import (
    EXACT_FLOAT64,
    MARKER_CENTRES_CM,
    MARKER_CENTRES_COST,
    MARKER_CENTRES_FIXED_POINT,
    MARKER_CENTRES_WEIGHTS,
    SOLVE_SAME_MINIMIZER,
)

import fit.solve.marker_centres
import mocap.mesh.layout
from fit.solve.gcv import gcv_smoothness
from fit.solve.marker_centres import solve_at_marker_centres
from fit.solve.weights import solve_weights
from mocap.errors import InputError
from mocap.synth.performance import match_shape_names

N_FRAMES = 120


@pytest.fixture(scope="module")
def centres_case(ict_basis, ict_layout, arkit_performance):
    """The ICT face, the 66-marker layout (2 mm offsets), real weights and their exact centres."""
    basis, layout = ict_basis, ict_layout
    assert np.all(layout.offsets > 0)
    performance = arkit_performance
    columns = match_shape_names(performance.names, basis.names)
    weights = np.zeros((performance.n_frames, len(basis.names)))
    for i, name in enumerate(basis.names):
        if name in columns:
            weights[:, i] = performance.weights[:, columns[name]]
    rows = np.linspace(0, len(weights) - 1, N_FRAMES).astype(int)
    truth = np.clip(weights[rows], 0.0, 1.0)
    V0, E = basis.neutral.vertices, basis.displacements
    rest = layout.positions(V0)
    # the oracle: the layout's centres on the whole deformed mesh, frame by frame
    data = np.stack([layout.positions(V0 + np.tensordot(w, E, axes=1)) for w in truth]) - rest
    # the tangent at the neutral, by central differences on the whole mesh
    h = 1e-4
    tangent = np.stack([(layout.positions(V0 + h * e) - layout.positions(V0 - h * e)) / (2 * h)
                        for e in E])
    return basis, layout, truth, data, tangent


@pytest.mark.parametrize("per_pass", [None, 50], ids=["one-pass", "passes-and-a-remainder"])
def test_positions_under_weights_are_the_positions_on_the_deformed_mesh(centres_case,
                                                                         per_pass, monkeypatch):
    basis, layout, truth, data, _ = centres_case
    if per_pass is not None:
        monkeypatch.setattr(mocap.mesh.layout, "_FRAMES_PER_PASS", per_pass)
    got = layout.positions_under_weights(basis.neutral.vertices, basis.displacements, truth)
    np.testing.assert_allclose(got - layout.positions(basis.neutral.vertices), data,
                               rtol=0, atol=EXACT_FLOAT64)


def test_noise_free_centres_give_back_the_true_weights(centres_case):
    """The linear (tangent) model misses the normals turning; the exact model does not."""
    basis, layout, truth, data, tangent = centres_case
    linear = solve_weights(tangent, data, lower=0.0, upper=1.0).weights
    fit = solve_at_marker_centres(layout, basis.neutral.vertices, basis.displacements, tangent,
                                  data, lower=0.0, upper=1.0)
    assert fit.solution.status == 0, fit.solution.message
    assert fit.settled.all() and fit.n_steps.max() > 2
    linear_error = np.abs(linear - truth).max()
    assert linear_error > 0.1                           # the tangent model is off here
    assert np.abs(fit.solution.weights - truth).max() < MARKER_CENTRES_WEIGHTS
    np.testing.assert_allclose(fit.displacements, data, rtol=0,
                               atol=MARKER_CENTRES_CM)   # cm: 0.1 µm
    assert np.all(fit.solution.cost < MARKER_CENTRES_COST)


@pytest.mark.parametrize("smoothness, bounds", [(0.0, (0.0, 1.0)), (0.5, (0.0, 1.0)),
                                                (0.5, (-np.inf, np.inf)), (0.5, (0.0, np.inf))],
                         ids=["frames", "smooth", "smooth-unbounded", "smooth-one-sided"])
def test_noisy_centres_reach_a_fixed_point_of_the_chord_step(centres_case, smoothness, bounds):
    """With noise the result solves the linear problem of its own nonlinear residual (the
    smooth one without bounds steps through the spectral solve, one-sided through the
    active set)."""
    basis, layout, truth, data, tangent = centres_case
    noisy = data + 0.02 * np.random.default_rng(3).standard_normal(data.shape)   # 0.2 mm
    lower, upper = bounds
    fit = solve_at_marker_centres(layout, basis.neutral.vertices, basis.displacements,
                                  tangent, noisy, lower=lower, upper=upper,
                                  smoothness=smoothness, tol=1e-9, max_steps=200)
    w = fit.solution.weights
    moved = layout.positions_under_weights(basis.neutral.vertices, basis.displacements, w) \
        - layout.positions(basis.neutral.vertices)
    again = solve_weights(tangent, noisy - (moved - np.tensordot(w, tangent, axes=1)),
                          lower=lower, upper=upper, smoothness=smoothness).weights
    assert fit.settled.all() and fit.solution.status == 0, fit.solution.message
    np.testing.assert_allclose(again, w, rtol=0, atol=MARKER_CENTRES_FIXED_POINT)
    np.testing.assert_allclose(fit.displacements, moved, rtol=0, atol=EXACT_FLOAT64)


def test_gcv_smoothness_is_chosen_once_on_the_tangent_model(centres_case):
    basis, layout, _, data, tangent = centres_case
    noisy = data + 0.02 * np.random.default_rng(4).standard_normal(data.shape)
    args = (layout, basis.neutral.vertices, basis.displacements, tangent, noisy)
    chosen = solve_at_marker_centres(*args, lower=0.0, upper=1.0, smoothness="gcv")
    lam = gcv_smoothness(tangent.reshape(len(tangent), -1).T, noisy.reshape(len(noisy), -1))
    assert chosen.solution.smoothness == lam > 0
    fixed = solve_at_marker_centres(*args, lower=0.0, upper=1.0, smoothness=lam)
    np.testing.assert_array_equal(chosen.solution.weights, fixed.solution.weights)


def test_pieces_of_the_frames_on_threads_are_one_fit(centres_case, monkeypatch):
    """Independent frames step in pieces shared among threads: the same weights, bit for bit,
    on one BLAS thread or two, and those of the frames fitted as one piece up to rounding."""
    basis, layout, truth, data, tangent = centres_case
    noisy = data + 0.02 * np.random.default_rng(5).standard_normal(data.shape)
    args = (layout, basis.neutral.vertices, basis.displacements, tangent, noisy)
    whole = solve_at_marker_centres(*args, lower=0.0, upper=1.0)
    monkeypatch.setattr(fit.solve.marker_centres, "_FRAMES_PER_TASK", 25)   # 5 pieces
    fits = {}
    for threads in (1, 2):
        with threadpoolctl.threadpool_limits(threads, user_api="blas"):
            fits[threads] = solve_at_marker_centres(*args, lower=0.0, upper=1.0)
    for got in fits.values():
        assert got.solution.status == 0, got.solution.message
        np.testing.assert_array_equal(got.n_steps, whole.n_steps)
        np.testing.assert_allclose(got.solution.weights, whole.solution.weights, rtol=0,
                                   atol=EXACT_FLOAT64)
        np.testing.assert_allclose(got.displacements, whole.displacements, rtol=0,
                                   atol=EXACT_FLOAT64)
    np.testing.assert_array_equal(fits[2].solution.weights, fits[1].solution.weights)
    np.testing.assert_array_equal(fits[2].solution.cost, fits[1].solution.cost)


def test_smooth_fit_evaluates_pieces_of_the_frames_on_threads_as_one(centres_case,
                                                                     monkeypatch):
    """The smooth fit's evaluations of the centre model share pieces of the frames among
    threads: the same weights and centres, bit for bit, on one BLAS thread or two, and
    those of one piece up to rounding."""
    basis, layout, _, data, tangent = centres_case
    noisy = data + 0.02 * np.random.default_rng(6).standard_normal(data.shape)
    args = (layout, basis.neutral.vertices, basis.displacements, tangent, noisy)
    fits = {}
    for per_piece, threads in ((len(noisy), 1), (64, 1), (64, 2)):   # 64: two pieces
        monkeypatch.setattr(fit.solve.marker_centres, "_FRAMES_PER_EVALUATION", per_piece)
        with threadpoolctl.threadpool_limits(threads, user_api="blas"):
            fits[per_piece, threads] = solve_at_marker_centres(*args, lower=0.0, upper=1.0,
                                                               smoothness=0.5)
    one = fits[len(noisy), 1]
    for got in fits.values():
        assert got.solution.status == 0, got.solution.message
        np.testing.assert_allclose(got.solution.weights, one.solution.weights, rtol=0,
                                   atol=EXACT_FLOAT64)
        np.testing.assert_allclose(got.displacements, one.displacements, rtol=0,
                                   atol=EXACT_FLOAT64)
    np.testing.assert_array_equal(fits[64, 2].solution.weights, fits[64, 1].solution.weights)
    np.testing.assert_array_equal(fits[64, 2].displacements, fits[64, 1].displacements)


def test_an_unsettled_frame_is_reported(centres_case):
    basis, layout, _, data, tangent = centres_case
    fit = solve_at_marker_centres(layout, basis.neutral.vertices, basis.displacements, tangent,
                                  data, lower=0.0, upper=1.0, max_steps=1)
    assert fit.solution.status == 1 and not fit.settled.any()
    assert f"{N_FRAMES} frames had not settled after 1 steps" in fit.solution.message


def test_one_smooth_step_is_the_smooth_solve_at_the_clipped_unbounded_optimum(centres_case):
    """With smoothness the first chord step is the smooth solve of the data less r at the
    linear model's unbounded smooth optimum clipped to the bounds; stopped there
    (max_steps=1), the result is that solve, finished exactly even though the active set
    was not yet optimal when the step was taken, and the frames are reported unsettled."""
    basis, layout, _, data, tangent = centres_case
    noisy = data + 0.02 * np.random.default_rng(6).standard_normal(data.shape)
    V0, E = basis.neutral.vertices, basis.displacements
    fit = solve_at_marker_centres(layout, V0, E, tangent, noisy, lower=0.0, upper=1.0,
                                  smoothness=0.5, max_steps=1)
    start = np.clip(solve_weights(tangent, noisy, smoothness=0.5).weights, 0.0, 1.0)
    moved = layout.positions_under_weights(V0, E, start) - layout.positions(V0)
    expected = solve_weights(tangent, noisy - (moved - np.tensordot(start, tangent, axes=1)),
                             lower=0.0, upper=1.0, smoothness=0.5)
    assert fit.solution.kkt_residual.max() <= 1e-9 and not fit.settled.all()
    assert fit.n_steps.tolist() == [1] * N_FRAMES
    np.testing.assert_allclose(fit.solution.weights, expected.weights, rtol=0,
                               atol=SOLVE_SAME_MINIMIZER)


def test_mismatched_inputs_are_named(centres_case):
    basis, layout, _, data, tangent = centres_case
    args = (layout, basis.neutral.vertices, basis.displacements)
    with pytest.raises(InputError, match=r"basis has 65 markers, the layout 66"):
        solve_at_marker_centres(*args, tangent[:, 1:], data[:, 1:])
    with pytest.raises(InputError, match=r"displacements hold 52 shapes, the basis 53"):
        solve_at_marker_centres(layout, basis.neutral.vertices, basis.displacements[1:],
                                tangent, data)
    with pytest.raises(InputError, match=r"data must have shape \(any, 66, 3\)"):
        solve_at_marker_centres(*args, tangent, data[:, :, :2])
    with pytest.raises(InputError, match=r"data contains NaN"):
        solve_at_marker_centres(*args, tangent, np.where(data == data[0, 0, 0], np.nan, data))
