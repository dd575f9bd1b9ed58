"""PCA of mesh displacement sequences: the model, and two ways to fit it.

:func:`pca_from_operator` is exact and never forms the mesh sequence when it
comes from a linear operator, Ξ(t) = W · D(t) (the RBF retargeting);
:func:`pca_streaming` reads any other mesh sequence in chunks, with memory
bounded by the chunk and the components. Both return a :class:`PCAModel`.

Conventions: a mesh frame of N vertices is flattened vertex-major
(x₁, y₁, z₁, x₂, ...), so a component of shape (N, 3) is a unit vector of
length 3N. The covariance is that of the paper's eq. 2, C = (1/T) Σ_t
(ξ(t) - μ)(ξ(t) - μ)ᵀ, divided by the number of frames T, not T - 1.

References
----------
Kim & Ko, "Intuitive quasi-eigen faces", GRAPHITE 2007, section 4, eq. 2.
Halko, Martinsson & Tropp, "Finding structure with randomness", SIAM Review 2011.
Ross, Lim, Lin & Yang, "Incremental learning for robust visual tracking", IJCV 2008.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
from scipy import sparse

from basis._implicit_pca import marker_moments as _moments
from basis._implicit_pca import operator_pca, orthonormal_factor, pooled_spectrum
from basis._streaming_pca import Spectrum, frame_chunks, incremental_pca, randomized_pca
from mocap.errors import InputError
from mocap.util.arrays import read_only
from mocap.util.validation import as_choice, as_float_array, as_int

__all__ = ["PCAModel", "PCA_METHODS", "MarkerMoments", "marker_moments", "pca_from_operator",
           "pca_from_operators", "pca_streaming", "pool_moments", "OperatorFactor"]

#: Methods of :func:`pca_streaming`.
PCA_METHODS = ("randomized", "incremental")

#: Extra trial vectors (randomized) or kept singular pairs (incremental).
_OVERSAMPLE = 10


@dataclass(frozen=True, eq=False)
class PCAModel:
    """Principal components of a mesh displacement sequence.

    Attributes
    ----------
    mean : ndarray, shape (N, 3), mesh units
        Mean displacement μ over the frames.
    components : ndarray, shape (m, N, 3)
        Principal axes e_j^PCA, orthonormal when flattened vertex-major,
        sorted by decreasing eigenvalue; sign-fixed so that the entry of
        largest magnitude of each component is positive (on a tie between +a
        and -a, the sign that makes it +a).
    eigenvalues : ndarray, shape (m,), mesh units²
        Covariance eigenvalues λ_j with the 1/T convention of the paper's eq. 2.
    total_variance : float, mesh units²
        Trace of the covariance over all 3N directions (Σ λ_j, j = 1..3N),
        kept even when only m components are, so that coverage is exact.
    n_frames : int
        Number of frames T analysed.
    method : str
        ``"implicit"``, ``"randomized"`` or ``"incremental"``.
    message : str
        How the model was computed.
    spectrum : ndarray, shape (K,), mesh units², optional
        Every covariance eigenvalue known (descending, K ≥ m), the kept ones first: the
        coverage of more components than were kept (:meth:`coverage_curve`), e.g. of a
        model whose components were computed only up to a coverage. None: the kept ones.
    """

    mean: np.ndarray
    components: np.ndarray
    eigenvalues: np.ndarray
    total_variance: float
    n_frames: int
    method: str = "implicit"
    message: str = ""
    spectrum: np.ndarray | None = None

    def __post_init__(self):
        mean = as_float_array(self.mean, "mean", shape=(None, 3), allow_nan=False)
        comps = as_float_array(self.components, "components", shape=(None, len(mean), 3),
                               allow_nan=False)
        evals = as_float_array(self.eigenvalues, "eigenvalues", shape=(len(comps),),
                               allow_nan=False)
        # C order whatever the solver returned (eigenvectors come transposed): a model
        # shipped to a worker (pickled: C order) then fits the same bits as here
        for name, value in (("mean", mean), ("components", comps), ("eigenvalues", evals)):
            object.__setattr__(self, name, read_only(np.ascontiguousarray(value)))
        object.__setattr__(self, "total_variance", float(self.total_variance))
        if self.spectrum is not None:
            spectrum = as_float_array(self.spectrum, "spectrum", ndim=1, allow_nan=False)
            if len(spectrum) < len(evals) or not np.array_equal(spectrum[:len(evals)], evals):
                raise InputError(f"spectrum must start with the {len(evals)} eigenvalues of "
                                 f"the components kept, got {len(spectrum)} values")
            object.__setattr__(self, "spectrum", read_only(spectrum))

    @property
    def n_components(self) -> int:
        """Number m of components kept."""
        return len(self.eigenvalues)

    def coverage(self) -> np.ndarray:
        """Cumulative coverage Σ_{j≤k} λ_j / Σ_{j≤3N} λ_j for k = 1..m, shape (m,)."""
        if self.total_variance <= 0:
            return np.ones(self.n_components)
        return np.cumsum(self.eigenvalues) / self.total_variance

    def coverage_curve(self) -> np.ndarray:
        """Cumulative coverage of every component whose eigenvalue is known (:attr:`spectrum`,
        else the m kept), shape (K,): what keeping more components than m would cover."""
        if self.spectrum is None:
            return self.coverage()
        if self.total_variance <= 0:
            return np.ones(len(self.spectrum))
        return np.cumsum(self.spectrum) / self.total_variance

    def n_for_coverage(self, threshold: float = 0.995) -> int:
        """Smallest number of components whose coverage reaches `threshold` (0, 1].

        Raises
        ------
        InputError
            If the kept components do not reach it (fit with more components).
        """
        if not 0 < threshold <= 1:
            raise InputError(f"threshold must be in (0, 1], got {threshold}")
        cov = self.coverage()
        reached = np.nonzero(cov >= threshold * (1 - 1e-12))[0]
        if len(reached) == 0:
            raise InputError(f"the {self.n_components} components kept cover "
                             f"{cov[-1]:.6f} < {threshold}; keep more components")
        return int(reached[0]) + 1

    def shapes(self) -> tuple[tuple, np.ndarray]:
        """The model as an expression basis: the mean, then each axis scaled to one SD.

        ``v = neutral + 1·μ + Σ_j w_j √λ_j e_j``: a weight is a coefficient in
        standard deviations of the frames the model was fitted to (most of
        them within ±3), the mean's weight is 1.

        Returns
        -------
        names : tuple of str, length m + 1
            ``"pca_mean"``, then ``"pc_00"``, ``"pc_01"``, ...
        displacements : ndarray, shape (m + 1, N, 3), mesh units

        Examples
        --------
        >>> model = PCAModel(np.zeros((1, 3)), np.eye(3)[:2, None], [4.0, 1.0], 5.0, 10)
        >>> names, shapes = model.shapes()
        >>> names, shapes[1:, 0].tolist()
        (('pca_mean', 'pc_00', 'pc_01'), [[2.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        """
        sd = np.sqrt(np.maximum(self.eigenvalues, 0.0))
        names = ("pca_mean",) + tuple(f"pc_{j:02d}" for j in range(self.n_components))
        return names, np.concatenate([self.mean[None], self.components * sd[:, None, None]])

    def truncate(self, n_components: int) -> "PCAModel":
        """The model with its first `n_components` components (same total variance; the
        eigenvalues of the others kept in :attr:`spectrum`)."""
        n_components = as_int(n_components, "n_components", minimum=1)
        if n_components > self.n_components:
            raise InputError(f"n_components must be at most {self.n_components}, "
                             f"got {n_components}")
        return PCAModel(mean=self.mean, components=self.components[:n_components],
                        eigenvalues=self.eigenvalues[:n_components],
                        total_variance=self.total_variance, n_frames=self.n_frames,
                        method=self.method, message=self.message,
                        spectrum=self.eigenvalues if self.spectrum is None else self.spectrum)

    def sha256(self) -> str:
        """SHA-256 (hex) of the model's numbers: two takes fitted in one basis share it.

        Hashes the mean, the components and the eigenvalues as float64
        (little-endian, C order), so any change to the basis changes it.
        """
        digest = hashlib.sha256()
        for array in (self.mean, self.components, self.eigenvalues):
            digest.update(np.ascontiguousarray(array, dtype="<f8").tobytes())
        return digest.hexdigest()

    def project(self, frames) -> np.ndarray:
        """PCA coefficients ⟨ξ(t) - μ, e_j⟩ of mesh frames.

        Parameters
        ----------
        frames : array_like, shape (T, N, 3) or (N, 3), mesh units
            Displacements; NaN is rejected (InputError).

        Returns
        -------
        ndarray, shape (T, m) or (m,)
        """
        frames = as_float_array(frames, "frames", allow_nan=False)
        if frames.shape[-2:] != self.mean.shape or frames.ndim not in (2, 3):
            raise InputError(f"frames must have shape (T, {len(self.mean)}, 3) or "
                             f"({len(self.mean)}, 3), got {frames.shape}")
        centred = (frames - self.mean).reshape(*frames.shape[:-2], -1)
        return centred @ self.components.reshape(self.n_components, -1).T

    def reconstruct(self, coefficients) -> np.ndarray:
        """Mesh frames μ + Σ_j c_j e_j from coefficients (T, m) or (m,) -> (T, N, 3) or (N, 3)."""
        coefficients = as_float_array(coefficients, "coefficients", allow_nan=False)
        if coefficients.ndim not in (1, 2) or coefficients.shape[-1] != self.n_components:
            raise InputError(f"coefficients must have shape (T, {self.n_components}) or "
                             f"({self.n_components},), got {coefficients.shape}")
        flat = coefficients @ self.components.reshape(self.n_components, -1)
        return flat.reshape(*coefficients.shape[:-1], *self.mean.shape) + self.mean


def _model(spec: Spectrum, method: str) -> PCAModel:
    comps = spec.components
    # svd_flip-like: the entry of largest magnitude of each component is positive
    comps *= np.where(comps.max(axis=1) >= -comps.min(axis=1), 1.0, -1.0)[:, None]
    return PCAModel(mean=spec.mean.reshape(-1, 3), components=comps.reshape(len(comps), -1, 3),
                    eigenvalues=spec.eigenvalues, total_variance=spec.total_variance,
                    n_frames=spec.n_frames, method=method, message=spec.message,
                    spectrum=spec.spectrum)


def pca_from_operator(operator, displacements, *, n_components: int | None = None) -> PCAModel:
    """Exact PCA of the mesh sequence Ξ(t) = W · D(t), without forming Ξ.

    Parameters
    ----------
    operator : array_like or scipy sparse matrix, shape (N, M)
        Linear map W from marker displacements to vertex displacements, applied
        to x, y and z alike (e.g. ``build_rbf_operator(...).matrix``); a sparse
        W is densified (N × M floats).
    displacements : array_like, shape (T, M, 3), marker units
        Marker displacements D(t). Not copied when already float64; NaN or
        infinite samples are rejected (fill gaps first).
    n_components : int, optional
        Components to keep, at most 3·min(N, M). Default: every component
        above the numerical-rank cutoff λ > λ₁ · 3 min(N, M) · ε.

    Returns
    -------
    PCAModel
        Mean W·mean(D) (N, 3), components (m, N, 3), eigenvalues (1/T), exact
        total variance.

    Raises
    ------
    InputError
        On shape mismatch, a non-finite operator, or a frame with NaN (named).

    Notes
    -----
    C_Ξ = (W⊗I₃) C_D (W⊗I₃)ᵀ; with W = QR, the eigenpairs come from the
    3k × 3k matrix (R⊗I₃) C_D (R⊗I₃)ᵀ, lifted by Q⊗I₃ (k = min(N, M)).
    This is exact, not an approximation; cost O(T M² + N M²) (the T M²
    term one GEMM of the centred marker frames), memory O(N M + T M). See
    :mod:`basis._implicit_pca`.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> model = pca_from_operator(rng.normal(size=(50, 4)), rng.normal(size=(30, 4, 3)))
    >>> model.components.shape, model.mean.shape
    ((12, 50, 3), (50, 3))
    """
    if sparse.issparse(operator):
        operator = operator.toarray()
    operator = as_float_array(operator, "operator", ndim=2, allow_nan=False)
    if not operator.any():
        raise InputError(f"operator {operator.shape} is all zeros: no mesh motion to analyse")
    displacements = np.asarray(displacements, dtype=np.float64)
    if displacements.ndim != 3 or displacements.shape[1:] != (operator.shape[1], 3):
        raise InputError(f"displacements must have shape (T, {operator.shape[1]}, 3) to "
                         f"match operator {operator.shape}, got {displacements.shape}")
    if len(displacements) == 0:
        raise InputError("displacements has no frame")
    if n_components is not None:
        n_components = as_int(n_components, "n_components", minimum=1)
        most = 3 * min(operator.shape)
        if n_components > most:
            raise InputError(f"n_components must be at most 3 * min(N, M) = {most}, "
                             f"got {n_components}")
    return _model(operator_pca(operator, displacements, n_components=n_components), "implicit")


@dataclass(frozen=True, eq=False)
class MarkerMoments:
    """Mean and covariance of a take's marker displacements: all its PCA needs of D(t).

    Attributes
    ----------
    n_frames : int
        T.
    mean : ndarray, shape (M, 3), marker units
    covariance : ndarray, shape (3M, 3M), marker units²
        C_D with the 1/T convention, markers flattened vertex-major.
    """

    n_frames: int
    mean: np.ndarray
    covariance: np.ndarray

    def __post_init__(self):
        n_frames = as_int(self.n_frames, "n_frames", minimum=1)
        mean = as_float_array(self.mean, "mean", shape=(None, 3), allow_nan=False)
        cov = as_float_array(self.covariance, "covariance",
                             shape=(3 * len(mean), 3 * len(mean)), allow_nan=False)
        object.__setattr__(self, "n_frames", n_frames)
        object.__setattr__(self, "mean", read_only(mean))
        object.__setattr__(self, "covariance", read_only(cov))

    @property
    def n_markers(self) -> int:
        """M."""
        return len(self.mean)


def marker_moments(displacements) -> MarkerMoments:
    """The :class:`MarkerMoments` of marker displacements D(t), (T, M, 3), marker units.

    Raises
    ------
    InputError
        Not (T, M, 3) with T ≥ 1, or a frame with NaN (named).

    Examples
    --------
    >>> d = np.arange(12.0).reshape(2, 2, 3)
    >>> moments = marker_moments(d)
    >>> moments.mean.tolist(), float(moments.covariance[0, 0])
    ([[3.0, 4.0, 5.0], [6.0, 7.0, 8.0]], 9.0)
    """
    displacements = np.asarray(displacements, dtype=np.float64)
    if displacements.ndim != 3 or displacements.shape[2] != 3 or len(displacements) == 0:
        raise InputError(f"displacements must have shape (T, M, 3) with T >= 1, got "
                         f"{displacements.shape}")
    mean, cov = _moments(displacements)
    return MarkerMoments(len(displacements), mean, cov)


def pool_moments(moments) -> MarkerMoments:
    """The :class:`MarkerMoments` of the frames of several sets of the same markers pooled.

    ``T = Σ T_k``, ``d̄ = Σ T_k d̄_k / T`` and ``C = Σ (T_k / T) [C_k + (d̄_k − d̄)(d̄_k − d̄)ᵀ]``
    (Chan, Golub & LeVeque's pairwise update, all sets at once): the moments of the
    concatenated frames, without the cancellation of sums of squares about zero.

    Raises
    ------
    InputError
        No moments, or moments of different marker counts.

    Examples
    --------
    >>> d = np.arange(18.0).reshape(3, 2, 3)
    >>> pooled = pool_moments([marker_moments(d[:1]), marker_moments(d[1:])])
    >>> bool(np.allclose(pooled.covariance, marker_moments(d).covariance))
    True
    """
    moments = list(moments)
    if not moments:
        raise InputError("no moments to pool")
    sizes = {m.n_markers for m in moments}
    if len(sizes) > 1:
        raise InputError(f"moments of different marker counts {sorted(sizes)} do not pool")
    counts = np.array([m.n_frames for m in moments], dtype=np.float64)
    shares = counts / counts.sum()
    means = np.stack([m.mean.ravel() for m in moments])                 # (K, 3M)
    mean = shares @ means
    spread = means - mean
    cov = np.tensordot(shares, np.stack([m.covariance for m in moments]), axes=1)
    cov += (spread.T * shares) @ spread
    return MarkerMoments(int(counts.sum()), mean.reshape(-1, 3), cov)


def _dense_operator(operator, index: int) -> np.ndarray:
    """Take `index`'s operator (array_like or sparse, (N, M)) as a dense float64 array,
    checked (no NaN or infinity; named ``operators[index]``)."""
    if sparse.issparse(operator):
        operator = operator.toarray()
    return as_float_array(operator, f"operators[{index}]", ndim=2, allow_nan=False)


@dataclass(frozen=True, eq=False)
class OperatorFactor:
    """The operators of takes side by side, ``[W_1 … W_K] = Q R``: Q (N, k) with orthonormal
    columns, R (k, Σ M_k), k their numerical rank (:mod:`basis._implicit_pca`).

    What :func:`pca_from_operators` makes of the operators before it reads any frame;
    made once with :meth:`of`, it serves several PCAs of the same operators (each of other
    frames).
    """

    q: np.ndarray
    r: np.ndarray

    @classmethod
    def of(cls, operators) -> OperatorFactor:
        """The factor of `operators` (sequence of array_like or sparse, each (N, M_k))."""
        dense = [_dense_operator(op, i) for i, op in enumerate(operators)]
        if not dense or len({op.shape[0] for op in dense}) > 1:
            raise InputError("operators must be one or more of one mesh (the same rows)")
        q, r = orthonormal_factor(np.concatenate(dense, axis=1))
        return cls(read_only(q), read_only(r))


def pca_from_operators(operators, displacements, *, n_components: int | None = None,
                       coverage: float | None = None,
                       factor: OperatorFactor | None = None) -> PCAModel:
    """Exact PCA of the mesh sequences of several takes pooled, Ξ_k(t) = W_k · D_k(t).

    The PCA of a session: every frame of every take counts once, each take
    through its own operator (its own binding), and the mesh sequences are
    never formed.

    Parameters
    ----------
    operators : sequence of array_like or sparse, each (N, M_k)
        One operator per take, on one mesh (same N).
    displacements : sequence of array_like (T_k, M_k, 3) or MarkerMoments
        Each take's marker displacements, or their :func:`marker_moments`
        (what a worker computing a take can send back instead of D).
    n_components : int, optional
        Components to keep; default every component above the numerical-rank
        cutoff (as :func:`pca_from_operator`).
    coverage : float in (0, 1], optional
        Instead of `n_components`: keep the fewest components whose coverage
        (:meth:`PCAModel.coverage`) reaches it; only those are computed on
        the mesh, the costly part for a long session.
    factor : OperatorFactor, optional
        :meth:`OperatorFactor.of` these operators, for several PCAs of them (the
        held-out folds of a take): its products with the mesh, the costly part on a
        dense mesh, are made once. Default: made here.

    Returns
    -------
    PCAModel
        Of the concatenated sequences: mean Σ_k (T_k/T) W_k d̄_k, covariance
        with the 1/T convention over all T = Σ T_k frames, exact total variance.

    Raises
    ------
    InputError
        No take, operators and displacements of different counts, operators of
        different meshes, a shape mismatch (the take is named by its index),
        a non-finite operator, a frame with NaN, both `n_components` and
        `coverage`, a coverage outside (0, 1].

    Notes
    -----
    The pooled covariance is Σ_k (T_k/T) [K_k C_k K_kᵀ + (μ_k − μ)(μ_k − μ)ᵀ]
    (K_k = W_k ⊗ I₃, μ_k the take's mean mesh displacement): the takes'
    covariances plus the scatter of their means. Its eigenpairs come from a
    3r × 3r problem, r = rank [W_1 … W_K] ≤ min(N, Σ M_k); cost
    O(N (Σ M_k)² + (3r)³). See :mod:`basis._implicit_pca`.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> ops = [rng.normal(size=(50, 4)), rng.normal(size=(50, 4))]
    >>> takes = [rng.normal(size=(30, 4, 3)), rng.normal(size=(20, 4, 3))]
    >>> model = pca_from_operators(ops, takes)
    >>> model.n_frames, model.components.shape
    (50, (24, 50, 3))
    """
    operators, displacements = list(operators), list(displacements)
    if not operators:
        raise InputError("operators is empty: give one operator per take")
    if len(operators) != len(displacements):
        raise InputError(f"{len(operators)} operators but {len(displacements)} takes of "
                         "displacements: give one of each per take")
    dense, moments = [], []
    for i, (operator, data) in enumerate(zip(operators, displacements)):
        operator = _dense_operator(operator, i)
        if operator.shape[0] != (dense[0].shape[0] if dense else operator.shape[0]):
            raise InputError(f"operators[{i}] has {operator.shape[0]} rows (vertices), "
                             f"operators[0] {dense[0].shape[0]}: the takes must share a mesh")
        if not isinstance(data, MarkerMoments):
            data = marker_moments(data)
        if data.n_markers != operator.shape[1]:
            raise InputError(f"take {i}: operator {operator.shape} maps {operator.shape[1]} "
                             f"markers but its displacements have {data.n_markers}")
        dense.append(operator)
        moments.append((data.n_frames, np.asarray(data.mean), np.asarray(data.covariance)))
    if not any(op.any() for op in dense):
        raise InputError("every operator is all zeros: no mesh motion to analyse")
    if n_components is not None:
        n_components = as_int(n_components, "n_components", minimum=1)
    if coverage is not None:
        if n_components is not None:
            raise InputError("give n_components or coverage, not both")
        if isinstance(coverage, bool) or not 0 < coverage <= 1:
            raise InputError(f"coverage must be in (0, 1], got {coverage!r}")
    if factor is not None and (len(factor.q) != len(dense[0])
                               or factor.r.shape[1] != sum(op.shape[1] for op in dense)):
        raise InputError(f"factor is of operators of {len(factor.q)} vertices and "
                         f"{factor.r.shape[1]} markers, these have {len(dense[0])} and "
                         f"{sum(op.shape[1] for op in dense)}")
    return _model(pooled_spectrum(dense, moments, n_components=n_components,
                                  coverage=coverage,
                                  factor=None if factor is None else (factor.q, factor.r)),
                  "implicit")


def pca_streaming(frames, *, n_components: int, chunk_frames: int = 512,
                  method: str = "randomized", n_iter: int = 2, rng=None) -> PCAModel:
    """PCA of a mesh sequence read in chunks, memory bounded by chunk and components.

    Parameters
    ----------
    frames : ndarray (T, N, 3), or iterable of arrays (t_i, N, 3), mesh units
        Displacements. An array (a ``np.memmap`` too) is read in views of
        `chunk_frames` frames, each converted to float64 on its own; an
        iterable's chunks are used as given. ``"randomized"`` reads the data
        ``n_iter + 2`` times, so the iterable must start over when iterated
        again (a list, or an object whose ``__iter__`` reopens the source); a
        one-shot iterator or generator is rejected, use ``"incremental"``.
        NaN or infinite samples are rejected, naming the frame.
    n_components : int
        Components m to compute, at most min(T, 3N).
    chunk_frames : int
        Frames per chunk for an array input. For ``"incremental"`` the cost
        per frame grows with the chunk (an SVD of (m + 10 + chunk) × 3N).
    method : {"randomized", "incremental"}
        Randomized subspace iteration on the covariance (Halko et al.) or a
        one-pass incremental SVD with mean update (Ross et al.); see
        :data:`PCA_METHODS`.
    n_iter : int
        Power iterations of ``"randomized"`` (ignored by ``"incremental"``).
    rng : None, int or numpy.random.Generator
        Seed of the randomized range finder; None means seed 0 (reproducible).

    Returns
    -------
    PCAModel
        ``total_variance`` is exact (streaming centred sum of squares) for both
        methods; eigenvalues and components are approximations whose accuracy
        depends on the gap after λ_m: exact to rounding when the data rank is
        at most m + 10.

    Raises
    ------
    InputError
        Bad option, inconsistent chunks, a non-finite frame, a one-shot
        iterator with ``"randomized"``, or n_components > min(T, 3N).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> frames = rng.normal(size=(40, 20, 3))
    >>> pca_streaming(frames, n_components=5, chunk_frames=16).eigenvalues.shape
    (5,)
    """
    n_components = as_int(n_components, "n_components", minimum=1)
    chunk_frames = as_int(chunk_frames, "chunk_frames", minimum=1)
    n_iter = as_int(n_iter, "n_iter", minimum=0)
    method = as_choice(method, "method", PCA_METHODS)
    if isinstance(frames, np.ndarray):
        if frames.ndim != 3 or frames.shape[2] != 3:
            raise InputError(f"frames must have shape (T, N, 3), got {frames.shape}")
    elif not hasattr(frames, "__iter__"):
        raise InputError("frames must be an array (T, N, 3) or an iterable of chunks "
                         f"(t_i, N, 3), got {type(frames).__name__}")
    elif method == "randomized" and iter(frames) is frames:
        raise InputError("frames is a one-shot iterator but method='randomized' reads the "
                         "data several times: pass a list of chunks or use "
                         "method='incremental'")

    def chunks():
        return frame_chunks(frames, "frames", chunk_frames)

    if method == "randomized":
        spec = randomized_pca(chunks, n_components, oversample=_OVERSAMPLE, n_iter=n_iter,
                              rng=np.random.default_rng(0 if rng is None else rng))
    else:
        spec = incremental_pca(chunks, n_components, oversample=_OVERSAMPLE)
    return _model(spec, method)
