"""Quasi-eigen faces (Kim & Ko 2007, eq. 3-4 and the missing-axis post-treatment)."""

import numpy as np
import pytest
from tolerances import EXACT_FLOAT64, PCA_EXACT_RTOL, QE_COLUMN_SUMS_RTOL, QE_IN_SPAN_REL

from basis.pca import PCAModel, pca_from_operator, pca_streaming
from basis.quasi_eigen import MISSING_POLICIES, quasi_eigen
from mocap.errors import InputError

N_VERTICES, M = 40, 5


def make_pca(seed=0, n_vertices=N_VERTICES, m=M):
    """A PCA model with known orthonormal axes, built directly (independent of PCA code)."""
    rng = np.random.default_rng(seed)
    axes = np.linalg.qr(rng.normal(size=(3 * n_vertices, m)))[0].T
    return PCAModel(mean=rng.normal(size=(n_vertices, 3)), components=axes.reshape(m, -1, 3),
                    eigenvalues=np.linspace(5, 1, m), total_variance=20.0, n_frames=100)


def flat(pca):
    return pca.components.reshape(pca.n_components, -1)


def orthogonal_offset(pca, rng):
    """A random displacement orthogonal to every PCA axis."""
    v = rng.normal(size=3 * N_VERTICES)
    return (v - flat(pca).T @ (flat(pca) @ v)).reshape(N_VERTICES, 3)


def test_matches_brute_force_and_lstsq_projection():
    pca, rng = make_pca(), np.random.default_rng(1)
    artist = rng.normal(size=(4, N_VERTICES, 3))
    kept = artist.copy()
    qe = quasi_eigen(pca, artist)
    # the shapes are read where they are, never written or kept
    np.testing.assert_array_equal(artist, kept)
    assert not any(np.shares_memory(artist, getattr(qe, name)) for name in
                   ("displacements", "weights", "relative_move", "max_vertex_move"))
    for i in range(4):
        for j in range(M):
            want = np.dot(pca.components[j].ravel(), (artist[i] - pca.mean).ravel())
            assert abs(qe.weights[i, j] - want) < EXACT_FLOAT64
    # e^QE is the closest point of the affine hyperplane μ + span(E): a least-squares oracle
    coef = np.linalg.lstsq(flat(pca).T, (artist - pca.mean).reshape(4, -1).T, rcond=None)[0]
    closest = pca.mean + (flat(pca).T @ coef).T.reshape(4, N_VERTICES, 3)
    np.testing.assert_allclose(qe.displacements, closest, atol=EXACT_FLOAT64)
    # per-element moves, against a loop over vertices
    for i in range(4):
        moves = [np.linalg.norm(closest[i, v] - artist[i, v]) for v in range(N_VERTICES)]
        assert qe.max_vertex[i] == int(np.argmax(moves))
        np.testing.assert_allclose(qe.max_vertex_move[i], max(moves), rtol=PCA_EXACT_RTOL)
        np.testing.assert_allclose(qe.relative_move[i], np.sqrt(np.sum(np.square(moves)))
                                   / np.linalg.norm(artist[i]), rtol=PCA_EXACT_RTOL)


def test_shape_in_span_is_unchanged():
    pca, rng = make_pca(), np.random.default_rng(2)
    artist = pca.mean + np.einsum("ij,jvc->ivc", rng.normal(size=(3, M)), pca.components)
    qe = quasi_eigen(pca, artist)
    np.testing.assert_allclose(qe.displacements, artist, atol=EXACT_FLOAT64)
    assert qe.relative_move.max() < EXACT_FLOAT64


def test_shape_orthogonal_to_span_maps_to_mean():
    pca, rng = make_pca(), np.random.default_rng(3)
    artist = np.stack([pca.mean + orthogonal_offset(pca, rng) for _ in range(2)])
    qe = quasi_eigen(pca, artist)
    np.testing.assert_allclose(qe.displacements, np.stack([pca.mean] * 2), atol=EXACT_FLOAT64)
    np.testing.assert_allclose(qe.weights, 0, atol=EXACT_FLOAT64)


def test_span_within_mean_plus_pca_span():
    pca, rng = make_pca(), np.random.default_rng(4)
    qe = quasi_eigen(pca, rng.normal(size=(7, N_VERTICES, 3)), n_components=3)
    offsets = (qe.displacements - pca.mean).reshape(7, -1)
    kept = flat(pca)[:3]
    residual = offsets - (offsets @ kept.T) @ kept
    assert np.abs(residual).max() < EXACT_FLOAT64
    assert qe.weights.shape == (7, 3)


def constructed_missing_case():
    """Artist shapes built from axes 0, 1, 3, 4, with a faint leak (1e-4) into axis 2."""
    pca, rng = make_pca(), np.random.default_rng(5)
    coef = rng.uniform(0.5, 1.5, size=(4, M))
    coef[:, 2] = 1e-4
    artist = pca.mean + np.einsum("ij,jvc->ivc", coef, pca.components) \
        + 0.1 * orthogonal_offset(pca, rng)
    return pca, artist, coef


def test_missing_axis_detected():
    pca, artist, coef = constructed_missing_case()
    qe = quasi_eigen(pca, artist, missing_eps=0.05)
    np.testing.assert_allclose(qe.column_sums, np.abs(coef).sum(axis=0), rtol=QE_COLUMN_SUMS_RTOL)
    assert qe.missing_axes.tolist() == [2]
    assert quasi_eigen(pca, artist, missing_eps=0.0).missing_axes.tolist() == []
    # a threshold above every column sum but the largest flags all others
    big = quasi_eigen(pca, artist, missing_eps=0.999)
    assert len(big.missing_axes) == M - 1


@pytest.mark.parametrize("missing", MISSING_POLICIES)
def test_augment_or_report(missing):
    pca, artist, _ = constructed_missing_case()
    names = ("brow", "smile", "jaw", "pucker")
    qe = quasi_eigen(pca, artist, missing=missing, names=names)
    assert qe.missing_axes.tolist() == [2]
    if missing == "augment":
        assert qe.augmented and qe.names == names + ("pca_axis_02",)
        np.testing.assert_array_equal(qe.displacements[-1], pca.components[2])
    else:
        assert not qe.augmented and qe.names == names
    assert len(qe.displacements) == len(qe.names)
    np.testing.assert_allclose(qe.displacements[:4], quasi_eigen(pca, artist).displacements)


def test_training_frames_are_unchanged_with_real_pca():
    """Shapes taken from the capture itself lie on the hyperplane (paper, section 4)."""
    rng = np.random.default_rng(6)
    operator = rng.normal(size=(N_VERTICES, 6))
    disp = rng.normal(size=(50, 6, 3))
    pca = pca_from_operator(operator, disp)
    frames = np.einsum("nk,tkc->tnc", operator, disp[[3, 17, 40]])
    qe = quasi_eigen(pca, frames)
    np.testing.assert_allclose(qe.displacements, frames, atol=PCA_EXACT_RTOL)


def test_ict_expressions_in_capture_span_are_unchanged(ict_neutral_path, ict_expressions_dir):
    """Real shapes: a capture blending 4 ICT expressions; those stay, a 5th one moves."""
    import trimesh
    neutral = trimesh.load(ict_neutral_path, process=False).vertices
    shapes = np.stack([trimesh.load(ict_expressions_dir / f"{name}.obj",
                                    process=False).vertices - neutral
                       for name in ("jawOpen", "mouthSmile_L", "browInnerUp_L",
                                    "eyeBlink_R", "mouthPucker")])
    weights = np.random.default_rng(7).uniform(0, 1, size=(300, 4))
    capture = np.einsum("ti,ivc->tvc", weights, shapes[:4])
    pca = pca_streaming(capture, n_components=4, chunk_frames=100)
    qe = quasi_eigen(pca, shapes)
    assert qe.relative_move[:4].max() < QE_IN_SPAN_REL
    assert qe.relative_move[4] > 0.1
    assert qe.missing_axes.tolist() == []


# --- errors: one per message ---------------------------------------------------------

def test_not_a_pca_model():
    with pytest.raises(InputError, match="pca must be a PCAModel, got dict"):
        quasi_eigen({}, np.ones((1, N_VERTICES, 3)))


def test_artist_shape_mismatch():
    with pytest.raises(InputError, match=r"artist must have shape \(any, 40, 3\)"):
        quasi_eigen(make_pca(), np.ones((2, 39, 3)))


def test_artist_nan():
    artist = np.ones((2, N_VERTICES, 3))
    artist[1, 5, 0] = np.nan
    with pytest.raises(InputError, match=r"artist contains NaN \(first at index \(1, 5, 0\)\)"):
        quasi_eigen(make_pca(), artist)


def test_zero_artist_shape():
    artist = np.ones((2, N_VERTICES, 3))
    artist[1] = 0
    with pytest.raises(InputError, match="artist shape 'b' is all zeros"):
        quasi_eigen(make_pca(), artist, names=["a", "b"])


def test_no_artist_shape():
    with pytest.raises(InputError, match="artist has no shape"):
        quasi_eigen(make_pca(), np.ones((0, N_VERTICES, 3)))


def test_bad_missing_policy():
    with pytest.raises(InputError, match="missing must be one of"):
        quasi_eigen(make_pca(), np.ones((1, N_VERTICES, 3)), missing="drop")


@pytest.mark.parametrize("eps", [-0.1, 1.0, "0.1"])
def test_bad_missing_eps(eps):
    with pytest.raises(InputError, match=r"missing_eps must be a number in \[0, 1\)"):
        quasi_eigen(make_pca(), np.ones((1, N_VERTICES, 3)), missing_eps=eps)


def test_names_wrong_length():
    with pytest.raises(InputError, match="names must be 2 non-empty strings"):
        quasi_eigen(make_pca(), np.ones((2, N_VERTICES, 3)), names=["a"])


def test_names_not_unique():
    with pytest.raises(InputError, match="names must be unique"):
        quasi_eigen(make_pca(), np.ones((2, N_VERTICES, 3)), names=["a", "a"])


def test_augmented_name_collision():
    pca, artist, _ = constructed_missing_case()
    with pytest.raises(InputError, match="names already contain one of"):
        quasi_eigen(pca, artist, missing="augment", names=["a", "b", "c", "pca_axis_02"])


def test_too_many_components():
    with pytest.raises(InputError, match="n_components must be at most 5"):
        quasi_eigen(make_pca(), np.ones((1, N_VERTICES, 3)), n_components=6)
