"""Retargeting stage: a stabilized take, bound to a face mesh, drives the mesh.

The glue between the correspondence stage (:class:`mocap.bind.Binding`) and
the RBF operator (:mod:`mocap.retarget.rbf`): face-marker displacements from a neutral
frame, in mesh units, become vertex displacements ``Xi(t) = W D(t)``, applied
chunk by chunk and streamed to a ``.npz`` archive or an OBJ sequence. The
library behind ``mocap2mesh retarget`` and the retargeting step of
``mocap2mesh run``.

NaN policy: :func:`marker_displacements` propagates NaN; :func:`retarget`
rejects it (fill gaps first, e.g. :func:`mocap.clean.ingest.ingest`, which the CLI
runs) and names the first missing marker and frame.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace

import numpy as np

from mocap.bind import Binding
from mocap.errors import InputError, MarkerError
from mocap.markerset import MarkerSet
from mocap.mesh.mesh import Mesh, face_normals
from mocap.mesh.mouth import MouthOpening
from mocap.neutral import find_neutral
from mocap.retarget.cross_validation import CrossValidation, MarkerGeometry, cross_validate
from mocap.retarget.lip_seal import LipWitness, lip_witness
from mocap.retarget.rbf import DISTANCES, KERNELS, RBFOperator, build_rbf_operator
from mocap.retarget.selection import RetargetSelection, select_variant
from mocap.rigid import fit_rigid
from mocap.take import Take, as_take
from mocap.util.validation import as_choice, as_float_array, as_int, as_positive_float

__all__ = ["RetargetOptions", "Retargeting", "marker_displacements",
           "align_head_frame", "build_retarget_operator", "describe_options", "retarget",
           "KERNELS", "RETARGET_KERNELS", "DISTANCES"]



#: The warning of a kernel matrix made positive definite by a diagonal shift.
_SHIFT_WARNING = r".*kernel matrix is not positive definite"

#: The kernels of :class:`RetargetOptions`: "auto" (chosen by cross-validation) and :data:`KERNELS`.
RETARGET_KERNELS = ("auto",) + tuple(KERNELS)


@dataclass(frozen=True)
class RetargetOptions:
    """Options of the retargeting stage (see :func:`mocap.retarget.rbf.build_rbf_operator`).

    Attributes
    ----------
    kernel : str
        One of :data:`RETARGET_KERNELS`. ``"auto"`` (the default) tries a
        grid of kernels and shape parameters, Euclidean and geodesic, with
        and without regions (what `distance` and `use_regions` leave open),
        and keeps the one with the lowest leave-one-marker-out error whose
        mesh opens the mouth where the lip markers do
        (:mod:`mocap.retarget.selection`); :attr:`Retargeting.selection`
        records what was tried.
    epsilon : float or None
        Shape parameter, 1/mesh units (compact kernels: support radius
        ``1/epsilon``); None for the scale-invariant kernels' default (and
        with ``"auto"``, which chooses it).
    degree : int or None
        Polynomial degree (-1: none); None for the kernel's default (with ``"auto"``, the
        only choice).
    smoothing : float
        Added to the kernel matrix diagonal (noisy markers), >= 0.
    distance : str or None
        One of :data:`DISTANCES`; None: ``"auto"`` tries both, a given kernel
        uses ``"euclidean"``.
    use_regions : bool or None
        Region masks: the markers of each region in `split_regions` drive only
        that region's vertices (soft region weights), so that the upper lip
        never drives the lower lip; every other face marker forms the
        ``"other"`` group, which drives its own vertices and supports every
        split region's system. None: ``"auto"`` tries both, a given kernel
        uses none.
    split_regions : tuple of str
        Marker-set regions given their own system with `use_regions`
        (default the two lips). Each needs enough markers for the kernel's
        polynomial (4 with degree 1, with the support markers).
    region_width : float or None
        Blend width of the region weights, mesh units (default: the median
        marker spacing).
    chunk_frames : int or None
        Frames per matrix product (default: a 64 MiB budget).
    """

    kernel: str = "auto"
    epsilon: float | None = None
    degree: int | None = None
    smoothing: float = 0.0
    distance: str | None = None
    use_regions: bool | None = None
    split_regions: tuple = ("upper_lip", "lower_lip")
    region_width: float | None = None
    chunk_frames: int | None = None

    def __post_init__(self):
        as_choice(self.kernel, "kernel", RETARGET_KERNELS)
        if self.distance is not None:
            as_choice(self.distance, "distance", DISTANCES)
        if self.use_regions is not None and not isinstance(self.use_regions, (bool, np.bool_)):
            raise InputError(f"use_regions must be true, false or unset, got {self.use_regions!r}")
        if self.kernel == "auto":
            for name in ("epsilon", "degree"):
                if getattr(self, name) is not None:
                    raise InputError(f"{name} is chosen by kernel='auto': name a kernel to set "
                                     f"it, got {name}={getattr(self, name)!r}")
        if self.epsilon is not None:
            as_positive_float(self.epsilon, "epsilon")
        if self.degree is not None:
            as_int(self.degree, "degree", minimum=-1)
        smoothing = as_float_array(self.smoothing, "smoothing", ndim=0, allow_nan=False)
        if smoothing < 0:
            raise InputError(f"smoothing must be >= 0, got {float(smoothing)}")
        if isinstance(self.split_regions, str) or not all(
                isinstance(r, str) for r in self.split_regions):
            raise InputError(f"split_regions must be a tuple of region names, "
                             f"got {self.split_regions!r}")
        if "other" in self.split_regions:
            raise InputError('split_regions cannot name "other": it is the group of the '
                             "markers outside the split regions")
        object.__setattr__(self, "split_regions", tuple(self.split_regions))
        if self.region_width is not None:
            as_positive_float(self.region_width, "region_width")
        if self.chunk_frames is not None:
            as_int(self.chunk_frames, "chunk_frames", minimum=1)

    def resolved(self) -> "RetargetOptions":
        """These options with `distance` and `use_regions` given their defaults.

        Raises
        ------
        InputError
            ``kernel="auto"``: the variant is chosen from a take
            (:func:`retarget`), there is nothing to resolve it from.
        """
        if self.kernel == "auto":
            raise InputError("kernel='auto' is chosen from a take's displacements: use "
                             "retarget() (or mocap.retarget.selection.select_variant)")
        return replace(self, distance=self.distance or "euclidean",
                       use_regions=bool(self.use_regions))


def _binding_rows(binding: Binding, labels) -> np.ndarray:
    lookup = {label: i for i, label in enumerate(binding.labels)}
    absent = [label for label in labels if label not in lookup]
    if absent:
        raise MarkerError(absent[0], f"is not in the binding ({len(absent)} markers "
                                     f"absent: {', '.join(absent[:10])})")
    return np.array([lookup[label] for label in labels], dtype=np.int64)


def marker_displacements(take: Take, binding: Binding, *, neutral_frame,
                         rotation=None, neutral_window: int | None = None) -> np.ndarray:
    """Marker displacements from the neutral frame, in mesh units and mesh axes.

    Parameters
    ----------
    take : Take
        Head-stabilized take (positions (T, M, 3), mm); every marker must be bound.
    binding : Binding
    neutral_frame : int, "auto" or "hold"
        0-based index of the rest frame, or picked
        (:func:`mocap.neutral.find_neutral`); every marker must be visible there.
    rotation : array_like of shape (3, 3), optional
        Head frame to the capture frame the binding was fitted in
        (:func:`align_head_frame`); default identity (the binding was made
        from the stabilized take, ``mocap2mesh bind --stabilize``).
    neutral_window : int, optional
        Frames around `neutral_frame` whose mean is the rest pose p₀
        (:func:`mocap.neutral.neutral_pose`; default the hold's window for
        "hold", else 1); every marker must be visible in them.

    Returns
    -------
    ndarray of shape (T, M, 3), mesh units
        ``scale * R_b @ rotation @ (p(t) - p₀)`` per marker, in the take's
        marker order. NaN where the take is NaN.

    Raises
    ------
    MarkerError
        A marker absent from the binding, or missing in the neutral frame
        (or its window).
    InputError
        A frame index beyond the take, a bad rotation, a window below 1.
    """
    take = as_take(take)
    _binding_rows(binding, take.labels)
    rest = find_neutral(take, neutral_frame, window=neutral_window).pose
    rotation = np.eye(3) if rotation is None else as_float_array(
        rotation, "rotation", shape=(3, 3), allow_nan=False)
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-9) \
            or np.linalg.det(rotation) <= 0:
        raise InputError("rotation must be a proper rotation matrix (orthonormal, det +1)")
    delta = take.positions - rest
    return binding.scale * delta @ (binding.rotation @ rotation).T


def align_head_frame(take: Take, binding: Binding, mesh: Mesh, *,
                     neutral_frame: int) -> np.ndarray:
    """Rotation (3, 3) from the head frame of `take` to the binding's capture frame.

    A binding fitted on a raw capture frame lives in that frame's world axes,
    not in the head frame. This fits the rigid motion taking the neutral
    frame's markers (mm, head frame) to the bound surface points mapped back
    to capture mm and lifted by the binding's skin offset along the face
    normals; for a binding made from the stabilized take it is the identity
    up to noise.

    Parameters
    ----------
    take : Take
        Head-stabilized take; its markers must be bound (at least 3).
    binding : Binding
    mesh : Mesh
        The neutral mesh the binding was made on.
    neutral_frame : int
        A frame where every marker is visible (ideally the one bound).

    Returns
    -------
    ndarray of shape (3, 3)

    Raises
    ------
    MarkerError, InputError
        As :func:`marker_displacements`; collinear markers.
    """
    take = as_take(take)
    rows = _binding_rows(binding, take.labels)
    neutral = find_neutral(take, neutral_frame)
    on_mesh = binding.marker_points(mesh.vertices)[rows]
    normals = face_normals(mesh.vertices, mesh.faces)[binding.face_ids[rows]]
    lifted = on_mesh + binding.skin_offset * binding.scale * normals
    fit = fit_rigid(neutral.pose, binding.to_capture(lifted))
    if not fit.valid:
        raise InputError("the neutral-frame markers are collinear: no head-frame alignment")
    return np.asarray(fit.rotation)


def _face_labels(markerset: MarkerSet, labels) -> tuple:
    labels = tuple(markerset.face_markers if labels is None else labels)
    for label in labels:
        if markerset.region_of(label) == "head":
            raise MarkerError(label, "is a head marker: only face markers drive the face")
    return labels


def _region_map(markerset: MarkerSet, labels: tuple, split_regions: tuple) -> dict:
    """Region name -> labels: each split region, then ``"other"`` (every other marker)."""
    unknown = [r for r in split_regions if r not in markerset.regions]
    if unknown:
        raise InputError(f"split_regions: marker set {markerset.name!r} has no region "
                         f"{unknown[0]!r} (regions: {', '.join(markerset.regions)})")
    regions = {name: [x for x in labels if markerset.region_of(x) == name]
               for name in split_regions}
    split = {x for members in regions.values() for x in members}
    regions["other"] = [x for x in labels if x not in split]
    return regions


def build_retarget_operator(binding: Binding, mesh: Mesh, markerset: MarkerSet,
                            labels: Sequence[str] | None = None,
                            options: RetargetOptions = RetargetOptions(kernel="thin_plate_spline"),
                            *, geometry: MarkerGeometry | None = None) -> RBFOperator:
    """The RBF operator (N, M) from face-marker displacements to vertex displacements.

    Parameters
    ----------
    binding : Binding
        Markers bound to `mesh`'s topology.
    mesh : Mesh
        Neutral mesh, N vertices, mesh units.
    markerset : MarkerSet
        Marker roles: head markers never drive the face; regions for
        ``options.use_regions`` (see :class:`RetargetOptions`).
    labels : sequence of str, optional
        Face markers to use, in the column order of the displacements
        (default: ``markerset.face_markers``).
    options : RetargetOptions
        A named kernel (``"auto"`` is chosen from a take: :func:`retarget`).
    geometry : MarkerGeometry, optional
        The same markers' geometry, whose geodesic distances are then reused.

    Returns
    -------
    RBFOperator
        Centers: the bound points on the neutral mesh (with their faces and
        barycentric coordinates for geodesic distances).

    Raises
    ------
    MarkerError
        A head marker, a marker outside the set, or an unbound marker in `labels`.
    InputError
        Bad options (``kernel="auto"`` among them) or a singular system (from
        :func:`mocap.retarget.rbf.build_rbf_operator`).
    """
    if not isinstance(mesh, Mesh):
        raise InputError(f"mesh must be a mocap.mesh.mesh.Mesh, got {type(mesh).__name__}")
    if not isinstance(options, RetargetOptions):
        raise InputError(f"options must be a RetargetOptions, got {type(options).__name__}")
    options = options.resolved()
    labels = _face_labels(markerset, labels)
    rows = _binding_rows(binding, labels)
    centers = binding.marker_points(mesh.vertices)[rows]
    regions = _region_map(markerset, labels, options.split_regions) if options.use_regions \
        else None
    geodesic = options.distance == "geodesic"
    precomputed = None
    if geodesic and geometry is not None:
        if geometry.labels != labels or not np.allclose(geometry.centers, centers):
            raise InputError("geometry must be of the same markers on the same mesh")
        between, _, fields = geometry.distances("geodesic")
        precomputed = (fields, between)
    return build_rbf_operator(
        centers, mesh.vertices, kernel=options.kernel, epsilon=options.epsilon,
        degree=options.degree, smoothing=options.smoothing, distance=options.distance,
        mesh=(mesh.vertices, mesh.faces) if geodesic else None,
        center_faces=binding.face_ids[rows] if geodesic else None,
        center_bary=binding.barycentric[rows] if geodesic else None,
        regions=regions, region_width=options.region_width, labels=labels,
        precomputed=precomputed)


def describe_options(options: RetargetOptions) -> str:
    """A retargeting variant in words, e.g. ``gaussian ε=0.38/unit, geodesic, regions``."""
    parts = [options.kernel + (f" ε={options.epsilon:.4g}/unit" if options.epsilon else "")]
    if options.degree is not None:
        parts.append(f"degree {options.degree}")
    if options.smoothing:
        parts.append(f"smoothing {options.smoothing:g}")
    parts.append(options.distance or "euclidean")
    if options.use_regions:
        parts.append("regions " + "/".join(options.split_regions))
    return ", ".join(parts)


@dataclass(frozen=True, eq=False)
class Retargeting:
    """A take retargeted onto a mesh; vertex displacements are made on demand.

    Attributes
    ----------
    operator : RBFOperator
        W (N, M).
    displacements : ndarray of shape (T, M, 3), mesh units
        Face-marker displacements from the neutral frame (no NaN).
    labels : tuple of str
        The M face markers, in column order.
    mesh : Mesh
        The neutral mesh (N vertices).
    neutral_frame : int
        0-based index of the rest frame of the take.
    rotation : ndarray of shape (3, 3)
        Head frame to the binding's capture frame (see :func:`align_head_frame`).
    rate : float, Hz
    first_frame : int
        Frame number of the take's first frame.
    chunk_frames : int or None
    options : RetargetOptions or None
        The variant the operator was built with (``kernel="auto"`` resolved).
    selection : RetargetSelection or None
        With ``kernel="auto"``: every variant tried, its score, the choice.
    cross_validation : CrossValidation or None
        Leave-one-marker-out errors of the operator on this take, per marker.
    mouth : MouthOpening or None
        The neutral mesh's lips (with the mesh landmarks).
    lip_witness : LipWitness or None
        The lip markers (with lip markers in the marker set).
    """

    operator: RBFOperator
    displacements: np.ndarray
    labels: tuple
    mesh: Mesh
    neutral_frame: int
    rotation: np.ndarray
    rate: float
    first_frame: int
    chunk_frames: int | None = None
    options: RetargetOptions | None = None
    selection: RetargetSelection | None = None
    cross_validation: CrossValidation | None = None
    mouth: MouthOpening | None = None
    lip_witness: LipWitness | None = None

    @property
    def n_frames(self) -> int:
        """Number of frames T."""
        return len(self.displacements)

    def vertex_displacements(self, *, dtype=np.float32) -> np.ndarray:
        """All vertex displacements (T, N, 3), mesh units (held in memory)."""
        return self.operator.apply(self.displacements, chunk_frames=self.chunk_frames,
                                   dtype=dtype)

    def iter_chunks(self, *, dtype=np.float32) -> Iterator[tuple[slice, np.ndarray]]:
        """``(frames, block)`` pairs: vertex displacements (c, N, 3) of a slice of frames."""
        return self.operator.iter_chunks(self.displacements, chunk_frames=self.chunk_frames,
                                         dtype=dtype)


def retarget(take: Take, binding: Binding, mesh: Mesh, markerset: MarkerSet, *,
             options: RetargetOptions = RetargetOptions(), neutral_frame="auto",
             neutral_window: int | None = None, align: bool = True,
             mouth: MouthOpening | None = None) -> Retargeting:
    """Retarget a head-stabilized take onto a face mesh.

    Parameters
    ----------
    take : Take
        Head-stabilized (``mocap.clean.ingest.ingest(..., IngestOptions(stabilize=True)).take``),
        gap-filled take, mm; head markers and markers outside the set are ignored.
    binding : Binding
        Every face marker of `markerset` bound to `mesh`.
    mesh : Mesh
        Neutral mesh the binding was made on.
    markerset : MarkerSet
    options : RetargetOptions
        ``kernel="auto"`` (the default) chooses the variant on this take.
    neutral_frame : int, "auto" or "hold"
        0-based rest frame, or picked: :func:`mocap.neutral.resolve_neutral_frame`.
    neutral_window : int, optional
        Frames around the rest frame averaged into the rest pose
        (:func:`marker_displacements`).
    align : bool, default True
        Fit the head-to-binding rotation (:func:`align_head_frame`); False
        trusts that the binding was made from the stabilized take.
    mouth : MouthOpening, optional
        The neutral mesh's lips (:func:`mocap.mesh.mouth.find_mouth`): with
        them ``"auto"`` reads each variant's lips where the lip markers open
        the mouth, and the lip check of the chain can run.

    Returns
    -------
    Retargeting
        With the variant used, its cross-validation and (``"auto"``) the selection.

    Raises
    ------
    MarkerError
        A face marker absent from the take or the binding, or missing (NaN)
        in some frame: the message names the first marker and frame (fill gaps first).
    InputError
        Bad options, a frame beyond the take, a singular RBF system, a mouth
        of another mesh, no variant ``"auto"`` could score.
    """
    if not isinstance(options, RetargetOptions):
        raise InputError(f"options must be a RetargetOptions, got {type(options).__name__}")
    take = markerset.own_labels(as_take(take))
    markerset.check_labels(take.labels, source=take.source.path or "the take")
    labels = markerset.face_markers
    face = take.select(labels)
    missing = np.isnan(face.positions).any(axis=2)
    if missing.any():
        t, m = (int(i) for i in np.argwhere(missing)[0])
        raise MarkerError(labels[m], f"is missing (NaN) in frame {take.first_frame + t} "
                                     f"(index {t}; {int(missing.sum())} missing marker-frames "
                                     "in all): fill gaps before retargeting")
    neutral = find_neutral(face, neutral_frame, window=neutral_window)
    frame = neutral.frame
    rotation = align_head_frame(face, binding, mesh, neutral_frame=frame) if align \
        else np.eye(3)
    displacements = marker_displacements(face, binding, neutral_frame=frame, rotation=rotation,
                                         neutral_window=neutral.window)
    geometry = MarkerGeometry.from_binding(binding, mesh, labels)
    if mouth is not None and (not isinstance(mouth, MouthOpening)
                              or mouth.vertex_ids.max() >= mesh.n_vertices):
        raise InputError("mouth must be the MouthOpening of this mesh (mocap.mesh.mouth."
                         "find_mouth)")
    try:
        witness = lip_witness(markerset, labels)
    except InputError:
        witness = None                      # a marker set without lip markers: lips not read
    mm_per_unit = 1.0 / binding.scale
    selection = None
    if options.kernel == "auto":
        has_regions = all(r in markerset.regions for r in options.split_regions)
        selection = select_variant(
            geometry, displacements, mm_per_unit=mm_per_unit,
            regions=_region_map(markerset, labels, options.split_regions)
            if options.use_regions or (options.use_regions is None and has_regions) else None,
            distances=DISTANCES if options.distance is None else (options.distance,),
            use_regions=(False, True) if options.use_regions is None else (options.use_regions,),
            smoothing=options.smoothing, region_width=options.region_width,
            mouth=mouth, witness=witness)
        options = replace(options, **selection.best.options())
    options = options.resolved()
    with warnings.catch_warnings():
        if selection is not None:           # the selection records the shift of its choice
            warnings.filterwarnings("ignore", _SHIFT_WARNING, UserWarning)
        operator = build_retarget_operator(binding, mesh, markerset, labels, options,
                                           geometry=geometry)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", _SHIFT_WARNING, UserWarning)   # the build's, again
        validation = cross_validate(
            geometry, displacements, mm_per_unit=mm_per_unit, variant=describe_options(options),
            kernel=options.kernel, epsilon=options.epsilon, degree=options.degree,
            smoothing=options.smoothing, distance=options.distance,
            regions=_region_map(markerset, labels, options.split_regions)
            if options.use_regions else None, region_width=options.region_width)
    return Retargeting(operator, displacements, labels, mesh, frame, rotation, take.rate,
                       take.first_frame, options.chunk_frames, options=options,
                       selection=selection, cross_validation=validation, mouth=mouth,
                       lip_witness=witness)
