"""PCA of mesh sequences: implicit (operator) and streaming PCA against a dense SVD."""

import numpy as np
import pytest
from scipy.linalg import subspace_angles, svd
from tolerances import (
    EXACT_FLOAT64,
    PCA_ANGLE_RAD,
    PCA_CHUNKS_COMPONENTS,
    PCA_CHUNKS_RTOL,
    PCA_COMPONENT_DOT,
    PCA_DISCARDED_IMPLICIT_RTOL,
    PCA_DISCARDED_STREAMING_RTOL,
    PCA_EIG_FLOOR,
    PCA_EXACT_RTOL,
    PCA_IMPLICIT_RTOL,
    PCA_STREAMING_RTOL,
)

from basis.pca import (
    PCA_METHODS,
    OperatorFactor,
    PCAModel,
    pca_from_operator,
    pca_from_operators,
    pca_streaming,
)
from mocap.errors import InputError

METHODS = ("implicit",) + PCA_METHODS
RTOL = {"implicit": PCA_IMPLICIT_RTOL, "randomized": PCA_STREAMING_RTOL,
        "incremental": PCA_STREAMING_RTOL}


def make_case(*, n_frames, n_vertices, n_markers, rank, noise=0.0, operator_rank=None,
              seed=0):
    """Operator W (N, M), marker displacements D (T, M, 3) of a given rank, Ξ = W·D."""
    rng = np.random.default_rng(seed)
    operator = rng.normal(size=(n_vertices, n_markers))
    if operator_rank is not None:
        operator[:, operator_rank:] = operator[:, :n_markers - operator_rank]
    scales = 2.0 ** -np.arange(rank)
    signal = (rng.normal(size=(n_frames, rank)) * scales) @ rng.normal(size=(rank, 3 * n_markers))
    disp = (signal + noise * rng.normal(size=signal.shape) + 2.0).reshape(n_frames, n_markers, 3)
    return operator, disp, np.einsum("nk,tkc->tnc", operator, disp)


def dense_pca(xi):
    """Oracle: mean, eigenvalues (1/T), right singular vectors of the centred Ξ."""
    flat = xi.reshape(len(xi), -1)
    centred = flat - flat.mean(axis=0)
    _, s, vt = svd(centred, full_matrices=False)
    return flat.mean(axis=0), s ** 2 / len(xi), vt, np.sum(centred ** 2) / len(xi)


def fit(method, operator, disp, xi, n_components):
    if method == "implicit":
        return pca_from_operator(operator, disp, n_components=n_components)
    return pca_streaming(xi, n_components=n_components, method=method, chunk_frames=7)


CASES = {
    "signal+noise": dict(n_frames=120, n_vertices=30, n_markers=8, rank=6, noise=1e-3),
    "T<3M": dict(n_frames=10, n_vertices=30, n_markers=8, rank=9),
    "rank-deficient": dict(n_frames=60, n_vertices=30, n_markers=8, rank=4, operator_rank=5),
}


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("method", METHODS)
def test_agrees_with_dense_svd(method, case):
    operator, disp, xi = make_case(**CASES[case])
    k = min(CASES[case]["rank"], 6)
    model = fit(method, operator, disp, xi, k)
    mean, evals, vt, total = dense_pca(xi)
    np.testing.assert_allclose(model.eigenvalues, evals[:k], rtol=RTOL[method])
    assert subspace_angles(model.components.reshape(k, -1).T, vt[:k].T).max() < PCA_ANGLE_RAD
    np.testing.assert_allclose(model.total_variance, total, rtol=PCA_EXACT_RTOL)
    np.testing.assert_allclose(model.mean.ravel(), mean, rtol=PCA_EXACT_RTOL, atol=EXACT_FLOAT64)
    flat = model.components.reshape(k, -1)
    np.testing.assert_allclose(flat @ flat.T, np.eye(k), atol=EXACT_FLOAT64)
    # each component is ± the oracle's (distinct eigenvalues), sign fixed by its largest entry
    np.testing.assert_allclose(np.abs(np.sum(flat * vt[:k], axis=1)), 1, atol=PCA_COMPONENT_DOT)
    assert (flat[np.arange(k), np.abs(flat).argmax(axis=1)] > 0).all()
    assert model.n_frames == len(xi) and model.method == method


@pytest.mark.parametrize("case", CASES)
def test_implicit_keeps_numerical_rank(case):
    operator, disp, xi = make_case(**CASES[case])
    model = pca_from_operator(operator, disp)
    rank = np.linalg.matrix_rank(xi.reshape(len(xi), -1) - xi.reshape(len(xi), -1).mean(0))
    assert model.n_components == rank
    _, evals, _, _ = dense_pca(xi)
    np.testing.assert_allclose(model.eigenvalues, evals[:rank], rtol=PCA_IMPLICIT_RTOL,
                               atol=PCA_EIG_FLOOR * evals[0])


def test_implicit_full_spectrum_is_exact_when_operator_is_tall():
    """All 3M eigenvalues, the smallest included, match the dense SVD."""
    operator, disp, xi = make_case(n_frames=200, n_vertices=25, n_markers=5, rank=15,
                                   noise=0.1)
    model = pca_from_operator(operator, disp, n_components=15)
    _, evals, _, total = dense_pca(xi)
    np.testing.assert_allclose(model.eigenvalues, evals[:15], rtol=PCA_IMPLICIT_RTOL)
    np.testing.assert_allclose(model.coverage()[-1], 1, rtol=PCA_EXACT_RTOL)


def test_components_up_to_a_coverage_keep_the_whole_spectrum():
    """Computed up to a coverage, the model lifts only the components it keeps; every
    eigenvalue stays in its spectrum, whose coverage curve is the dense SVD's, and its
    components are the full model's first ones."""
    operator, disp, xi = make_case(**CASES["signal+noise"])
    full = pca_from_operator(operator, disp)
    cut = pca_from_operators([operator], [disp], coverage=0.9)
    _, evals, _, total = dense_pca(xi)
    m = cut.n_components
    assert m == full.n_for_coverage(0.9) < full.n_components
    np.testing.assert_allclose(cut.components, full.components[:m], rtol=0,
                               atol=PCA_COMPONENT_DOT)
    curve = cut.coverage_curve()
    assert len(curve) >= full.n_components and len(cut.spectrum) == len(curve)
    # W·D has rank 3M at most: the dense SVD's other eigenvalues are 0 to rounding
    np.testing.assert_allclose(curve, (np.cumsum(evals) / total)[:len(curve)],
                               rtol=PCA_IMPLICIT_RTOL)
    np.testing.assert_array_equal(cut.coverage(), curve[:m])
    np.testing.assert_array_equal(full.truncate(m).coverage_curve(), full.coverage_curve())


def test_the_operators_factor_made_once_serves_several_pcas_of_them():
    """A factor made once (:class:`OperatorFactor`), given to the PCAs of several sets of
    frames of the same operator (held-out folds), gives each the PCA it makes alone, to
    the bit, and each is the dense SVD's; a factor of other operators is refused."""
    operator, disp, xi = make_case(**CASES["signal+noise"])
    factor = OperatorFactor.of([operator])
    assert not factor.q.flags.writeable and not factor.r.flags.writeable
    for frames in (slice(0, None), slice(0, 60), slice(60, None)):
        alone = pca_from_operators([operator], [disp[frames]], n_components=4)
        shared = pca_from_operators([operator], [disp[frames]], n_components=4, factor=factor)
        for name in ("components", "eigenvalues", "mean", "spectrum"):
            np.testing.assert_array_equal(getattr(shared, name), getattr(alone, name))
        _, evals, _, _ = dense_pca(xi[frames])
        np.testing.assert_allclose(shared.eigenvalues, evals[:4], rtol=PCA_IMPLICIT_RTOL)
    with pytest.raises(InputError, match="factor is of operators of"):
        pca_from_operators([operator[:-1]], [disp], factor=factor)
    with pytest.raises(InputError, match="one mesh"):
        OperatorFactor.of([operator, operator[:-1]])


def test_a_model_without_spectrum_keeps_its_eigenvalues_when_truncated():
    model = PCAModel(np.zeros((1, 3)), np.eye(3)[:2, None], [4.0, 1.0], 5.0, 10)
    assert model.spectrum is None
    np.testing.assert_array_equal(model.coverage_curve(), [0.8, 1.0])
    small = model.truncate(1)
    np.testing.assert_array_equal(small.spectrum, [4.0, 1.0])
    np.testing.assert_array_equal(small.coverage_curve(), [0.8, 1.0])
    np.testing.assert_array_equal(small.coverage(), [0.8])


def test_model_spectrum_must_start_with_the_kept_eigenvalues():
    args = (np.zeros((1, 3)), np.eye(3)[:2, None], [4.0, 1.0], 5.0, 10)
    with pytest.raises(InputError, match="spectrum must start with the 2 eigenvalues"):
        PCAModel(*args, spectrum=[4.0, 0.5, 0.1])
    with pytest.raises(InputError, match="spectrum must start with the 2 eigenvalues"):
        PCAModel(*args, spectrum=[4.0])


def test_implicit_ill_conditioned_operator():
    """cond(W) = 1e6: the factorization W = QR stays exact (W·D spans all of it)."""
    operator, disp, _ = make_case(n_frames=80, n_vertices=30, n_markers=6, rank=18, noise=0.1)
    u, _, vt = np.linalg.svd(operator, full_matrices=False)
    operator = u @ np.diag(np.logspace(0, -6, 6)) @ vt
    xi = np.einsum("nk,tkc->tnc", operator, disp)
    model = pca_from_operator(operator, disp, n_components=18)
    _, evals, vt_dense, _ = dense_pca(xi)
    np.testing.assert_allclose(model.eigenvalues, evals[:18], rtol=PCA_IMPLICIT_RTOL,
                               atol=PCA_EIG_FLOOR * evals[0])
    assert subspace_angles(model.components[:6].reshape(6, -1).T, vt_dense[:6].T).max() \
        < PCA_ANGLE_RAD


@pytest.mark.parametrize("method", METHODS)
def test_model_methods_against_dense_oracle(method):
    operator, disp, xi = make_case(**CASES["signal+noise"])
    model = fit(method, operator, disp, xi, 6)
    _, evals, _, total = dense_pca(xi)
    brute = [sum(evals[:k + 1]) / total for k in range(6)]
    np.testing.assert_allclose(model.coverage(), brute, rtol=PCA_STREAMING_RTOL)
    for threshold in (0.5, 0.9, 0.99):
        want = next(k + 1 for k in range(len(evals)) if sum(evals[:k + 1]) / total >= threshold)
        assert model.n_for_coverage(threshold) == want
    # the mean squared reconstruction error is the discarded variance
    for m in (2, 6):
        small = model.truncate(m)
        assert small.total_variance == model.total_variance
        rebuilt = small.reconstruct(small.project(xi))
        np.testing.assert_allclose(np.sum((rebuilt - xi) ** 2) / len(xi), evals[m:].sum(),
                                   rtol=(PCA_DISCARDED_IMPLICIT_RTOL if method == "implicit"
                                         else PCA_DISCARDED_STREAMING_RTOL))


def test_project_reconstruct_roundtrip_in_span():
    operator, disp, xi = make_case(**CASES["rank-deficient"])
    model = pca_from_operator(operator, disp)
    coefs = model.project(xi)
    assert coefs.shape == (len(xi), model.n_components)
    np.testing.assert_allclose(model.reconstruct(coefs), xi, atol=PCA_EXACT_RTOL)
    np.testing.assert_allclose(model.reconstruct(model.project(xi[3])), xi[3], atol=PCA_EXACT_RTOL)
    np.testing.assert_allclose(coefs.var(axis=0), model.eigenvalues, rtol=PCA_IMPLICIT_RTOL)


def test_inputs_not_mutated_and_model_read_only():
    operator, disp, xi = make_case(**CASES["signal+noise"])
    copies = operator.copy(), disp.copy(), xi.copy()
    model = pca_from_operator(operator, disp, n_components=3)
    pca_streaming(xi, n_components=3)
    for before, after in zip(copies, (operator, disp, xi)):
        np.testing.assert_array_equal(before, after)
    with pytest.raises(ValueError, match="read-only"):
        model.components[0, 0, 0] = 1.0


@pytest.mark.parametrize("method", PCA_METHODS)
def test_chunk_iterables_match_array(method):
    _, _, xi = make_case(**CASES["signal+noise"])
    chunks = [xi[:13], xi[13:50], xi[50:51], xi[51:]]
    from_array = pca_streaming(xi, n_components=4, method=method, chunk_frames=13, rng=5)
    from_list = pca_streaming(chunks, n_components=4, method=method, rng=5)
    np.testing.assert_allclose(from_list.eigenvalues, from_array.eigenvalues, rtol=PCA_CHUNKS_RTOL)
    np.testing.assert_allclose(from_list.components, from_array.components,
                               atol=PCA_CHUNKS_COMPONENTS)
    assert from_list.n_frames == len(xi)


def test_memmap_input(tmp_path):
    """A memory-mapped (and float32) take is read chunk by chunk, like an array."""
    operator, disp, xi = make_case(**CASES["signal+noise"])
    np.save(tmp_path / "xi.npy", xi.astype(np.float32))
    np.save(tmp_path / "d.npy", disp)
    mapped = np.load(tmp_path / "xi.npy", mmap_mode="r")
    want = pca_streaming(mapped.astype(np.float64), n_components=3)
    np.testing.assert_allclose(pca_streaming(mapped, n_components=3).eigenvalues,
                               want.eigenvalues, rtol=EXACT_FLOAT64)
    implicit = pca_from_operator(operator, np.load(tmp_path / "d.npy", mmap_mode="r"))
    np.testing.assert_allclose(implicit.eigenvalues, pca_from_operator(operator, disp).eigenvalues,
                               rtol=EXACT_FLOAT64)


def test_incremental_accepts_a_generator():
    _, _, xi = make_case(**CASES["T<3M"])
    model = pca_streaming((xi[i:i + 3] for i in range(0, 10, 3)), n_components=5,
                          method="incremental")
    _, evals, _, _ = dense_pca(xi)
    np.testing.assert_allclose(model.eigenvalues, evals[:5], rtol=PCA_STREAMING_RTOL)


def test_randomized_is_reproducible():
    _, _, xi = make_case(**CASES["signal+noise"])
    a, b = (pca_streaming(xi, n_components=3, n_iter=0, rng=7) for _ in range(2))
    np.testing.assert_array_equal(a.components, b.components)


# --- errors: one per message ---------------------------------------------------------

def test_implicit_nan_frame_named():
    operator, disp, _ = make_case(**CASES["signal+noise"])
    disp[17, 2, 1] = np.nan
    with pytest.raises(InputError, match="displacements: frame 17 has NaN"):
        pca_from_operator(operator, disp)


def test_streaming_nan_frame_named():
    _, _, xi = make_case(**CASES["signal+noise"])
    xi[33, 0, 0] = np.inf
    with pytest.raises(InputError, match="frames: frame 33 has NaN or infinite"):
        pca_streaming(xi, n_components=2, chunk_frames=10)


def test_implicit_shape_mismatch():
    operator, disp, _ = make_case(**CASES["signal+noise"])
    with pytest.raises(InputError, match=r"displacements must have shape \(T, 7, 3\)"):
        pca_from_operator(operator[:, :7], disp)


def test_implicit_zero_operator():
    _, disp, _ = make_case(**CASES["signal+noise"])
    with pytest.raises(InputError, match="operator \\(30, 8\\) is all zeros"):
        pca_from_operator(np.zeros((30, 8)), disp)


def test_implicit_no_frame():
    operator, disp, _ = make_case(**CASES["signal+noise"])
    with pytest.raises(InputError, match="displacements has no frame"):
        pca_from_operator(operator, disp[:0])


def test_implicit_too_many_components():
    operator, disp, _ = make_case(**CASES["signal+noise"])
    with pytest.raises(InputError, match=r"at most 3 \* min\(N, M\) = 24"):
        pca_from_operator(operator, disp, n_components=25)


def test_implicit_more_components_than_operator_rank():
    operator, disp, _ = make_case(**CASES["rank-deficient"])
    with pytest.raises(InputError, match="operator has numerical rank 5: at most 15"):
        pca_from_operator(operator, disp, n_components=16)


def test_streaming_too_many_components():
    _, _, xi = make_case(**CASES["T<3M"])
    with pytest.raises(InputError, match=r"n_components=11 exceeds min\(n_frames"):
        pca_streaming(xi, n_components=11)


def test_streaming_bad_method():
    with pytest.raises(InputError, match="method must be one of"):
        pca_streaming(np.zeros((4, 2, 3)), n_components=1, method="dense")


def test_streaming_bad_array_shape():
    with pytest.raises(InputError, match=r"frames must have shape \(T, N, 3\)"):
        pca_streaming(np.zeros((4, 6)), n_components=1)


def test_streaming_not_iterable():
    with pytest.raises(InputError, match="frames must be an array .* got float"):
        pca_streaming(3.0, n_components=1, method="incremental")


def test_streaming_one_shot_iterator_with_randomized():
    with pytest.raises(InputError, match="one-shot iterator"):
        pca_streaming(iter([np.zeros((4, 2, 3))]), n_components=1)


def test_streaming_inconsistent_chunks():
    with pytest.raises(InputError, match="starting at frame 4 has 5 vertices, expected 6"):
        pca_streaming([np.ones((4, 6, 3)), np.ones((3, 5, 3))], n_components=1)


def test_streaming_chunk_not_frames():
    with pytest.raises(InputError, match=r"starting at frame 0 must have shape \(n_frames"):
        pca_streaming([np.ones((6, 3))], n_components=1)


def test_streaming_empty():
    with pytest.raises(InputError, match="no frame to analyse"):
        pca_streaming([], n_components=1, method="incremental")


def test_model_coverage_not_reached():
    operator, disp, _ = make_case(**CASES["signal+noise"])
    model = pca_from_operator(operator, disp, n_components=1)
    with pytest.raises(InputError, match="keep more components"):
        model.n_for_coverage(0.9999)


def test_model_bad_threshold():
    operator, disp, _ = make_case(**CASES["signal+noise"])
    with pytest.raises(InputError, match=r"threshold must be in \(0, 1\]"):
        pca_from_operator(operator, disp).n_for_coverage(1.5)


def test_model_truncate_too_many():
    operator, disp, _ = make_case(**CASES["signal+noise"])
    with pytest.raises(InputError, match="n_components must be at most 3"):
        pca_from_operator(operator, disp, n_components=3).truncate(4)


def test_model_project_shape():
    operator, disp, _ = make_case(**CASES["signal+noise"])
    with pytest.raises(InputError, match=r"frames must have shape \(T, 30, 3\)"):
        pca_from_operator(operator, disp).project(np.zeros((2, 29, 3)))


def test_model_reconstruct_shape():
    operator, disp, _ = make_case(**CASES["signal+noise"])
    with pytest.raises(InputError, match=r"coefficients must have shape \(T, 3\)"):
        pca_from_operator(operator, disp, n_components=3).reconstruct(np.zeros((2, 4)))


def test_model_construction_checks_shapes():
    with pytest.raises(InputError, match=r"components must have shape \(any, 4, 3\)"):
        PCAModel(mean=np.zeros((4, 3)), components=np.zeros((2, 5, 3)),
                 eigenvalues=np.ones(2), total_variance=2.0, n_frames=3)
