"""The options of each stage of the chain, as frozen dataclasses (the tables of ``run.toml``).

Each class validates its fields when made, so that a wrong value is refused
where it is given (a config key, a keyword argument), not deep in a stage.
Ingestion and retargeting options live with their stages
(:class:`mocap.clean.ingest.IngestOptions`,
:class:`mocap.retarget.retargeting.RetargetOptions`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from basis.quasi_eigen import MISSING_POLICIES
from fit.solve.weights import as_smoothness
from mocap.errors import InputError
from mocap.neutral import PICKED_FRAMES
from mocap.util.validation import as_choice, as_int, as_positive_float

__all__ = ["BASES", "SPACES", "H_SOLVERS", "CENTRE_MODELS", "BASIS_SCOPES", "BindOptions",
           "BasisOptions", "FitOptions", "ReportOptions"]

#: The bases every take is fitted with: hand-made (artist), quasi-eigen, PCA.
BASES = ("H", "QE", "PCA")
#: Where the weights are fitted: at the bound marker points, or on every vertex through W.
SPACES = ("marker", "mesh")
#: How the H weights are found: exactly, or by the gestures paper's sampling estimator.
H_SOLVERS = ("exact", "sampling")
#: How the artist shapes move the marker centres in a marker-space fit
#: (:attr:`FitOptions.marker_centres`).
CENTRE_MODELS = ("exact", "linear")
#: What the PCA and quasi-eigen bases of a take are made from (:attr:`BasisOptions.scope`):
#: every take of the session pooled, or the take alone.
BASIS_SCOPES = ("session", "take")


@dataclass(frozen=True)
class BindOptions:
    """Options of the bind stage (see :func:`mocap.bind.bind_markers`).

    Attributes
    ----------
    frame : int, "auto" or "hold"
        Neutral frame, the capture's own frame number, ``"auto"`` (the frame nearest the median
        pose) or ``"hold"`` (the take starts with a neutral hold): see
        :func:`mocap.neutral.pick_neutral_frame`. With "hold" the rest pose is
        the mean of the hold's window around that frame.
    icp : bool
        Refine the landmark similarity by trimmed ICP against the surface.
    skin_offset : float, mm
        Height of the marker centres off the skin (the markers' radius).
    max_distance_warn : float, mm
        Warn about markers whose distance to the surface differs from
        `skin_offset` by more than this.
    """

    frame: int | str = "auto"
    icp: bool = True
    skin_offset: float = 0.0
    max_distance_warn: float = 3.0

    def __post_init__(self):
        if isinstance(self.frame, str):
            if self.frame not in PICKED_FRAMES:
                raise InputError(f"frame must be a frame number, 'auto' or 'hold', "
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
    scope : str
        One of :data:`BASIS_SCOPES`. ``"session"`` (default): one PCA of the
        mesh sequences of every take of the run pooled, and its quasi-eigen
        faces, fit every take, so that their weights share one basis
        (:mod:`fit.pipeline.session_basis`; a run of one take is its own
        session). ``"take"``: each take's own PCA and quasi-eigen faces.
    """

    pca_components: int | None = None
    pca_coverage: float = 0.995
    qe_missing: str = "report"
    missing_eps: float = 0.05
    scope: str = "session"

    def __post_init__(self):
        as_choice(self.scope, "scope", BASIS_SCOPES)
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


@dataclass(frozen=True)
class ReportOptions:
    """Options of the QA report of each take.

    Attributes
    ----------
    video : bool
        Write the overlay video (one VP9 WebM, a panel per basis) into the report.
    video_step : int or "auto"
        Draw every n-th frame in the video ("auto": at most 60 a second). With
        "auto", every frame of a take up to 60 Hz, above it the smallest step
        that keeps the real-time video at most 60 frames a second
        (:func:`fit.report.video.video_step`).
    n_worst : int
        Worst frames shown and listed.
    exaggerate : float
        Error vectors drawn this many times longer.
    held_out_folds : int
        Time-blocked folds of the out-of-sample QE and PCA errors
        (:func:`fit.pipeline.holdout.time_blocked_splits`); 0: none.
    held_out_guard_s : float
        Seconds on each side of a test block left out of its training frames.
    mesh_views : bool
        Shaded renders of every basis's mesh and of W·D at the worst frames
        and the take's extremes.
    """

    video: bool = True
    video_step: int | str = "auto"
    n_worst: int = 5
    exaggerate: float = 1.0
    held_out_folds: int = 5
    held_out_guard_s: float = 0.5
    mesh_views: bool = True

    def __post_init__(self):
        if not isinstance(self.video, bool):
            raise InputError(f"video must be true or false, got {self.video!r}")
        if isinstance(self.video_step, str):
            if self.video_step != "auto":
                raise InputError(f"video_step must be 'auto' or an integer >= 1, got "
                                 f"{self.video_step!r}")
        else:
            as_int(self.video_step, "video_step", minimum=1)
        as_int(self.n_worst, "n_worst", minimum=1)
        as_positive_float(self.exaggerate, "exaggerate")
        folds = as_int(self.held_out_folds, "held_out_folds", minimum=0)
        if folds == 1:
            raise InputError("held_out_folds must be 0 (none) or at least 2")
        if not np.isfinite(self.held_out_guard_s) or self.held_out_guard_s < 0:
            raise InputError(f"held_out_guard_s must be a finite number >= 0, got "
                             f"{self.held_out_guard_s!r}")
        if not isinstance(self.mesh_views, bool):
            raise InputError(f"mesh_views must be true or false, got {self.mesh_views!r}")
