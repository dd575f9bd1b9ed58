"""Numerics of PCA over frames read in chunks: chunking, exact streaming
statistics, a randomized range finder and an incremental SVD.

Every function here works on flattened frames, rows of length ``n_features``
(``3 * n_vertices``, vertex-major), and never holds more than one chunk of
frames plus the basis being built. Validation of the options is done by the
caller (:mod:`basis.pca`); the frames themselves are checked chunk by chunk
because an iterable can only be checked while it is read.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.errors import InputError


def frame_chunks(frames, name: str, chunk_frames: int, n_cols: int | None = None):
    """Yield ``(first_frame, chunk)`` with ``chunk`` of shape (t_i, n_cols), float64.

    `frames` is either an ndarray (n_frames, n, 3), cut into views of
    `chunk_frames` frames, or an iterable of arrays (t_i, n, 3) used as given.
    Each chunk is checked: same ``n`` throughout (``n_cols = 3 n`` when given),
    finite everywhere; a NaN or infinite sample raises :class:`InputError`
    naming the frame (counted from 0 over the whole sequence).
    """
    source = ((s, frames[s:s + chunk_frames]) for s in range(0, len(frames), chunk_frames)) \
        if isinstance(frames, np.ndarray) else _numbered(frames)
    for start, chunk in source:
        chunk = np.asarray(chunk, dtype=np.float64)
        if chunk.ndim != 3 or chunk.shape[2] != 3:
            raise InputError(f"{name}: the chunk starting at frame {start} must have shape "
                             f"(n_frames, n_vertices, 3), got {chunk.shape}")
        if n_cols is None:
            n_cols = 3 * chunk.shape[1]
        if 3 * chunk.shape[1] != n_cols:
            raise InputError(f"{name}: the chunk starting at frame {start} has "
                             f"{chunk.shape[1]} vertices, expected {n_cols // 3}")
        if len(chunk) == 0:
            continue
        flat = chunk.reshape(len(chunk), n_cols)
        # one cheap reduction; look for the frame only when it is not finite
        bad = ~np.isfinite(flat).all(axis=1) if not np.isfinite(np.sum(flat)) else None
        if bad is not None and bad.any():
            raise InputError(f"{name}: frame {start + int(np.argmax(bad))} has NaN or "
                             "infinite values; fill the gaps before PCA")
        yield start, flat


def _numbered(chunks):
    start = 0
    for chunk in chunks:
        yield start, chunk
        start += len(chunk)


@dataclass
class RunningMoments:
    """Frame count, mean (n_features,) and centred sum of squares, merged per
    chunk with the pairwise update of Chan, Golub & LeVeque (exact in exact
    arithmetic, no cancellation between a large mean and a small spread)."""

    n: int = 0
    mean: np.ndarray | None = None
    m2: float = 0.0

    def add(self, flat: np.ndarray) -> None:
        t = len(flat)
        mean_b = flat.mean(axis=0)
        m2_b = float(np.sum((flat - mean_b) ** 2))
        if self.n == 0:
            self.n, self.mean, self.m2 = t, mean_b, m2_b
            return
        delta = mean_b - self.mean
        total = self.n + t
        self.m2 += m2_b + float(delta @ delta) * self.n * t / total
        self.mean = self.mean + delta * (t / total)
        self.n = total


@dataclass(frozen=True)
class Spectrum:
    """What a PCA routine hands back: flattened components (m, n_features),
    covariance eigenvalues (m,), mean (n_features,), exact trace, frame count,
    how it was computed, and every eigenvalue it found (descending, the m first;
    None when it found only those)."""

    components: np.ndarray
    eigenvalues: np.ndarray
    mean: np.ndarray
    total_variance: float
    n_frames: int
    message: str
    spectrum: np.ndarray | None = None


def _orth(a: np.ndarray) -> np.ndarray:
    return np.linalg.qr(a)[0]


def randomized_pca(chunks, n_components: int, *, oversample: int, n_iter: int,
                   rng: np.random.Generator) -> Spectrum:
    """Top eigenpairs of the frame covariance by subspace iteration on chunks.

    `chunks` is a zero-argument callable returning a fresh iterator of
    ``(first_frame, flat_chunk)``. Passes over the data: one for the moments
    fused with the first product C·Ω, `n_iter` power iterations, one
    Rayleigh-Ritz pass (Halko, Martinsson & Tropp 2011, alg. 4.4 + 5.1 on the
    covariance C = X̃ᵀX̃ / T, never formed).
    """
    moments = RunningMoments()
    omega = shift = y = None
    for _, flat in chunks():
        if omega is None:
            shift = flat.mean(axis=0)
            width = min(n_components + oversample, flat.shape[1])
            omega = _orth(rng.standard_normal((flat.shape[1], width)))
            y = np.zeros_like(omega)
        moments.add(flat)
        xs = flat - shift
        y += xs.T @ (xs @ omega)
    if moments.n == 0:
        raise InputError("frames: no frame to analyse")
    _check_rank(n_components, moments.n, moments.mean.size)
    # X̃ = Xs - 1 δᵀ with δ = mean - shift, so X̃ᵀX̃Ω = XsᵀXsΩ - T δ (δᵀΩ)
    delta = moments.mean - shift
    y -= moments.n * np.outer(delta, delta @ omega)
    for _ in range(n_iter):
        q = _orth(y)
        y = np.zeros_like(q)
        for _, flat in chunks():
            xc = flat - moments.mean
            y += xc.T @ (xc @ q)
    q = _orth(y)
    gram = np.zeros((q.shape[1], q.shape[1]))
    for _, flat in chunks():
        z = (flat - moments.mean) @ q
        gram += z.T @ z
    evals, vecs = np.linalg.eigh(gram)
    order = np.argsort(evals)[::-1][:n_components]
    return Spectrum(components=(q @ vecs[:, order]).T,
                    eigenvalues=np.clip(evals[order], 0, None) / moments.n,
                    mean=moments.mean, total_variance=moments.m2 / moments.n,
                    n_frames=moments.n,
                    message=f"randomized range finder: {n_iter + 2} passes, "
                            f"{q.shape[1]} trial vectors")


def incremental_pca(chunks, n_components: int, *, oversample: int) -> Spectrum:
    """Top eigenpairs by one pass of incremental SVD with mean update.

    Each chunk B (t, n_features) updates the kept factorization by the thin
    SVD of ``[diag(s) V ; B - mean_B ; sqrt(n t / (n + t)) (mean - mean_B)]``
    (computed from its Gram matrix, see :func:`_wide_svd`)
    (Ross, Lim, Lin & Yang 2008, sequential Karhunen-Loeve with mean update);
    ``n_components + oversample`` singular pairs are kept between chunks.
    Exact when the data's rank does not exceed that number.
    """
    moments = RunningMoments()
    s = vt = None
    for _, flat in chunks():
        mean_b = flat.mean(axis=0)
        if moments.n == 0:
            stacked = flat - mean_b
        else:
            t = len(flat)
            correction = np.sqrt(moments.n * t / (moments.n + t)) * (moments.mean - mean_b)
            stacked = np.vstack([s[:, None] * vt, flat - mean_b, correction[None]])
        moments.add(flat)
        s, vt = _wide_svd(stacked, n_components + oversample)
    if moments.n == 0:
        raise InputError("frames: no frame to analyse")
    _check_rank(n_components, moments.n, moments.mean.size)
    return Spectrum(components=vt[:n_components], eigenvalues=s[:n_components] ** 2 / moments.n,
                    mean=moments.mean, total_variance=moments.m2 / moments.n,
                    n_frames=moments.n,
                    message=f"incremental SVD: 1 pass, {len(s)} pairs kept between chunks")


def _wide_svd(wide: np.ndarray, keep: int):
    """Top `keep` singular pairs (s, vt) of a wide matrix (p, n), p << n.

    LAPACK's SVD of a 500 × 28,000 matrix is ~50 times slower than its Gram
    matrix, so: eigenpairs of ``wide wideᵀ`` (p × p), ``vt = uᵀ wide / s``,
    then a QR of the kept rows restores orthonormality lost to rounding where
    s is tiny (rank-deficient data; such rows carry no variance).
    """
    evals, u = np.linalg.eigh(wide @ wide.T)
    order = np.argsort(evals)[::-1][:keep]
    s = np.sqrt(np.clip(evals[order], 0, None))
    vt = (u[:, order].T @ wide) / np.where(s > s[0] * 1e-12, s, np.inf)[:, None] \
        if s[0] > 0 else np.zeros((len(order), wide.shape[1]))
    q, r = np.linalg.qr(vt.T)
    return s, (q * np.where(np.diag(r) < 0, -1.0, 1.0)).T


def _check_rank(n_components: int, n_frames: int, n_features: int) -> None:
    if n_components > min(n_frames, n_features):
        raise InputError(f"n_components={n_components} exceeds min(n_frames, 3 * n_vertices)"
                         f" = min({n_frames}, {n_features})")
