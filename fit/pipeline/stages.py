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
from mocap.bind import Binding, BoundTake, bind_take
from mocap.neutral import PICKED_FRAMES
from mocap.errors import InputError, MarkerError
from mocap.markerset import MarkerSet
from mocap.mesh.mesh import Mesh
from mocap.take import Take

from mocap.clean.ingest import IngestOptions, IngestResult, ingest
from fit.solve.marker_centres import solve_at_marker_centres
from mocap.retarget.retargeting import RetargetOptions, Retargeting, retarget
from fit.solve.sampling_estimator import estimate_weights_by_sampling
from fit.solve.weights import WeightSolution, as_smoothness, solve_weights
from fit.solve.temporal import moving_average

__all__ = ["BASES", "SPACES", "BindOptions", "BasisOptions", "FitOptions", "complete_span",
           "NamedBasis", "BasisResult", "FitResult", "ingest_stage",
           "bind_stage", "retarget_stage", "basis_stage", "fit_stage", "marker_basis",
           "solve_mesh_space", "H_SOLVERS", "CENTRE_MODELS"]

#: The bases every take is fitted with: hand-made (artist), quasi-eigen, PCA.
BASES = ("H", "QE", "PCA")
#: Where the weights are fitted: at the bound marker points, or on every vertex through W.
SPACES = ("marker", "mesh")
#: Largest vertex move of the central differences of :func:`marker_basis`, over the mesh size.
_NORMAL_STEP = 1e-4
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
        n-row problem of :func:`solve_mesh_space`). The λ used is each
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
        their tangent at the neutral (:func:`marker_basis`) only, which is off
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
    """A basis as the fit and the exports see it.

    ``v = neutral + Σ_i w_i e_i``; `fixed` shapes (the PCA mean) have weight 1
    in every frame and are not solved for.

    Attributes
    ----------
    names : tuple of str, length n
    displacements : ndarray, shape (n, N, 3), mesh units
    lower, upper : float
        Bounds of the solved weights.
    n_fixed : int
        The first `n_fixed` shapes have weight 1.
    """

    names: tuple
    displacements: np.ndarray
    lower: float = -np.inf
    upper: float = np.inf
    n_fixed: int = 0


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
    pcs = tuple(f"pc_{j:02d}" for j in range(m))
    bases = {"H": NamedBasis(artist.names, artist.displacements, 0.0, 1.0),
             "QE": NamedBasis(qe.names, qe.displacements),
             "PCA": NamedBasis(("pca_mean",) + pcs,
                               np.concatenate([model.mean[None], model.components]),
                               n_fixed=1)}
    return BasisResult(bases=bases, pca=pca, n_components=m, qe=qe)


def marker_basis(binding: Binding, displacements, labels=None, *,
                 mesh: Mesh | None = None) -> np.ndarray:
    """A mesh basis sampled at the bound markers, in mesh units and mesh axes.

    Parameters
    ----------
    binding : Binding
        The markers bound to the mesh.
    displacements : array_like of shape (n, N, 3), mesh units
        Shape displacements from the neutral mesh. No NaN.
    labels : sequence of str, optional
        The M markers to sample, in this order; default every bound marker.
    mesh : Mesh, optional
        The neutral mesh of the binding; with a binding made with
        ``skin_offset`` > 0, the marker centres are sampled instead of the
        surface points (Notes).

    Returns
    -------
    ndarray of shape (n, M, 3), mesh units

    Raises
    ------
    MarkerError
        A label not in the binding.

    Notes
    -----
    Without `mesh` (or with a binding of no skin offset), the motion of the
    bound surface points. With the neutral `mesh` and a binding made with
    ``skin_offset`` > 0, the motion of the marker centres that far off the
    skin along the normal, to first order: markers sit on the skin and their
    centres turn with it. The normal is the one of
    :meth:`mocap.mesh.layout.MarkerLayout.positions` (area-weighted vertex normals,
    interpolated); its change along each shape is a central difference.
    """
    absent = [x for x in (labels or ()) if x not in binding.labels]
    if absent:
        raise MarkerError(absent[0], "is not in the binding")
    if mesh is None or binding.skin_offset == 0:
        points = binding.marker_points(displacements)
    else:
        layout = binding.centre_layout(mesh)
        displacements = np.asarray(displacements, dtype=np.float64)
        size = np.ptp(mesh.vertices, axis=0).max()
        largest = np.abs(displacements).reshape(len(displacements), -1).max(axis=1)
        h = (_NORMAL_STEP * size / np.maximum(largest, np.finfo(float).tiny))[:, None, None]
        points = (layout.positions(mesh.vertices + h * displacements)
                  - layout.positions(mesh.vertices - h * displacements)) / (2 * h)
    if labels is None:
        return points
    return points[:, [binding.labels.index(label) for label in labels]]


def solve_mesh_space(displacements, operator, marker_disp, *, offset=None, lower=-np.inf,
                     upper=np.inf, smoothness: float | str = 0.0) -> WeightSolution:
    """Per frame ``min ½‖E w − (W d_t − o)‖²`` over every vertex, without forming W·D(t).

    Parameters
    ----------
    displacements : array_like, shape (n, N, 3), mesh units
        The basis E.
    operator : array_like, shape (N, M)
        W, applied to x, y and z alike.
    marker_disp : array_like, shape (T, M, 3), mesh units
        d_t. No NaN.
    offset : array_like, shape (N, 3), mesh units, optional
        o, subtracted from every frame's target (the fixed part of a basis,
        e.g. the PCA mean); default 0.
    lower, upper, smoothness
        As in :func:`fit.solve.weights.solve_weights`.

    Returns
    -------
    WeightSolution
        ``cost`` is the mesh-space ½‖E w − (W d_t − o)‖² (mesh units²).

    Notes
    -----
    With G = EᵀE = V Λ Vᵀ and c_t = Eᵀ W d_t = (WᵀE)ᵀ d_t, the objective is
    ½‖R w − y_t‖² + ½(‖W d_t‖² − ‖y_t‖²) with R = Λ^½ Vᵀ and y_t = Λ^-½ Vᵀ c_t
    (directions with λ = 0 dropped: c_t has no component there). So the n × n
    problem (R, y) is handed to :func:`fit.solve.weights.solve_weights` and the constant
    added back; ‖W d_t‖² = Σ_c d_tcᵀ (WᵀW) d_tc needs only the M × M matrix WᵀW,
    and an offset adds −Eᵀo to c_t and ‖o‖² − 2 (Wᵀo)·d_t to ‖W d_t‖².
    Cost O(n N M + n² N + T M n), memory O(n N + T n).
    """
    E = np.asarray(displacements, dtype=np.float64)
    W = np.asarray(operator.toarray() if hasattr(operator, "toarray") else operator,
                   dtype=np.float64)
    D = np.asarray(marker_disp, dtype=np.float64)
    n, n_vertices, _ = E.shape
    if W.shape[0] != n_vertices or D.ndim != 3 or D.shape[1:] != (W.shape[1], 3):
        raise InputError(f"mesh-space fit: basis {E.shape}, operator {W.shape} and marker "
                         f"displacements {D.shape} do not match (n, N, 3), (N, M), (T, M, 3)")
    flat = E.reshape(n, -1)
    gram = flat @ flat.T
    # P_i = Wᵀ e_i (M, 3): c_t = Σ P_i · d_t
    proj = (W.T @ E.transpose(1, 0, 2).reshape(n_vertices, -1)).reshape(-1, n, 3)
    C = D.reshape(len(D), -1) @ proj.transpose(0, 2, 1).reshape(-1, n)
    norm2 = np.einsum("tmc,mk,tkc->t", D, W.T @ W, D)
    if offset is not None:
        o = np.asarray(offset, dtype=np.float64).reshape(n_vertices, 3)
        C = C - flat @ o.ravel()
        norm2 = norm2 + (o ** 2).sum() - 2 * np.einsum("tmc,mc->t", D, W.T @ o)
    lam, V = np.linalg.eigh(gram)
    keep = lam > lam.max() * n * np.finfo(float).eps
    root = np.sqrt(lam[keep])
    R = root[:, None] * V[:, keep].T
    y = (C @ V[:, keep]) / root
    sol = solve_weights(R, y, lower=lower, upper=upper, smoothness=smoothness)
    return replace(sol, cost=sol.cost + 0.5 * np.maximum(norm2 - (y ** 2).sum(axis=1), 0.0))


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
    Marker space: B = basis sampled at the bound markers (:func:`marker_basis`:
    binding face ids and barycentric coordinates; for H, lifted by the
    binding's skin offset), d_t = marker displacements; mesh space: see
    :func:`solve_mesh_space`. With ``moving_average`` the displacements are
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
        # the artist's shapes move the skin: lift them to the marker centres; the
        # PCA and QE bases come from W·D, which already holds the centres' motion
        # at the bound points
        at_markers = marker_basis(binding, basis.displacements, labels,
                                  mesh=retargeted.mesh if name == "H" else None)
        data = D - at_markers[:k].sum(axis=0)
        lower, upper = basis.lower, basis.upper
        if name == "H":
            lower, upper = -options.h_epsilon, 1.0 + options.h_epsilon
        with warnings.catch_warnings():
            if name == "QE":        # rank ≤ m + 1 < n by construction when m < n - 1
                warnings.filterwarnings("ignore", "the basis has rank", RuntimeWarning)
            if name == "H" and options.h_solver == "sampling":
                sol = estimate_weights_by_sampling(at_markers[k:], data, lower=lower,
                                                   upper=upper, n_samples=options.n_samples,
                                                   n_neighbors=options.n_neighbors)
            elif options.space == "mesh":
                sol = solve_mesh_space(basis.displacements[k:], retargeted.operator.matrix, D,
                                       offset=basis.displacements[:k].sum(axis=0),
                                       lower=lower, upper=upper,
                                       smoothness=options.smoothness)
            elif name == "H" and options.marker_centres == "exact" and binding.skin_offset:
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
