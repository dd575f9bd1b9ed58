"""Stages of the whole chain on a short demo session, against independent solvers."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import threadpoolctl
from scipy.optimize import lsq_linear
from tolerances import (
    EXACT_FLOAT64,
    EXACT_MM,
    MARKER_BASIS_LIFTED,
    MARKER_CENTRES_COST_REL,
    MARKER_CENTRES_VS_OPTIMUM,
    MESH_EXACT,
    MESH_SPACE_CHAIN,
    MESH_SPACE_VS_DENSE,
    PCA_FIT_VS_LSTSQ_REL,
    SOLVE_OBJECTIVE_FLOOR,
    SOLVE_OBJECTIVE_REL,
)

import fit.pipeline.stages
import mocap
from basis.basis_io import load_basis
from fit.demo import DEMO_MAX_GAP, make_demo_session
from fit.pipeline import (
    BASES,
    SPACES,
    BasisOptions,
    BindOptions,
    FitOptions,
    basis_stage,
    bind_stage,
    complete_span,
    fit_stage,
    ingest_stage,
    retarget_stage,
)
from fit.solve.gcv import gcv_smoothness
from fit.solve.marker_basis import marker_basis
from fit.solve.mesh_space import solve_mesh_space
from fit.solve.sampling_estimator import estimate_weights_by_sampling
from fit.solve.weights import solve_weights
from mocap.clean.ingest import IngestOptions
from mocap.errors import InputError, MarkerError
from mocap.markerset import load_markerset
from mocap.mesh.landmarks import load_mesh_landmarks
from mocap.mesh.layout import MarkerLayout
from mocap.mesh.mesh import load_mesh
from mocap.neutral import hold_window


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """A 3 s demo session through ingest, bind, retarget and the bases."""
    session = make_demo_session(tmp_path_factory.mktemp("session"), seconds=3.0)
    paths = session.paths
    markerset = load_markerset(paths["markerset"])
    mesh = load_mesh(paths["neutral"])
    landmarks = load_mesh_landmarks(paths["landmarks"], mesh)
    ingested = ingest_stage(mocap.read(paths["capture"]), markerset,
                            IngestOptions(max_gap=DEMO_MAX_GAP))
    take = complete_span(ingested.take, markerset.face_markers)
    bound = bind_stage(take, markerset, mesh, landmarks, options=BindOptions(skin_offset=2.0))
    retargeted = retarget_stage(take, bound, mesh, markerset)
    bases = basis_stage(retargeted, load_basis(paths["shapes"]))
    return dict(take=take, bound=bound, retargeted=retargeted, bases=bases, mesh=mesh,
                markerset=markerset, landmarks_path=paths["landmarks"])


@pytest.fixture(scope="module")
def fitted(chain):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # QE: rank ≤ m + 1 by construction
        out = {space: fit_stage(chain["take"], chain["bound"], chain["retargeted"],
                                chain["bases"], options=FitOptions(space=space))
               for space in SPACES}
        out["linear"] = fit_stage(chain["take"], chain["bound"], chain["retargeted"],
                                  chain["bases"], options=FitOptions(marker_centres="linear"))
        return out


def test_h_weights_solve_marker_problem_like_lsq_linear(chain, fitted):
    """marker_centres = "linear": the tangent basis' bounded least squares, as bvls solves it."""
    basis = chain["bases"].bases["H"]
    B = marker_basis(chain["bound"].binding, basis.displacements, chain["retargeted"].labels,
                     mesh=chain["mesh"]).reshape(len(basis.names), -1).T
    D = chain["retargeted"].displacements.reshape(len(fitted["linear"].weights["H"]), -1)
    sol = fitted["linear"].solutions["H"]
    assert np.all((sol.weights >= 0) & (sol.weights <= 1))
    for t in np.linspace(0, len(D) - 1, 6).astype(int):
        ref = lsq_linear(B, D[t], bounds=(0, 1), method="bvls", max_iter=10_000)
        ours = 0.5 * np.sum((B @ sol.weights[t] - D[t]) ** 2)
        assert ours <= ref.cost * (1 + SOLVE_OBJECTIVE_REL) + SOLVE_OBJECTIVE_FLOOR
        assert sol.cost[t] == pytest.approx(ours, rel=EXACT_FLOAT64)


def test_h_weights_at_the_exact_marker_centres_near_least_squares(chain, fitted):
    """The default fits the centres as they move off the turning skin.

    Oracle: scipy's bounded nonlinear least squares of the same centres,
    frame by frame. Ours (a fixed point whose residual is orthogonal to the
    tangent basis) costs at most 1 % more than its optimum, and over the take
    less than the linear model's weights do under the exact model (frame by
    frame the two can tie where the skin barely turns: the fixed point is not
    the exact model's minimizer).
    """
    from scipy.optimize import least_squares

    basis, bound = chain["bases"].bases["H"], chain["bound"]
    labels, mesh = chain["retargeted"].labels, chain["mesh"]
    layout = bound.binding.centre_layout(mesh, labels)
    rest = layout.positions(mesh.vertices)
    D = chain["retargeted"].displacements
    exact, linear = fitted["marker"].solutions["H"], fitted["linear"].solutions["H"]
    assert exact.status == 0, exact.message

    def residual(w, t):
        return (layout.positions(mesh.vertices + np.tensordot(w, basis.displacements, axes=1))
                - rest - D[t]).ravel()
    for t in np.linspace(0, len(D) - 1, 4).astype(int):
        ref = least_squares(residual, linear.weights[t], bounds=(0.0, 1.0), args=(t,),
                            xtol=1e-12, ftol=1e-12, gtol=1e-12)
        ours = 0.5 * np.sum(residual(exact.weights[t], t) ** 2)
        assert ours == pytest.approx(exact.cost[t], rel=MARKER_CENTRES_COST_REL)
        assert ref.cost * (1 - SOLVE_OBJECTIVE_REL) <= ours <= MARKER_CENTRES_VS_OPTIMUM * ref.cost
    linear_moved = layout.positions_under_weights(mesh.vertices, basis.displacements,
                                                  linear.weights) - rest
    assert exact.cost.sum() < 0.5 * np.sum((linear_moved - D) ** 2)
    np.testing.assert_allclose(fitted["marker"].reconstructed["H"],
                               bound.neutral_pose(chain["take"].select(labels).positions)
                               + np.stack([residual(w, t).reshape(-1, 3) + D[t] for t, w in
                                           enumerate(exact.weights)]) @ bound.binding.rotation
                               / bound.binding.scale, rtol=0, atol=EXACT_MM)


def test_moving_average_fit_solves_the_averaged_displacements(chain):
    window = 5
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        fit = fit_stage(chain["take"], chain["bound"], chain["retargeted"], chain["bases"],
                        options=FitOptions(moving_average=window, marker_centres="linear"))
    basis = chain["bases"].bases["H"]
    B = marker_basis(chain["bound"].binding, basis.displacements, chain["retargeted"].labels,
                     mesh=chain["mesh"]).reshape(len(basis.names), -1).T
    D = chain["retargeted"].displacements
    D = D.reshape(len(D), -1)
    for t in (0, 1, len(D) // 2, len(D) - 1):                    # by hand, cut at the ends
        d = D[max(0, t - 2):t + 3].mean(axis=0)
        ref = lsq_linear(B, d, bounds=(0, 1), method="bvls", max_iter=10_000)
        ours = 0.5 * np.sum((B @ fit.weights["H"][t] - d) ** 2)
        assert ours <= ref.cost * (1 + SOLVE_OBJECTIVE_REL) + SOLVE_OBJECTIVE_FLOOR


@pytest.mark.parametrize("space", SPACES)
def test_gcv_smoothness_is_chosen_per_basis(chain, space):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        fit = fit_stage(chain["take"], chain["bound"], chain["retargeted"], chain["bases"],
                        options=FitOptions(space=space, smoothness="gcv"))
    lams = {name: sol.smoothness for name, sol in fit.solutions.items()}
    assert all(lam > 0 for lam in lams.values()) and set(lams) == set(BASES)
    if space == "marker":          # H: the marker problem of the test above, GCV on it
        basis = chain["bases"].bases["H"]
        B = marker_basis(chain["bound"].binding, basis.displacements,
                         chain["retargeted"].labels, mesh=chain["mesh"])
        D = chain["retargeted"].displacements
        assert lams["H"] == gcv_smoothness(B.reshape(len(B), -1).T, D.reshape(len(D), -1))
        assert fit.solutions["H"].status == 0


def test_sampling_h_solver_is_the_estimator_and_never_beats_the_exact_fit(chain, fitted):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        fit = fit_stage(chain["take"], chain["bound"], chain["retargeted"], chain["bases"],
                        options=FitOptions(h_solver="sampling", n_samples=300,
                                           n_neighbors=20))
    basis = chain["bases"].bases["H"]
    at = marker_basis(chain["bound"].binding, basis.displacements, chain["retargeted"].labels,
                      mesh=chain["mesh"])
    direct = estimate_weights_by_sampling(at, chain["retargeted"].displacements,
                                          n_samples=300, n_neighbors=20)
    np.testing.assert_array_equal(fit.weights["H"], direct.weights)
    exact = fitted["linear"].solutions["H"].cost           # the estimator's problem
    assert (fit.solutions["H"].cost >= exact * (1 - SOLVE_OBJECTIVE_REL)).all()
    assert fit.solutions["H"].cost.mean() > exact.mean()
    # the other bases are solved exactly as before
    np.testing.assert_array_equal(fit.weights["QE"], fitted["marker"].weights["QE"])


def test_marker_basis_moves_the_offset_marker_centres_with_the_skin(chain):
    """A translation moves every marker alike; a rotation turns the centres off the skin too."""
    binding, mesh = chain["bound"].binding, chain["mesh"]
    assert binding.skin_offset == 2.0
    omega = np.array([0.02, -0.05, 0.03])                    # an infinitesimal rotation
    centre = mesh.vertices.mean(axis=0)
    fields = np.stack([np.broadcast_to([0.3, -0.2, 0.1], mesh.vertices.shape),
                       np.cross(omega, mesh.vertices - centre)])
    got = marker_basis(binding, fields, mesh=mesh)
    skin = marker_basis(binding, fields)                       # no mesh: the surface points
    np.testing.assert_allclose(got[0], np.broadcast_to([0.3, -0.2, 0.1], got[0].shape),
                               atol=MESH_EXACT)
    np.testing.assert_allclose(skin[1], np.cross(omega, binding.marker_points(mesh.vertices)
                                                 - centre), atol=EXACT_FLOAT64)
    # the centres: the surface points lifted along their normals, which turn with the mesh
    lifted = MarkerLayout(binding.labels, binding.vertex_ids, binding.barycentric,
                          binding.face_ids, np.full(len(binding.labels),
                                                    binding.skin_offset * binding.scale),
                          mesh.faces, mesh.n_vertices).positions(mesh.vertices)
    np.testing.assert_allclose(got[1], np.cross(omega, lifted - centre), atol=MARKER_BASIS_LIFTED)
    assert np.abs(got[1] - skin[1]).max() > 1e-3 * np.abs(skin[1]).max()



def test_gesture_marker_basis_lifts_the_centres_too_in_capture_mm(chain):
    """The gestures' basis B_i (capture mm) follows the same offset centres: a mesh
    rotation field, brought to the capture frame by the binding's similarity."""
    binding, mesh = chain["bound"].binding, chain["mesh"]
    omega = np.array([0.02, -0.05, 0.03])
    centre = mesh.vertices.mean(axis=0)
    fields = np.cross(omega, mesh.vertices - centre)[None]
    labels = binding.labels[::-1]
    got = marker_basis(binding, fields, labels, mesh=mesh, units="mm")
    lifted = MarkerLayout(binding.labels, binding.vertex_ids, binding.barycentric,
                          binding.face_ids, np.full(len(binding.labels),
                                                    binding.skin_offset * binding.scale),
                          mesh.faces, mesh.n_vertices).positions(mesh.vertices)[::-1]
    want = np.cross(omega, lifted - centre) @ np.asarray(binding.rotation) / binding.scale
    np.testing.assert_allclose(got[0], want, atol=MARKER_BASIS_LIFTED / binding.scale)
    skin = marker_basis(binding, fields, labels, units="mm")
    assert np.abs(got - skin).max() > 1e-3 * np.abs(skin).max()


def test_marker_basis_names_a_marker_the_binding_lacks(chain):
    binding, mesh = chain["bound"].binding, chain["mesh"]
    fields = np.zeros((1, mesh.n_vertices, 3))
    with pytest.raises(MarkerError, match="marker 'nope'.*is not in the binding"):
        marker_basis(binding, fields, [binding.labels[0], "nope"], mesh=mesh)

def test_pca_marker_fit_is_least_squares_with_mean_fixed(chain, fitted):
    basis = chain["bases"].bases["PCA"]
    at = marker_basis(chain["bound"].binding, basis.displacements, chain["retargeted"].labels)
    B = at[1:].reshape(len(at) - 1, -1).T
    D = chain["retargeted"].displacements
    D = D.reshape(len(D), -1) - at[0].ravel()
    ref = np.linalg.lstsq(B, D.T, rcond=None)[0].T
    weights = fitted["marker"].weights["PCA"]
    np.testing.assert_array_equal(weights[:, 0], 1.0)
    np.testing.assert_allclose(weights[:, 1:], ref, atol=PCA_FIT_VS_LSTSQ_REL * np.abs(ref).max())


@pytest.mark.parametrize("space", SPACES)
def test_reconstruction_is_neutral_plus_basis_in_mm(chain, fitted, space):
    bound, fit = chain["bound"], fitted[space]
    binding = bound.binding
    labels = chain["retargeted"].labels
    neutral = chain["take"].select(labels).positions[bound.frame]
    at = marker_basis(binding, chain["bases"].bases["QE"].displacements, labels)
    disp_mesh = np.einsum("tn,nmc->tmc", fit.weights["QE"], at)
    # back to capture mm through the binding's inverse similarity (independent path)
    expected = binding.to_capture(binding.to_mesh(neutral) + disp_mesh)
    np.testing.assert_allclose(fit.reconstructed["QE"], expected, atol=EXACT_MM)


def test_reconstruction_in_tasks_on_threads_is_the_whole_one(chain, fitted, monkeypatch):
    """The reconstructed markers are made by tasks of frames shared among the threads: with
    tasks of 7 frames, the same bits on one BLAS thread or two, and the markers of one task
    to rounding (a product of 7 rows may round otherwise than one of all)."""
    monkeypatch.setattr(fit.pipeline.stages, "_FRAMES_PER_TASK", 7)
    args = (chain["take"], chain["bound"], chain["retargeted"], chain["bases"])
    got = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # QE: rank ≤ m + 1 by construction
        for threads in (1, 2):
            with threadpoolctl.threadpool_limits(threads, user_api="blas"):
                got[threads] = fit_stage(*args, options=FitOptions(space="marker"))
    for name, markers in fitted["marker"].reconstructed.items():
        assert len(markers) > 7
        np.testing.assert_array_equal(got[2].reconstructed[name], got[1].reconstructed[name])
        np.testing.assert_allclose(got[1].reconstructed[name], markers, rtol=0, atol=EXACT_MM)


@pytest.mark.parametrize("bounds", [(-np.inf, np.inf), (0.0, 1.0), (-0.1, 1.1)])
@pytest.mark.parametrize("with_offset", [False, True])
def test_mesh_space_reduction_equals_materialized_solve(bounds, with_offset):
    rng = np.random.default_rng(3)
    n, N, M, T = 6, 40, 9, 25
    E = rng.standard_normal((n, N, 3))
    W = rng.standard_normal((N, M))
    D = 0.3 * rng.standard_normal((T, M, 3))
    offset = 0.2 * rng.standard_normal((N, 3)) if with_offset else np.zeros((N, 3))
    target = np.einsum("nm,tmc->tnc", W, D) - offset
    dense = solve_weights(E.reshape(n, -1).T, target.reshape(T, -1), lower=bounds[0],
                          upper=bounds[1])
    ours = solve_mesh_space(E, W, D, offset=offset if with_offset else None,
                            lower=bounds[0], upper=bounds[1])
    np.testing.assert_allclose(ours.weights, dense.weights, atol=MESH_SPACE_VS_DENSE)
    np.testing.assert_allclose(ours.cost, dense.cost, rtol=MESH_SPACE_VS_DENSE)


def test_mesh_space_fit_matches_materialized_on_the_chain(chain, fitted):
    basis = chain["bases"].bases["H"]
    W = chain["retargeted"].operator.matrix
    W = W.toarray() if hasattr(W, "toarray") else W
    D = chain["retargeted"].displacements[::20]
    target = np.einsum("nm,tmc->tnc", W, D).reshape(len(D), -1)
    dense = solve_weights(basis.displacements.reshape(len(basis.names), -1).T, target,
                          lower=0, upper=1)
    np.testing.assert_allclose(fitted["mesh"].weights["H"][::20], dense.weights,
                               atol=MESH_SPACE_CHAIN)


def test_complete_span_drops_incomplete_end_frames():
    pos = np.zeros((6, 2, 3))
    pos[:2, 0] = np.nan
    pos[5, 1] = np.nan
    pos[3, 1] = np.nan                        # inside the span: kept
    take = mocap.Take(("a", "b"), pos, rate=100.0, first_frame=10)
    cut = complete_span(take, ["a", "b"])
    assert cut.first_frame == 12 and cut.n_frames == 3
    np.testing.assert_array_equal(np.isnan(cut.positions[:, 1, 0]), [False, True, False])


def test_complete_span_rejects_a_take_without_a_complete_frame():
    pos = np.zeros((3, 2, 3))
    pos[1:, 0] = np.nan                       # each marker is seen, never both together
    pos[0, 1] = np.nan
    with pytest.raises(InputError, match="no frame has every face marker"):
        complete_span(mocap.Take(("a", "b"), pos, rate=100.0), ["a", "b"])


@pytest.mark.parametrize("cls, kwargs, match", [
    (FitOptions, {"space": "vertex"}, "space must be one of"),
    (FitOptions, {"h_epsilon": -0.1}, "h_epsilon must be a finite number >= 0"),
    (FitOptions, {"smoothness": float("nan")}, "smoothness must be a finite number >= 0"),
    (FitOptions, {"smoothness": "GCV"}, "smoothness must be a number >= 0 or one of 'gcv'"),
    (FitOptions, {"smoothness": True}, "smoothness must be a finite number >= 0 or one"),
    (FitOptions, {"h_solver": "sampling", "smoothness": "gcv"}, "and smoothness = 0"),
    (BasisOptions, {"pca_coverage": 1.5}, r"pca_coverage must be in \(0, 1\]"),
    (BasisOptions, {"pca_components": 0}, "pca_components must be at least 1"),
    (BasisOptions, {"qe_missing": "drop"}, "qe_missing must be one of"),
    (BindOptions, {"frame": -1}, "frame must be at least 0"),
    (BindOptions, {"frame": "still"}, "frame must be a frame number, 'auto' or 'hold'"),
    (BindOptions, {"icp": 1}, "icp must be true or false"),
    (BindOptions, {"skin_offset": -1.0}, "skin_offset must be a finite number >= 0"),
    (BindOptions, {"max_distance_warn": 0.0}, "max_distance_warn must be positive"),
    (FitOptions, {"h_solver": "bvls"}, "h_solver must be one of"),
    (FitOptions, {"moving_average": 40}, "moving_average must be an odd number of frames"),
    (FitOptions, {"moving_average": -1}, "moving_average must be at least 0"),
    (FitOptions, {"n_samples": 0}, "n_samples must be at least 1"),
    (FitOptions, {"h_solver": "sampling", "space": "mesh"}, "needs space = 'marker'"),
    (FitOptions, {"h_solver": "sampling", "smoothness": 1.0}, "and smoothness = 0"),
    (FitOptions, {"marker_centres": "curved"}, "marker_centres must be one of"),
])
def test_option_errors(cls, kwargs, match):
    with pytest.raises(InputError, match=match):
        cls(**kwargs)


def test_bind_hold_averages_the_hold_into_the_rest_pose(chain):
    take, markerset = chain["take"], chain["markerset"]
    landmarks = load_mesh_landmarks(chain["landmarks_path"], chain["mesh"])
    bound = bind_stage(take, markerset, chain["mesh"], landmarks,
                       options=BindOptions(frame="hold", skin_offset=2.0))
    window = hold_window(take.rate)
    assert bound.window == window > 1
    face = take.select(markerset.face_markers).positions
    lo = max(0, bound.frame - window // 2)
    np.testing.assert_allclose(bound.neutral_pose(face), face[lo:bound.frame + window // 2 + 1]
                               .mean(axis=0), rtol=0, atol=EXACT_FLOAT64)
    retargeted = retarget_stage(take, bound, chain["mesh"], markerset)
    # displacements from that mean: they average to zero over the window
    np.testing.assert_allclose(retargeted.displacements[lo:bound.frame + window // 2 + 1]
                               .mean(axis=0), 0.0, atol=EXACT_FLOAT64)


def test_bind_frame_beyond_take(chain):
    take = chain["take"]
    last = take.first_frame + take.n_frames - 1
    with pytest.raises(InputError, match=rf"bind.frame {last + 1} is not a frame of the take: "
                                         rf"its frames are numbered {take.first_frame}\.\.{last}"):
        bind_stage(take, chain["markerset"], chain["mesh"], {},
                   options=BindOptions(frame=last + 1))


def test_too_many_pca_components(chain):
    with pytest.raises(InputError, match="pca_components = 999 is more than"):
        basis_stage(chain["retargeted"], _artist(chain), options=BasisOptions(pca_components=999))


def _artist(chain):
    from basis.artist import ArtistBasis

    H = chain["bases"].bases["H"]
    return ArtistBasis(H.names, chain["mesh"], H.displacements)
