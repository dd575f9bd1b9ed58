"""Numerics of the PCA of Ξ(t) = W · D(t) without forming Ξ.

Flatten a mesh frame vertex-major, ``ξ = [x_1, y_1, z_1, x_2, ...]`` (3N), and
a marker frame the same way, ``d`` (3M). The same W acts on x, y and z, so
``ξ = K d`` with ``K = W ⊗ I₃``. The covariance of the mesh frames is then

    C_Ξ = K C_D Kᵀ,     C_D = (1/T) Σ_t (d(t) - d̄)(d(t) - d̄)ᵀ   (3M × 3M).

With ``W = Q R`` (Q: N × k orthonormal, R: k × M, k = rank W ≤ min(N, M)),
``K = (Q ⊗ I₃)(R ⊗ I₃)`` and ``Q ⊗ I₃`` has orthonormal columns, so the
nonzero eigenpairs of C_Ξ are those of the 3k × 3k matrix
``S = (R ⊗ I₃) C_D (R ⊗ I₃)ᵀ`` with eigenvectors lifted by ``Q ⊗ I₃``; and
``trace C_Ξ = trace S`` exactly. Both Kronecker products are applied as
tensor contractions over the marker/vertex axis, never formed.

Several takes, each through its own operator, ``ξ_k(t) = (W_k ⊗ I₃) d_k(t)``
(one binding per take, so one W_k per take): with ``[W_1 … W_K] = Q [R_1 … R_K]``
every take lives in the span of the one Q, and the covariance of all the
frames pooled (T = Σ T_k, weights w_k = T_k / T) is, in Q's coordinates,

    S = Σ_k w_k [(R_k ⊗ I₃) C_k (R_k ⊗ I₃)ᵀ + (a_k − ā)(a_k − ā)ᵀ],
    a_k = (R_k ⊗ I₃) d̄_k,   ā = Σ_k w_k a_k,

the within-take covariances plus the scatter of the take means: exactly the
covariance of the concatenated mesh sequences, of size 3r × 3r with
r = rank [W_1 … W_K] ≤ min(N, Σ M_k). One take is the case K = 1.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import solve_triangular

from basis._streaming_pca import Spectrum, frame_chunks
from mocap.errors import InputError


def marker_moments(displacements: np.ndarray):
    """Mean (M, 3) and covariance C_D (3M, 3M) of marker frames, 1/T convention.

    One float64 GEMM of the centred frames (T, 3M) with themselves (a symmetric
    rank-T update); the centred copy is the only temporary. A non-finite frame
    raises InputError naming it.
    """
    n_frames, n_markers, _ = displacements.shape
    _, flat = next(frame_chunks(displacements, "displacements", n_frames))
    mean = flat.mean(axis=0)
    centred = flat - mean
    cov = centred.T @ centred
    cov /= n_frames
    return mean.reshape(n_markers, 3), cov


def orthonormal_factor(operator: np.ndarray):
    """W = Q R with Q (N, k) orthonormal columns and R (k, M), k = numerical rank of W.

    CholeskyQR2 started from an eigendecomposition: WᵀW = V Σ² Vᵀ, drop the
    directions with σ² ≤ σ₁² M ε (their share of any variance is below
    M ε), Q₁ = W V Σ⁻¹, then one Cholesky re-orthonormalization Q₁ = Q R₂.
    Level-3 BLAS only: ~20 times faster than Householder QR for a tall thin
    W (9,409 × 66). W = Q₁ Σ Vᵀ holds to rounding whatever the error in Σ,
    and Q₁ is orthogonal to ~ε cond(W)², which the Cholesky step removes
    while that is below ~1e-2: accurate up to cond(W) ~ 1e7 (tested at 1e6;
    an RBF operator on the ICT face has cond(W) ~ 24).
    """
    evals, vecs = np.linalg.eigh(operator.T @ operator)
    keep = evals > evals[-1] * operator.shape[1] * np.finfo(np.float64).eps
    sigma, vecs = np.sqrt(evals[keep]), vecs[:, keep]
    q1 = operator @ (vecs / sigma)
    r2 = np.linalg.cholesky(q1.T @ q1).T
    q = solve_triangular(r2, q1.T, trans="T").T
    return q, (r2 * sigma) @ vecs.T


def operator_pca(operator: np.ndarray, displacements: np.ndarray, *,
                 n_components: int | None) -> Spectrum:
    """Exact PCA of W · D(t) from the marker covariance; see the module notes.

    `n_components` None keeps every component above the numerical-rank cutoff
    λ > λ₁ · 3k · ε (ε: float64 machine epsilon); at most 3k exist.
    """
    mean_d, cov_d = marker_moments(displacements)
    return pooled_spectrum([operator], [(displacements.shape[0], mean_d, cov_d)],
                           n_components=n_components)


def pooled_spectrum(operators, moments, *, n_components: int | None,
                    coverage: float | None = None, factor=None) -> Spectrum:
    """Exact PCA of the pooled mesh sequences of several takes; see the module notes.

    Parameters
    ----------
    operators : sequence of ndarray (N, M_k)
    moments : sequence of (n_frames T_k, mean (M_k, 3), covariance (3M_k, 3M_k))
        Each take's marker moments (:func:`marker_moments`), 1/T_k convention.
    n_components : int or None
        As :func:`operator_pca`; at most 3r exist.
    coverage : float in (0, 1], optional
        Instead of `n_components`: the fewest components whose share of the
        total variance reaches it (only those are lifted to the mesh).
    factor : (Q, R), optional
        :func:`orthonormal_factor` of the operators side by side, when it is known
        already (several PCAs of the same operators); default computed here.
    """
    counts = np.array([m[0] for m in moments], dtype=np.float64)
    n_frames = int(counts.sum())
    shares = counts / counts.sum()
    q, r = orthonormal_factor(np.concatenate(operators, axis=1)) if factor is None else factor
    k = r.shape[0]
    small = np.zeros((k, 3, k, 3))
    centres = np.empty((len(operators), k, 3))
    mean = np.zeros((operators[0].shape[0], 3))
    offset = 0
    for i, (operator, (_, mean_d, cov_d)) in enumerate(zip(operators, moments)):
        n_markers = operator.shape[1]
        r_k = r[:, offset:offset + n_markers]
        offset += n_markers
        cov4 = cov_d.reshape(n_markers, 3, n_markers, 3)
        # S[a,c,b,e] += w Σ_{k,l} R[a,k] C[k,c,l,e] R[b,l]
        small += shares[i] * np.tensordot(np.tensordot(r_k, cov4, axes=(1, 0)), r_k,
                                          axes=(2, 1)).transpose(0, 1, 3, 2)
        centres[i] = r_k @ mean_d
        mean += shares[i] * (operator @ mean_d)
    spread = (centres - np.tensordot(shares, centres, axes=1)).reshape(len(operators), -1)
    small = small.reshape(3 * k, 3 * k) + (spread.T * shares) @ spread
    small = (small + small.T) / 2
    evals, vecs = np.linalg.eigh(small)
    evals, vecs = np.clip(evals[::-1], 0, None), vecs[:, ::-1]
    if coverage is not None:
        share = np.cumsum(evals) / max(float(np.trace(small)), np.finfo(np.float64).tiny)
        n_components = int(np.searchsorted(share, coverage * (1 - 1e-12))) + 1
        n_components = min(n_components, 3 * k)
    elif n_components is None:
        cutoff = evals[0] * 3 * k * np.finfo(np.float64).eps
        n_components = max(int(np.count_nonzero(evals > cutoff)), 1)
    elif n_components > 3 * k:
        what = "the operators of the takes have" if len(operators) > 1 else "operator has"
        raise InputError(f"{what} numerical rank {k}: at most {3 * k} components "
                         f"exist, got n_components={n_components}")
    vecs = vecs[:, :n_components].reshape(k, 3, n_components)
    # lift by Q ⊗ I₃: component[m, n, c] = Σ_a Q[n, a] V[a, c, m], one GEMM per axis c
    # written into C order (m, N, 3): a transposed result would cost every later pass
    # over the components (sign fix, validation, copies) a strided walk
    components = np.empty((n_components, len(q), 3))
    for axis in range(3):
        components[:, :, axis] = vecs[:, axis].T @ q.T
    takes = f" of {len(operators)} takes" if len(operators) > 1 else ""
    return Spectrum(components=components.reshape(n_components, -1),
                    eigenvalues=evals[:n_components], mean=mean.ravel(),
                    total_variance=float(np.trace(small)), n_frames=n_frames,
                    message=f"implicit: eigenproblem of size {3 * k} from "
                            f"{n_frames} marker frames{takes}", spectrum=evals)
