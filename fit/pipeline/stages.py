"""One take through the whole chain, one function per stage.

ingest → bind → retarget → bases (PCA, quasi-eigen, artist) → fit.
Each stage is a thin call into the library returning a frozen result, so a
script can run, inspect or replace any of them;
:class:`fit.pipeline.reconstruction.Reconstruction` chains them (what
``mocap2mesh run`` does per take) and writes the outputs.

Units: markers in capture millimetres, everything on the mesh (bases, marker
displacements fed to the fit) in mesh units; reconstructed markers are brought
back to millimetres for the error metrics.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np

from basis.artist import ArtistBasis
from basis.pca import PCAModel, pca_from_operator, pca_from_operators
from basis.quasi_eigen import QuasiEigenBasis, quasi_eigen
from fit.pipeline.options import BasisOptions, BindOptions, FitOptions
from fit.report.retarget_qa import mesh_lip_gaps
from fit.solve.marker_basis import marker_basis
from fit.solve.marker_centres import solve_at_marker_centres
from fit.solve.mesh_space import solve_mesh_space
from fit.solve.sampling_estimator import estimate_weights_by_sampling
from fit.solve.temporal import moving_average
from fit.solve.weights import solve_weights
from mocap.bind import BoundTake, bind_take
from mocap.clean.ingest import IngestOptions, IngestResult, ingest
from mocap.errors import InputError, MarkerError
from mocap.markerset import MarkerSet
from mocap.mesh.mesh import Mesh
from mocap.mesh.mouth import find_mouth
from mocap.retarget.lip_seal import LipSealCheck, check_lip_seal
from mocap.retarget.retargeting import Retargeting, RetargetOptions, retarget
from mocap.take import Take
from mocap.util.blas import map_on_blas_threads

__all__ = ["complete_span", "NamedBasis", "BasisResult", "FitResult", "ingest_stage",
           "bind_stage", "retarget_stage", "basis_stage", "fit_stage", "lip_seal_stage"]

@dataclass(frozen=True, eq=False)
class NamedBasis:
    """A basis as the fit and the exports see it, with how it is fitted.

    ``v = neutral + Σ_i w_i e_i``; `fixed` shapes (the PCA mean) have weight 1
    in every frame and are not solved for.

    Attributes
    ----------
    names : tuple of str, length n
    displacements : ndarray, shape (n, N, 3), mesh units
    lower, upper : float
        Bounds of the solved weights; finite bounds are widened by
        :attr:`FitOptions.h_epsilon`.
    n_fixed : int
        The first `n_fixed` shapes have weight 1.
    on_skin : bool
        Shapes sculpted on the skin (an artist's): sampled at the marker
        centres off the skin, and fitted with :attr:`FitOptions.h_solver`
        and :attr:`FitOptions.marker_centres`. Bases made from W·D (PCA,
        quasi-eigen) already hold the centres' motion at the bound points.
    rank_deficient : bool
        May have rank below n by construction (the quasi-eigen faces: rank
        ≤ m + 1, below n when m < n − 1): the solver's rank warning is not
        passed on.
    """

    names: tuple
    displacements: np.ndarray
    lower: float = -np.inf
    upper: float = np.inf
    n_fixed: int = 0
    on_skin: bool = False
    rank_deficient: bool = False


@dataclass(frozen=True, eq=False)
class BasisResult:
    """The three bases of a take and where they came from.

    Attributes
    ----------
    bases : dict of str to NamedBasis
        Keyed by :data:`BASES`.
    pca : PCAModel
        The full PCA of the take's mesh sequence (before truncation), or the
        session's PCA (``scope == "session"``: as many components as it kept).
    n_components : int
        m, the PCA size used for PCA and QE.
    qe : QuasiEigenBasis
    scope : str
        ``"take"`` (the take's own PCA) or ``"session"`` (one shared by the takes).
    """

    bases: dict
    pca: PCAModel
    n_components: int
    qe: QuasiEigenBasis
    scope: str = "take"


@dataclass(frozen=True, eq=False)
class FitResult:
    """Weights of every basis and the markers they reconstruct.

    Attributes
    ----------
    solutions : dict of str to WeightSolution or SamplingEstimate
        Solved weights per basis, (T, n_solved) (a SamplingEstimate for H
        with ``h_solver = "sampling"``).
    weights : dict of str to ndarray, shape (T, n)
        Full weights, fixed shapes included (what the exports evaluate).
    reconstructed : dict of str to ndarray, shape (T, M, 3), mm
        Reconstructed face markers (``Retargeting.labels``) in the head frame of the capture.
    space : str
    """

    solutions: dict
    weights: dict
    reconstructed: dict
    space: str


def ingest_stage(take: Take, markerset: MarkerSet, options: IngestOptions) -> IngestResult:
    """Clean and head-stabilize a take (:func:`mocap.clean.ingest.ingest`).

    Stabilization is always on in the chain: ``options.stabilize`` says how
    the head frame is found ("head", "auto" or "none"; off means "head").
    """
    return ingest(take, markerset=markerset,
                  options=replace(options, stabilize=options.stabilize or "head"))


def complete_span(take: Take, labels) -> Take:
    """The take cut to the frames from the first to the last where all `labels` are present.

    Gap filling does not extrapolate, so a marker missing at the start or the
    end of a take stays NaN there; those end frames are dropped (``first_frame``
    follows). Gaps left inside the span are kept (and rejected downstream).

    Raises
    ------
    MarkerError
        A marker of `labels` is missing in every frame (the first such is named).
    InputError
        The take has no frames, or no frame has every one of `labels`.
    """
    where, labels = take.source.path or "the take", tuple(labels)
    if take.n_frames == 0:
        raise InputError(f"{where}: the take has no frames")
    present = ~np.isnan(take.select(labels).positions).any(axis=2)
    never = np.flatnonzero(~present.any(axis=0))
    if never.size:
        raise MarkerError(labels[never[0]], f"is missing in every frame of {where}, even after "
                                            "gap filling (absent in all: "
                                            f"{', '.join(labels[i] for i in never)})")
    complete = present.all(axis=1)
    if not complete.any():
        raise InputError(f"{where}: no frame has every face marker "
                         "present, even after gap filling")
    first, last = np.flatnonzero(complete)[[0, -1]]
    if first == 0 and last == take.n_frames - 1:
        return take
    return take.replace(positions=take.positions[first:last + 1],
                        filled=take.filled[first:last + 1],
                        first_frame=take.first_frame + int(first))


def bind_stage(take: Take, markerset: MarkerSet, mesh: Mesh, mesh_landmarks, *,
               options: BindOptions = BindOptions()) -> BoundTake:
    """Bind the markers of the neutral frame of a head-stabilized take to `mesh`.

    :func:`mocap.bind.bind_take` of the take as it is (in the head frame):
    every marker of the set is bound (landmarks may name head markers); the
    neutral frame is picked on the face markers.

    Parameters
    ----------
    take : Take
        Head-stabilized positions (T, M, 3), mm, with every face marker of `markerset`.
    markerset : MarkerSet
    mesh : Mesh
    mesh_landmarks : mapping of str to int
    options : BindOptions

    Returns
    -------
    BoundTake

    Raises
    ------
    InputError
        The neutral frame is beyond the take.
    MarkerError
        A marker missing in the neutral frame (or its hold window).
    """
    return bind_take(take, markerset, mesh, mesh_landmarks,
                     frame=take.frame_index(options.frame, "bind.frame"),
                     stabilize="none", icp=options.icp, skin_offset=options.skin_offset,
                     max_distance_warn=options.max_distance_warn)


def retarget_stage(take: Take, bound: BoundTake, mesh: Mesh, markerset: MarkerSet,
                   options: RetargetOptions = RetargetOptions(), *,
                   mesh_landmarks=None) -> Retargeting:
    """Face-marker displacements (mesh units) and the RBF operator W
    (:func:`mocap.retarget.retargeting.retarget`).

    Parameters
    ----------
    take : Take
        Head-stabilized, gap-free positions, mm (the take `bound` was made from).
    bound : BoundTake
    mesh : Mesh
    markerset : MarkerSet
    options : RetargetOptions
        ``kernel="auto"`` (the default) is chosen on this take.
    mesh_landmarks : mapping of str to int, optional
        The mesh's landmarks: the mouth (:func:`mocap.mesh.mouth.find_mouth`),
        for ``"auto"`` and :func:`lip_seal_stage`; a mouth they do not give
        is a warning, and the lips are not read.

    Returns
    -------
    Retargeting
        ``displacements`` (T, M, 3) from the bound rest pose, ``operator.matrix`` (N, M),
        the variant used, its cross-validation and (``"auto"``) the selection.
    """
    mouth = None
    if mesh_landmarks is not None:
        try:
            mouth = find_mouth(mesh, mesh_landmarks)
        except InputError as exc:
            warnings.warn(f"the lips are not checked: {exc}", stacklevel=2)
    return retarget(take, bound.binding, mesh, markerset, options=options,
                    neutral_frame=bound.frame, neutral_window=bound.window, align=False,
                    mouth=mouth)


def basis_stage(retargeted: Retargeting, artist: ArtistBasis, *,
                options: BasisOptions = BasisOptions(), pca: PCAModel | None = None) -> BasisResult:
    """PCA of the take's mesh sequence W·D(t), quasi-eigen faces, and the artist basis.

    Parameters
    ----------
    retargeted : Retargeting
    artist : ArtistBasis
        E^H on the mesh's topology, mesh units.
    options : BasisOptions
    pca : PCAModel, optional
        A PCA made elsewhere to use instead of the take's own: the session's
        (:class:`fit.pipeline.session_basis.SessionBasis`), so that every take
        of a session is fitted in one PCA and one quasi-eigen basis.

    Returns
    -------
    BasisResult
        Bases ``H`` (artist, [0, 1] by default), ``QE`` (unbounded) and
        ``PCA`` (the mean, weight fixed at 1, then m unbounded eigenfaces).
    """
    scope = "take" if pca is None else "session"
    if pca is None and options.pca_components is None:
        # the components up to the coverage only (the others' eigenvalues are kept for the
        # coverage plot): the take's QE and PCA need no more
        pca = pca_from_operators([retargeted.operator.matrix], [retargeted.displacements],
                                 coverage=options.pca_coverage)
    elif pca is None:
        pca = pca_from_operator(retargeted.operator.matrix, retargeted.displacements)
    elif pca.mean.shape != (retargeted.mesh.n_vertices, 3):
        raise InputError(f"the session PCA has {len(pca.mean)} vertices, the take's mesh "
                         f"{retargeted.mesh.n_vertices}")
    m = options.pca_components or pca.n_for_coverage(options.pca_coverage)
    if m > pca.n_components:
        raise InputError(f"basis.pca_components = {m} is more than the {pca.n_components} "
                         f"components of the {scope}'s mesh sequence")
    model = pca.truncate(m)
    qe = quasi_eigen(model, artist.displacements, names=artist.names,
                     missing=options.qe_missing, missing_eps=options.missing_eps)
    bases = {"H": NamedBasis(artist.names, artist.displacements, 0.0, 1.0, on_skin=True),
             "QE": NamedBasis(qe.names, qe.displacements, rank_deficient=True),
             "PCA": NamedBasis(*model.shapes(), n_fixed=1)}
    return BasisResult(bases=bases, pca=pca, n_components=m, qe=qe, scope=scope)


def fit_stage(take: Take, bound: BoundTake, retargeted: Retargeting, bases: BasisResult, *,
              options: FitOptions = FitOptions()) -> FitResult:
    """Weights of every basis, frame by frame, and the face markers they reconstruct.

    Parameters
    ----------
    take : Take
        Head-stabilized positions, mm, with the binding's markers.
    bound, retargeted, bases
        Earlier stages.
    options : FitOptions

    Returns
    -------
    FitResult

    Notes
    -----
    Marker space: B = basis sampled at the bound markers
    (:func:`fit.solve.marker_basis.marker_basis`: binding face ids and barycentric
    coordinates; for H, lifted by the binding's skin offset), d_t = marker
    displacements; mesh space: see
    :func:`fit.solve.mesh_space.solve_mesh_space`. With ``moving_average`` the displacements are
    averaged over time first (the reconstruction is then compared with the
    captured, unaveraged markers). Reconstructed markers are the bound rest
    pose (:meth:`BoundTake.neutral_pose`) plus B w_t taken back to capture
    millimetres.
    """
    binding, labels = bound.binding, retargeted.labels
    D = retargeted.displacements
    if options.moving_average > 1:
        D = moving_average(D, window=options.moving_average)
    # the rest pose of every marker (a few frames), then the fitted ones: no copy of the take
    neutral = bound.neutral_pose(take.positions)[take.indices(labels)]
    solutions, weights, reconstructed = {}, {}, {}
    for name, basis in bases.bases.items():
        k, centres = basis.n_fixed, None
        at_markers = marker_basis(binding, basis.displacements, labels,
                                  mesh=retargeted.mesh if basis.on_skin else None)
        data = D - at_markers[:k].sum(axis=0) if k else D     # (no copy of D without one)
        lower, upper = (b + sign * options.h_epsilon if np.isfinite(b) else b
                        for b, sign in ((basis.lower, -1), (basis.upper, 1)))
        with warnings.catch_warnings():
            if basis.rank_deficient:
                warnings.filterwarnings("ignore", "the basis has rank", RuntimeWarning)
            if basis.on_skin and options.h_solver == "sampling":
                sol = estimate_weights_by_sampling(at_markers[k:], data, lower=lower,
                                                   upper=upper, n_samples=options.n_samples,
                                                   n_neighbors=options.n_neighbors)
            elif options.space == "mesh":
                sol = solve_mesh_space(basis.displacements[k:], retargeted.operator.matrix, D,
                                       offset=basis.displacements[:k].sum(axis=0),
                                       lower=lower, upper=upper,
                                       smoothness=options.smoothness)
            elif basis.on_skin and options.marker_centres == "exact" and binding.skin_offset:
                centres = solve_at_marker_centres(
                    binding.centre_layout(retargeted.mesh, labels),
                    retargeted.mesh.vertices, basis.displacements, at_markers, data,
                    lower=lower, upper=upper, smoothness=options.smoothness)
                sol = centres.solution
            else:
                sol = solve_weights(at_markers[k:], data, lower=lower, upper=upper,
                                    smoothness=options.smoothness)
        full = np.concatenate([np.ones((len(D), k)), sol.weights], axis=1)
        solutions[name], weights[name] = sol, full
        reconstructed[name] = _capture_markers(
            full, at_markers, centres.displacements if centres else None, binding, neutral)
    return FitResult(solutions=solutions, weights=weights, reconstructed=reconstructed,
                     space=options.space)


#: Frames of a task of :func:`_capture_markers` on the worker threads.
_FRAMES_PER_TASK = 4096


def _capture_markers(weights, at_markers, displacements, binding, neutral) -> np.ndarray:
    """The markers that `weights` (T, n) reconstruct, in capture millimetres, (T, M, 3).

    ``neutral + (B w_t) R / s``, with B `at_markers` (n, M, 3) and the binding's rotation
    R and scale s, or `displacements` (T, M, 3) instead of ``B w_t`` when given (the exact
    centres'); in place on each task's rows, tasks shared among the worker threads.
    """
    out = np.empty((len(weights), *neutral.shape))
    flat = at_markers.reshape(len(at_markers), -1)

    def task(first):
        rows = slice(first, first + _FRAMES_PER_TASK)
        part = out[rows]
        moved = displacements[rows] if displacements is not None else \
            (weights[rows] @ flat).reshape(part.shape)
        np.matmul(moved, binding.rotation, out=part)
        part /= binding.scale
        part += neutral
    map_on_blas_threads(task, range(0, len(weights), _FRAMES_PER_TASK))
    return out


def lip_seal_stage(take: Take, bound: BoundTake, retargeted: Retargeting, bases: BasisResult,
                   fitted: FitResult) -> LipSealCheck | None:
    """The lip gap of W·D and of every basis's mesh against the lip markers' opening.

    Parameters
    ----------
    take : Take
        Head-stabilized positions, mm, with the face markers.
    bound, retargeted, bases, fitted
        Earlier stages.

    Returns
    -------
    LipSealCheck or None
        None when the mesh's mouth (mesh landmarks) or the lip markers are unknown.
        Mesh gaps are in capture millimetres (mesh units over the binding's scale).
    """
    mouth, witness = retargeted.mouth, retargeted.lip_witness
    if mouth is None or witness is None:
        return None
    # the witness's markers only: their rest pose is the same columns of the face's
    witness = witness.own_markers()
    lips = take.select(witness.labels)
    rest = bound.neutral_pose(lips.positions)
    mm_per_unit = 1.0 / bound.binding.scale
    neutral = retargeted.mesh.vertices
    gaps = mesh_lip_gaps(mouth, neutral, mm_per_unit=mm_per_unit,
                         operator=retargeted.operator.matrix,
                         displacements=retargeted.displacements,
                         bases={name: (basis.displacements, fitted.weights[name])
                                for name, basis in bases.bases.items()})
    return check_lip_seal(witness.distance(lips.positions), gaps,
                          rest_distance=float(witness.distance(rest[None])[0]),
                          rest_gap=mm_per_unit * float(mouth.gap(neutral[mouth.vertex_ids])),
                          first_frame=take.first_frame, witness=witness.describe())
