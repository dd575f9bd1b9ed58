"""One take through the whole chain, one function per stage.

ingest → bind → retarget → bases (PCA, quasi-eigen, artist) → fit → outputs.
Each stage is a thin call into the library returning a frozen result, so a
script can run, inspect or replace any of them; :func:`process_take` chains
them and writes every output of a take (what ``mocap2mesh run`` does per take).

Units: markers in capture millimetres, everything on the mesh (bases, marker
displacements fed to the fit) in mesh units; reconstructed markers are brought
back to millimetres for the error metrics.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np

from basis.artist import ArtistBasis
from basis.pca import PCAModel, pca_from_operator
from basis.quasi_eigen import MISSING_POLICIES, QuasiEigenBasis, quasi_eigen
from mocap.util.validation import as_choice, as_int, as_positive_float
from mocap.bind import BoundTake, bind_take
from mocap.neutral import PICKED_FRAMES
from mocap.errors import InputError
from mocap.markerset import MarkerSet
from mocap.mesh.mesh import Mesh
from mocap.take import Take

from mocap.clean.ingest import IngestOptions, IngestResult, ingest
from fit.solve.marker_basis import marker_basis
from fit.solve.marker_centres import solve_at_marker_centres
from fit.solve.mesh_space import solve_mesh_space
from mocap.retarget.retargeting import RetargetOptions, Retargeting, retarget
from fit.solve.sampling_estimator import estimate_weights_by_sampling
from fit.solve.weights import as_smoothness, solve_weights
from fit.solve.temporal import moving_average

__all__ = ["BASES", "SPACES", "BindOptions", "BasisOptions", "FitOptions", "complete_span",
           "NamedBasis", "BasisResult", "FitResult", "ingest_stage",
           "bind_stage", "retarget_stage", "basis_stage", "fit_stage", "H_SOLVERS", "CENTRE_MODELS"]

#: The bases every take is fitted with: hand-made (artist), quasi-eigen, PCA.
BASES = ("H", "QE", "PCA")
#: Where the weights are fitted: at the bound marker points, or on every vertex through W.
SPACES = ("marker", "mesh")
#: How the H weights are found: exactly, or by the gestures paper's sampling estimator.
H_SOLVERS = ("exact", "sampling")
#: How the artist shapes move the marker centres in a marker-space fit
#: (:attr:`FitOptions.marker_centres`).
CENTRE_MODELS = ("exact", "linear")


@dataclass(frozen=True)
class BindOptions:
    """Options of the bind stage (see :func:`mocap.bind.bind_markers`).

    Attributes
    ----------
    frame : int, "auto" or "hold"
        Neutral frame index (0-based), ``"auto"`` (the frame nearest the median
        pose) or ``"hold"`` (the take starts with a neutral hold): see
        :func:`mocap.neutral.pick_neutral_frame`. With "hold" the rest pose is
        the mean of the hold's window around that frame.
    icp : bool
    skin_offset : float, mm
    max_distance_warn : float, mm
    """

    frame: int | str = "auto"
    icp: bool = True
    skin_offset: float = 0.0
    max_distance_warn: float = 3.0

    def __post_init__(self):
        if isinstance(self.frame, str):
            if self.frame not in PICKED_FRAMES:
                raise InputError(f"frame must be a frame index, 'auto' or 'hold', "
                                 f"got {self.frame!r}")
        else:
            as_int(self.frame, "frame", minimum=0)
        if not isinstance(self.icp, bool):
            raise InputError(f"icp must be true or false, got {self.icp!r}")
        if not np.isfinite(self.skin_offset) or self.skin_offset < 0:
            raise InputError(f"skin_offset must be a finite number >= 0, got {self.skin_offset!r}")
        as_positive_float(self.max_distance_warn, "max_distance_warn")


@dataclass(frozen=True)
class BasisOptions:
    """Options of the basis stage.

    Attributes
    ----------
    pca_components : int or None
        PCA size m; None picks the smallest m reaching `pca_coverage`.
    pca_coverage : float in (0, 1]
        Coverage threshold of the default m (the paper: 0.995).
    qe_missing : str
        One of :data:`basis.quasi_eigen.MISSING_POLICIES`.
    missing_eps : float
        Threshold of a missing PCA axis (:func:`basis.quasi_eigen.quasi_eigen`).
    """

    pca_components: int | None = None
    pca_coverage: float = 0.995
    qe_missing: str = "report"
    missing_eps: float = 0.05

    def __post_init__(self):
        if self.pca_components is not None:
            as_int(self.pca_components, "pca_components", minimum=1)
        if not 0 < self.pca_coverage <= 1:
            raise InputError(f"pca_coverage must be in (0, 1], got {self.pca_coverage!r}")
        as_choice(self.qe_missing, "qe_missing", MISSING_POLICIES)


@dataclass(frozen=True)
class FitOptions:
    """Options of the fit stage.

    Attributes
    ----------
    space : str
        One of :data:`SPACES`.
    h_epsilon : float
        Hand-made weights are bounded to [−ε, 1 + ε]; QE and PCA weights are
        unbounded (QE weights may be negative, as in the paper).
    smoothness : float or "gcv"
        λ of :func:`fit.solve.weights.solve_weights` (0: frames independent), or
        "gcv": chosen per basis by generalized cross-validation
        (:func:`fit.solve.gcv.gcv_smoothness`; in mesh space, of the projected
        n-row problem of :func:`fit.solve.mesh_space.solve_mesh_space`). The λ used is each
        solution's ``smoothness``.
    moving_average : int
        Odd window (frames) of the centred moving average of the marker
        displacements before solving (:func:`fit.solve.temporal.moving_average`;
        the gestures paper's 41); 0 or 1: none.
    h_solver : str
        One of :data:`H_SOLVERS`: "exact" (:func:`fit.solve.weights.solve_weights`) or
        "sampling", the gestures paper's estimator
        (:func:`fit.solve.sampling_estimator.estimate_weights_by_sampling`), for
        the H weights in marker space, to compare with the exact solver.
    n_samples, n_neighbors : int
        Samples and nearest neighbours of "sampling" (paper: 1000 and 60).
    marker_centres : str
        One of :data:`CENTRE_MODELS`, for the H weights of the exact solver in
        marker space with a binding made with a skin offset: "exact" (default)
        fits the centres as they move, off the turning skin
        (:func:`fit.solve.marker_centres.solve_at_marker_centres`); "linear" fits
        their tangent at the neutral (:func:`fit.solve.marker_basis.marker_basis`) only, which is off
        by up to 0.25 in weight at full expressions on the ICT face with 2 mm
        markers.
    """

    space: str = "marker"
    h_epsilon: float = 0.0
    smoothness: float | str = 0.0
    moving_average: int = 0
    h_solver: str = "exact"
    n_samples: int = 1000
    n_neighbors: int = 60
    marker_centres: str = "exact"

    def __post_init__(self):
        as_choice(self.space, "space", SPACES)
        as_choice(self.h_solver, "h_solver", H_SOLVERS)
        as_choice(self.marker_centres, "marker_centres", CENTRE_MODELS)
        if not np.isfinite(self.h_epsilon) or self.h_epsilon < 0:
            raise InputError(f"h_epsilon must be a finite number >= 0, got {self.h_epsilon!r}")
        as_smoothness(self.smoothness)
        window = as_int(self.moving_average, "moving_average", minimum=0)
        if window > 1 and window % 2 == 0:
            raise InputError(f"moving_average must be an odd number of frames, got {window}")
        as_int(self.n_samples, "n_samples", minimum=1)
        as_int(self.n_neighbors, "n_neighbors", minimum=1)
        if self.h_solver == "sampling" and (self.space != "marker" or self.smoothness):
            raise InputError("h_solver = 'sampling' estimates frames one by one in marker "
                             "space: it needs space = 'marker' and smoothness = 0")


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
        The full PCA of the take's mesh sequence (before truncation).
    n_components : int
        m, the PCA size used for PCA and QE.
    qe : QuasiEigenBasis
    """

    bases: dict
    pca: PCAModel
    n_components: int
    qe: QuasiEigenBasis


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
    """Clean and head-stabilize a take (:func:`mocap.clean.ingest.ingest`, stabilization forced on)."""
    return ingest(take, markerset=markerset, options=replace(options, stabilize=True))


def complete_span(take: Take, labels) -> Take:
    """The take cut to the frames from the first to the last where all `labels` are present.

    Gap filling does not extrapolate, so a marker missing at the start or the
    end of a take stays NaN there; those end frames are dropped (``first_frame``
    follows). Gaps left inside the span are kept (and rejected downstream).

    Raises
    ------
    InputError
        No frame has every one of `labels`.
    """
    complete = ~np.isnan(take.select(labels).positions).any(axis=(1, 2))
    if not complete.any():
        raise InputError(f"{take.source.path or 'the take'}: no frame has every face marker "
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
    return bind_take(take, markerset, mesh, mesh_landmarks, frame=options.frame,
                     stabilize="none", icp=options.icp, skin_offset=options.skin_offset,
                     max_distance_warn=options.max_distance_warn)


def retarget_stage(take: Take, bound: BoundTake, mesh: Mesh, markerset: MarkerSet,
                   options: RetargetOptions = RetargetOptions()) -> Retargeting:
    """Face-marker displacements (mesh units) and the RBF operator W (:func:`mocap.retarget.retargeting.retarget`).

    Parameters
    ----------
    take : Take
        Head-stabilized, gap-free positions, mm (the take `bound` was made from).
    bound : BoundTake
    mesh : Mesh
    markerset : MarkerSet
    options : RetargetOptions

    Returns
    -------
    Retargeting
        ``displacements`` (T, M, 3) from the bound rest pose, ``operator.matrix`` (N, M).
    """
    return retarget(take, bound.binding, mesh, markerset, options=options,
                    neutral_frame=bound.frame, neutral_window=bound.window, align=False)


def basis_stage(retargeted: Retargeting, artist: ArtistBasis, *,
                options: BasisOptions = BasisOptions()) -> BasisResult:
    """PCA of the take's mesh sequence W·D(t), quasi-eigen faces, and the artist basis.

    Parameters
    ----------
    retargeted : Retargeting
    artist : ArtistBasis
        E^H on the mesh's topology, mesh units.
    options : BasisOptions

    Returns
    -------
    BasisResult
        Bases ``H`` (artist, [0, 1] by default), ``QE`` (unbounded) and
        ``PCA`` (the mean, weight fixed at 1, then m unbounded eigenfaces).
    """
    pca = pca_from_operator(retargeted.operator.matrix, retargeted.displacements)
    m = options.pca_components or pca.n_for_coverage(options.pca_coverage)
    if m > pca.n_components:
        raise InputError(f"basis.pca_components = {m} is more than the {pca.n_components} "
                         "components of the take's mesh sequence")
    model = pca.truncate(m)
    qe = quasi_eigen(model, artist.displacements, names=artist.names,
                     missing=options.qe_missing, missing_eps=options.missing_eps)
    bases = {"H": NamedBasis(artist.names, artist.displacements, 0.0, 1.0, on_skin=True),
             "QE": NamedBasis(qe.names, qe.displacements, rank_deficient=True),
             "PCA": NamedBasis(*model.shapes(), n_fixed=1)}
    return BasisResult(bases=bases, pca=pca, n_components=m, qe=qe)


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
    Marker space: B = basis sampled at the bound markers (:func:`fit.solve.marker_basis.marker_basis`:
    binding face ids and barycentric coordinates; for H, lifted by the
    binding's skin offset), d_t = marker displacements; mesh space: see
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
    neutral = bound.neutral_pose(take.select(labels).positions)
    solutions, weights, reconstructed = {}, {}, {}
    for name, basis in bases.bases.items():
        k, centres = basis.n_fixed, None
        at_markers = marker_basis(binding, basis.displacements, labels,
                                  mesh=retargeted.mesh if basis.on_skin else None)
        data = D - at_markers[:k].sum(axis=0)
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
        disp = centres.displacements if centres else np.tensordot(full, at_markers, axes=1)
        solutions[name], weights[name] = sol, full
        reconstructed[name] = neutral + disp @ binding.rotation / binding.scale
    return FitResult(solutions=solutions, weights=weights, reconstructed=reconstructed,
                     space=options.space)
