"""One PCA and quasi-eigen basis for every take of a session (``[basis] scope = "session"``).

Why: each take has its own binding, hence its own RBF operator W_k, and its
own PCA; the weights of two takes in their own bases cannot be compared. The
session basis is the exact PCA of the mesh sequences of all the takes
pooled, Ξ_k(t) = W_k · D_k(t), each take through its own operator (the mesh
motion each take's own chain computes), every frame counted once:

    C = Σ_k (T_k / T) [K_k C_k K_kᵀ + (μ_k − μ)(μ_k − μ)ᵀ],   K_k = W_k ⊗ I₃,

the takes' covariances plus the scatter of their mean meshes
(:func:`basis.pca.pca_from_operators`; no mesh sequence is formed). A common
"session binding" was the alternative; it would fit every take with a
binding made on another take's neutral, which the per-take binding exists to
avoid. The quasi-eigen faces follow from the shared PCA
(:func:`basis.quasi_eigen.quasi_eigen`), so they are shared too.

How: before any take is fitted, each take goes through ingest, bind and
retarget (:func:`take_moments`, in worker processes) and sends back only its
operator (N × M) and its marker moments (a 3M × 3M covariance), never its
frames; :func:`session_basis` pools them. The result, a :class:`SessionBasis`,
is a plain picklable object handed to the work of each take
(:func:`fit.pipeline.session.process_take`). The takes are then run as
usual, each fitting H, QE and PCA in the shared bases; the manifest records
the session basis (:meth:`SessionBasis.record`) and each take the SHA-256 of
the PCA it was fitted in.
"""

from __future__ import annotations

import hashlib
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from basis.pca import MarkerMoments, PCAModel, marker_moments, pca_from_operators
from fit.pipeline.config import RunConfig
from fit.pipeline.executors import LocalExecutor
from fit.pipeline.kept_takes import keep_prepared
from fit.pipeline.options import BasisOptions
from fit.pipeline.reconstruction import Reconstruction
from fit.pipeline.take_warnings import recorded_warnings
from mocap.errors import InputError, Mocap2MeshError

__all__ = ["TakeMoments", "SessionBasis", "take_moments", "session_basis",
           "uses_session_basis", "session_input", "build_session_basis"]


@dataclass(frozen=True, eq=False)
class TakeMoments:
    """What the session PCA needs of one take.

    Attributes
    ----------
    name : str
        The take (its capture's file stem).
    operator : ndarray, shape (N, M)
        Its RBF operator W_k (from its own binding).
    moments : MarkerMoments
        Mean and covariance of its face-marker displacements D_k (mesh units).
    """

    name: str
    operator: np.ndarray
    moments: MarkerMoments


@dataclass(frozen=True, eq=False)
class SessionBasis:
    """The PCA shared by the takes of a session.

    Attributes
    ----------
    pca : PCAModel
        The pooled PCA, cut to the m components the bases use (the basis
        options' ``pca_components`` or coverage), with the exact total
        variance: every take derives the same PCA and quasi-eigen bases from it.
    takes : tuple of str
        The takes pooled, in the run's order.
    frames : tuple of int
        Frames each take contributed (after ingestion and trimming).
    seconds : float
        Wall time of the pooling and eigenproblem (not of the takes' stages).
    """

    pca: PCAModel
    takes: tuple
    frames: tuple
    seconds: float = 0.0

    @property
    def sha256(self) -> str:
        """:meth:`basis.pca.PCAModel.sha256` of :attr:`pca`: the id each take's record names."""
        return self.pca.sha256()

    def record(self) -> dict:
        """What the manifest records of it (plain JSON data)."""
        coverage = self.pca.coverage()
        return {"scope": "session", "takes": dict(zip(self.takes, self.frames)),
                "n_frames": int(sum(self.frames)), "n_components": self.pca.n_components,
                "coverage": float(coverage[-1]), "total_variance": self.pca.total_variance,
                "eigenvalues": self.pca.eigenvalues.tolist(), "message": self.pca.message,
                "sha256": self.sha256, "seconds": round(self.seconds, 3)}


def take_moments(capture, reconstruction: Reconstruction, *, keep=None) -> TakeMoments:
    """One take through ingest, bind and retarget; its operator and marker moments.

    The take's warnings are not passed on: its run raises them when it is
    fitted. With `keep` (a file in a folder of kept takes), the prepared take
    and its warnings are kept there for that run (:func:`fit.pipeline.kept_takes.keep_prepared`).

    Raises
    ------
    Mocap2MeshError
        Any stage's error (:meth:`Reconstruction.prepare`).
    """
    with recorded_warnings() as caught:
        prepared = reconstruction.prepare(capture)
    if keep is not None:
        keep_prepared(prepared, caught, keep)
    retargeted = prepared.retargeted
    return TakeMoments(prepared.name, np.asarray(retargeted.operator.matrix, dtype=np.float64),
                       marker_moments(retargeted.displacements))


def session_basis(takes, options: BasisOptions = BasisOptions()) -> SessionBasis:
    """The shared PCA of takes, from their :class:`TakeMoments` (see the module notes).

    Parameters
    ----------
    takes : sequence of TakeMoments
        In the order they are pooled (the run's order: the result does not
        depend on it beyond rounding).
    options : BasisOptions
        ``pca_components`` or ``pca_coverage`` choose the m components kept.

    Returns
    -------
    SessionBasis

    Raises
    ------
    InputError
        No take, takes on different meshes or marker sets, or more
        ``pca_components`` than the pooled sequences have.
    """
    takes = list(takes)
    if not takes:
        raise InputError("a session basis needs at least one take")
    tic = time.perf_counter()
    markers = {t.moments.n_markers for t in takes}
    if len(markers) > 1:
        raise InputError(f"the takes have different numbers of face markers {sorted(markers)}: "
                         "a session shares one marker set")
    m = options.pca_components
    most = 3 * min(len(takes[0].operator), sum(t.moments.n_markers for t in takes))
    if m is not None and m > most:
        raise InputError(f"basis.pca_components = {m} is more than the {most} components "
                         f"the session's mesh sequences can have ({len(takes)} takes)")
    pca = pca_from_operators([t.operator for t in takes], [t.moments for t in takes],
                             n_components=m, coverage=None if m else options.pca_coverage)
    return SessionBasis(pca=pca, takes=tuple(t.name for t in takes),
                        frames=tuple(t.moments.n_frames for t in takes),
                        seconds=time.perf_counter() - tic)


def uses_session_basis(config: RunConfig) -> bool:
    """Whether a run shares one basis across its takes: scope "session" and several takes."""
    return config.basis_options.scope == "session" and len(config.captures) > 1


def session_input(digests) -> dict:
    """The manifest input a session basis adds to every take's key.

    Parameters
    ----------
    digests : mapping of Path to str
        Each capture of the run and its SHA-256, in the run's order.

    Returns
    -------
    dict
        ``{"takes": [stems], "sha256": hash of the captures' hashes}``: a take
        fitted in the session basis depends on every capture of the session,
        so adding, removing or changing one re-runs them all.
    """
    lines = "\n".join(f"{Path(path).stem}:{digest}" for path, digest in digests.items())
    return {"takes": [Path(path).stem for path in digests],
            "sha256": hashlib.sha256(lines.encode()).hexdigest()}


@dataclass(frozen=True)
class _PrepareJob:
    """One capture to prepare for the session basis, and where to keep it (or None)."""

    capture: Path
    keep: Path | None = None

    @property
    def stem(self) -> str:
        """The name Dask shows the task by."""
        return self.capture.stem


def _moments_or_error(job: _PrepareJob, shared: tuple):
    """:func:`take_moments` of a capture, or the message of the error it raised; ``shared``
    is the run's configuration and its
    :class:`~fit.pipeline.reconstruction.SharedReconstruction` (or None: built here)."""
    config, built = shared
    try:
        reconstruction = Reconstruction.from_config(config) if built is None \
            else built.reconstruction
        return take_moments(job.capture, reconstruction, keep=job.keep)
    except Exception as exc:  # noqa: BLE001 - one take's failure must not stop the others
        return str(exc) if isinstance(exc, Mocap2MeshError) else f"{type(exc).__name__}: {exc}"


def build_session_basis(config: RunConfig, *, executor=None,
                        progress: bool | None = None, keep=None, built=None) -> tuple:
    """The session basis of a run's takes, and the takes that could not contribute.

    Parameters
    ----------
    config : RunConfig
        Every capture of it is pooled, whether or not it is run again.
    executor : fit.pipeline.executors.SessionExecutor, optional
        Where the takes are prepared, one task each (default: one after the
        other in this process).
    progress : bool or None
        Show a progress bar (None: only on a terminal).
    keep : mapping of Path to Path, optional
        Captures whose prepared take is kept for their run: capture -> its file
        (:mod:`fit.pipeline.kept_takes`).
    built : fit.pipeline.reconstruction.SharedReconstruction, optional
        The run's reconstruction, built once (default: each take builds it).

    Returns
    -------
    basis : SessionBasis or None
        None when no take could be prepared.
    failed : dict of str to str
        Take name -> the error that kept it out (it fails the run as well).

    Raises
    ------
    InputError
        From :func:`session_basis` (the options do not fit the pooled takes).
    """
    captures = list(config.captures)
    executor = LocalExecutor(1) if executor is None else executor
    done = {}
    with tqdm(total=len(captures), desc="session basis", unit="take", file=sys.stderr,
              disable=None if progress is None else not progress) as bar:
        jobs = [_PrepareJob(capture, (keep or {}).get(capture)) for capture in captures]
        for outcome in executor.map_unordered(_moments_or_error, jobs,
                                              shared=(config, built)):
            done[outcome.job.capture] = outcome.result if outcome.ok else outcome.error
            bar.update()
    outcomes = [done[c] for c in captures]          # pooled in the run's order
    failed = {c.stem: o for c, o in zip(captures, outcomes) if isinstance(o, str)}
    prepared = [o for o in outcomes if isinstance(o, TakeMoments)]
    if not prepared:
        return None, failed
    return session_basis(prepared, config.basis_options), failed
