"""Leave-one-marker-out cross-validation of the RBF retargeting operator, in closed form.

Each face marker is held out in turn: the operator is rebuilt from the other
markers and the mesh it drives is read at the held-out marker's bound surface
point, in every frame. The difference from the marker's own displacement is
what the operator gets wrong where it has no marker, a score that needs no
ground truth. Rebuilding the operator M times is not needed: the held-out
prediction is linear in the other markers' displacements, ``f̂ = P f`` with
an (M, M) matrix ``P`` (zero diagonal) that comes from one solve per region
(Rippa 1999), so the whole take costs one product and the sum of squared
residuals of every marker only the (M, M) Gram matrix of the displacements.

NaN policy: displacements must be complete (as :func:`mocap.retarget.retargeting.retarget`
gives them); :meth:`LeaveOneOut.residuals` rejects NaN.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.distance import cdist

from mocap.errors import InputError
from mocap.mesh.regions import as_region_markers, region_weights
from mocap.retarget import _kernels as _k
from mocap.retarget import _system
from mocap.retarget.rbf import DISTANCES
from mocap.util.validation import as_choice, as_float_array

__all__ = ["MarkerGeometry", "LeaveOneOut", "leave_one_out", "leave_one_out_many",
           "gram_matrix", "CrossValidation", "cross_validate"]

#: A held-out marker whose polynomial leverage is this close to 1 leaves the
#: others unable to fit the polynomial tail: its held-out system is singular.
_LEVERAGE_TOL = 1e-9


@dataclass(frozen=True, eq=False)
class MarkerGeometry:
    """Markers bound on a mesh, with the distances every variant tried shares.

    Attributes
    ----------
    centers : ndarray of shape (M, 3)
        Bound surface points of the markers, mesh units.
    corners : ndarray of int, shape (M, 3)
        Vertices of each marker's triangle.
    bary : ndarray of shape (M, 3)
        Barycentric coordinates of each marker in its triangle.
    face_ids : ndarray of int, shape (M,)
    vertices : ndarray of shape (N, 3), faces : ndarray of int, shape (F, 3)
        The neutral mesh, mesh units.
    labels : tuple of str
    """

    centers: np.ndarray
    corners: np.ndarray
    bary: np.ndarray
    face_ids: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray
    labels: tuple
    _cache: dict = field(default_factory=dict, init=False, repr=False)

    @classmethod
    def from_binding(cls, binding, mesh, labels: Sequence[str]) -> "MarkerGeometry":
        """The geometry of markers `labels` of a :class:`mocap.bind.Binding` on `mesh`.

        Raises
        ------
        InputError
            A label the binding does not have, or a mesh of another topology.
        """
        lookup = {label: i for i, label in enumerate(binding.labels)}
        absent = [label for label in labels if label not in lookup]
        if absent:
            raise InputError(f"marker {absent[0]!r} is not in the binding "
                             f"({len(absent)} absent)")
        rows = np.array([lookup[label] for label in labels], dtype=np.int64)
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        if binding.vertex_ids.max() >= len(vertices):
            raise InputError(f"the binding indexes vertex {int(binding.vertex_ids.max())}, the "
                             f"mesh has {len(vertices)}: bound to another topology")
        return cls(centers=binding.marker_points(vertices)[rows],
                   corners=np.asarray(binding.vertex_ids, np.int64)[rows],
                   bary=np.asarray(binding.barycentric, np.float64)[rows],
                   face_ids=np.asarray(binding.face_ids, np.int64)[rows],
                   vertices=vertices, faces=np.asarray(mesh.faces, np.int64),
                   labels=tuple(labels))

    @property
    def n_markers(self) -> int:
        """Number of markers M."""
        return len(self.centers)

    def distances(self, distance: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """``(between (M, M), to_corners (M, 3M), fields (M, N) or None)``, mesh units.

        ``to_corners[j, 3k + i]`` is the distance from marker j to corner i of
        marker k's triangle; `fields` are the geodesic distance fields from
        every marker over the mesh (computed once, see
        :func:`mocap.retarget.rbf.build_rbf_operator`'s ``precomputed``).
        """
        distance = as_choice(distance, "distance", DISTANCES)
        if distance not in self._cache:
            if distance == "geodesic":
                fields, between = _system.geodesic_distances(
                    self.centers, self.vertices, (self.vertices, self.faces), self.face_ids,
                    self.bary)
                entry = (between, fields[:, self.corners.ravel()], fields)
            else:
                entry = (cdist(self.centers, self.centers),
                         cdist(self.centers, self.vertices[self.corners.ravel()]), None)
            self._cache[distance] = entry
        return self._cache[distance]

    def to_vertices(self, distance: str, vertex_ids) -> np.ndarray:
        """Distances (M, len(vertex_ids)) from every marker to some mesh vertices, mesh units."""
        ids = np.asarray(vertex_ids, dtype=np.int64)
        if ids.ndim != 1 or (len(ids) and (ids.min() < 0 or ids.max() >= len(self.vertices))):
            raise InputError(f"vertex_ids must be a 1-D array of vertex ids in "
                             f"0..{len(self.vertices) - 1}")
        _, _, fields = self.distances(distance)
        return fields[:, ids] if fields is not None else cdist(self.centers, self.vertices[ids])


@dataclass(frozen=True, eq=False)
class LeaveOneOut:
    """Held-out predictions of every marker: ``f̂ = matrix @ f`` per coordinate and frame.

    Attributes
    ----------
    matrix : ndarray of shape (M, M)
        Row k: the mesh at marker k's bound point, from the operator rebuilt
        without marker k, as a linear map of the markers' displacements (zero
        diagonal). NaN rows for the markers in `singular`.
    singular : dict of str to str
        Markers that cannot be held out (the others leave a singular system), with why.
    labels : tuple of str
    region_width : float or None
        Blend width the region weights were made with (held fixed), mesh units.
    shifts : dict of str to float
        Diagonal shift of each region's system (held fixed when a marker is out).
    rows : ndarray of shape (n_vertices, M) or None
        The full operator at the `vertices` asked for (no marker held out).
    """

    matrix: np.ndarray
    singular: dict
    labels: tuple
    region_width: float | None
    shifts: dict
    rows: np.ndarray | None = None

    def residuals(self, displacements) -> np.ndarray:
        """Held-out residuals ``f - f̂`` (T, M, 3) of displacements (T, M, 3), their units.

        Raises
        ------
        InputError
            Wrong shape or NaN.
        """
        d = as_float_array(displacements, "displacements", shape=(None, len(self.labels), 3),
                           allow_nan=False)
        return d - np.matmul(self.matrix, d)

    def sum_squares(self, gram) -> np.ndarray:
        """Sum over frames and coordinates of each marker's squared residual (M,).

        ``gram`` is :func:`gram_matrix` of the displacements: with ``R = I - P``,
        the sums are ``diag(R G R^T)``, exact, in O(M^3) whatever the length.
        """
        gram = as_float_array(gram, "gram", shape=(len(self.labels),) * 2)
        r = np.eye(len(self.labels)) - self.matrix
        return np.sum((r @ gram) * r, axis=1)


def gram_matrix(displacements) -> np.ndarray:
    """``G = Σ_t Σ_c f_c(t) f_c(t)^T`` (M, M) of displacements (T, M, 3), no NaN.

    From the (3M, 3M) Gram matrix of the frames as rows (one symmetric product of the
    array as it is, no transposed copy of it), summed over the coordinate pairs
    ``(3i + c, 3j + c)``.
    """
    d = as_float_array(displacements, "displacements", shape=(None, None, 3), allow_nan=False,
                       copy=False)
    flat = np.ascontiguousarray(d).reshape(len(d), -1)
    m = d.shape[1]
    return np.einsum("icjc->ij", (flat.T @ flat).reshape(m, 3, m, 3))


def _held_out_region_weights(to_corners, members, width) -> np.ndarray:
    """Region weights (M, 3, R) at each marker's corners with that marker left out.

    Marker k's distance to its own corners is made too large to count (more
    than `width` beyond every other distance), which is exactly leaving it out
    of :func:`mocap.mesh.regions.region_weights`.
    """
    n_markers = to_corners.shape[0]
    far = to_corners.max() + 2.0 * width + 1.0
    masked = to_corners.copy()
    owner = np.repeat(np.arange(n_markers), 3)
    masked[owner, np.arange(masked.shape[1])] = far
    weights = region_weights(masked, members, width=width).weights
    return weights.reshape(n_markers, 3, -1)


def _leverage(p: np.ndarray) -> np.ndarray:
    """Diagonal of the hat matrix of the polynomial block P (m, q): 1 where a row is essential."""
    if p.shape[1] == 0:
        return np.zeros(len(p))
    q, _ = np.linalg.qr(p)
    return np.sum(q * q, axis=1)


def leave_one_out(geometry: MarkerGeometry, *, kernel: str = "thin_plate_spline",
                  epsilon: float | None = None, degree: int | None = None, smoothing=0.0,
                  distance: str = "euclidean", regions: Mapping[str, Sequence] | None = None,
                  region_width: float | None = None, support_region: str | None = "other",
                  vertices=None) -> LeaveOneOut:
    """The held-out prediction matrix of one operator variant (closed form).

    Parameters
    ----------
    geometry : MarkerGeometry
    kernel, epsilon, degree, smoothing, distance, regions, region_width, support_region
        As :func:`mocap.retarget.rbf.build_rbf_operator` (default region weights).
    vertices : array_like of int, optional
        Mesh vertices at which to also evaluate the full operator
        (:attr:`LeaveOneOut.rows`), e.g. the lips'.

    Returns
    -------
    LeaveOneOut

    Raises
    ------
    InputError
        Bad options, or a full system that cannot be solved (as the operator's).

    Notes
    -----
    For one system with augmented matrix ``A`` (kernel, smoothing and shift,
    polynomial), ``Z = A^{-1}[:, :m]`` and ``H = Z[:m]``: the interpolant built
    without center k is the full one minus ``e_k`` times the full operator's
    column k, ``s^{(k)}(y) = s(y) - W(y, k) e_k``, where ``e_k = (H f)_k / H_kk``
    is the held-out residual at the center itself (Rippa 1999; the augmented
    inverse gives it with a polynomial tail too: Fasshauer & Zhang 2007). The
    mesh at marker k's point is the barycentric blend of ``s^{(k)}`` at its
    triangle's corners. With regions, ``W = Σ_r diag(w_r) W_r``: every system
    that holds k is corrected the same way, and the region weights at k's
    corners are made again without k (the blend width held at the full
    layout's). The geodesic distances and each system's diagonal shift are
    those of the full layout.

    References
    ----------
    S. Rippa, "An algorithm for selecting a good value for the parameter c in
    radial basis function interpolation", Adv. Comput. Math. 11 (1999) 193-210.
    G. E. Fasshauer, J. G. Zhang, "On choosing 'optimal' shape parameters for
    RBF approximation", Numer. Algorithms 45 (2007) 345-368.
    """
    if not isinstance(geometry, MarkerGeometry):
        raise InputError(f"geometry must be a MarkerGeometry, got {type(geometry).__name__}")
    kernel, epsilon, degree, smoothing = _system.check_options(kernel, epsilon, degree,
                                                               smoothing, geometry.n_markers)
    layout = _Layout.make(geometry, distance, regions, region_width, support_region, vertices)
    kcc, kq = layout.kernel_matrices(kernel, np.array([epsilon]))
    matrix, rows_out, singular, shifts = layout.accumulators(1)
    for name, subset in layout.systems.items():
        pc, pq = _system.polynomial(geometry.centers[subset], layout.points, degree)
        solved = _system.solve_system(name, kcc[0][np.ix_(subset, subset)], kq[0][:, subset],
                                      pc, pq, smoothing[subset], degree,
                                      layout.regularize(kernel), stacklevel=3, condition=False)
        shifts[0][name] = solved.shift
        layout.hold_out(name, subset, pc, degree, solved.matrix[None], solved.inverse[None],
                        matrix, rows_out, singular)
    return layout.results(matrix, rows_out, singular, shifts)[0]


def leave_one_out_many(geometry: MarkerGeometry, *, kernel: str = "thin_plate_spline",
                       epsilons: Sequence = (None,), degree: int | None = None,
                       smoothing=0.0, distance: str = "euclidean",
                       regions: Mapping[str, Sequence] | None = None,
                       region_width: float | None = None, support_region: str | None = "other",
                       vertices=None) -> list:
    """The held-out prediction matrices of one kernel at several shape parameters.

    What :func:`leave_one_out` gives for each of `epsilons`, the variants solved
    together: they share the distances, the region weights, the polynomial
    blocks and their null spaces, and each region's k systems are stacks of
    (m, m) matrices, so that one NumPy call evaluates the kernels, finds the
    eigenvalues or solves the systems of all k variants
    (:func:`mocap.retarget._system.solve_systems`). Each variant's diagonal
    shift (and its warning), singular markers and result are those of
    :func:`leave_one_out`, to rounding.

    Parameters
    ----------
    geometry : MarkerGeometry
    kernel : str
    epsilons : sequence of float or None, length k
        The shape parameters, 1/mesh units (None: the kernel's default).
    degree, smoothing, distance, regions, region_width, support_region, vertices
        As :func:`leave_one_out`, the same for every variant.

    Returns
    -------
    list of LeaveOneOut or InputError, length k
        Entry i: ``leave_one_out(geometry, epsilon=epsilons[i], ...)``, or the
        :class:`InputError` it raises (bad options, a singular system, a
        polynomial the centers cannot fit), in the manner of
        ``asyncio.gather(..., return_exceptions=True)``.

    Raises
    ------
    InputError
        `geometry` is not a MarkerGeometry.

    Examples
    --------
    >>> import numpy as np
    >>> v = np.array([[0., 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [.5, .5, .2]])
    >>> f = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    >>> geo = MarkerGeometry(v[f[:, 0]], f, np.tile([1.0, 0, 0], (4, 1)), np.arange(4), v, f,
    ...                      tuple("abcd"))
    >>> out = leave_one_out_many(geo, kernel="gaussian", epsilons=[0.5, 1.0, -1.0])
    >>> [type(x).__name__ for x in out]
    ['LeaveOneOut', 'LeaveOneOut', 'InputError']
    >>> bool(np.allclose(out[1].matrix, leave_one_out(geo, kernel="gaussian",
    ...                                               epsilon=1.0).matrix))
    True
    """
    if not isinstance(geometry, MarkerGeometry):
        raise InputError(f"geometry must be a MarkerGeometry, got {type(geometry).__name__}")
    out: list = [None] * len(epsilons)
    valid, checked = [], None
    for i, epsilon in enumerate(epsilons):
        try:
            checked = _system.check_options(kernel, epsilon, degree, smoothing,
                                            geometry.n_markers)
            valid.append((i, checked[1]))
        except InputError as exc:
            out[i] = exc
    if not valid:
        return out
    kernel, _, degree, smoothing = checked          # the same for every epsilon
    index = [i for i, _ in valid]
    try:
        layout = _Layout.make(geometry, distance, regions, region_width, support_region,
                              vertices)
    except InputError as exc:
        for i in index:
            out[i] = exc
        return out
    kcc, kq = layout.kernel_matrices(kernel, np.array([e for _, e in valid]))
    matrix, rows_out, singular, shifts = layout.accumulators(len(valid))
    failed: list = [None] * len(valid)
    for name, subset in layout.systems.items():
        pc, pq = _system.polynomial(geometry.centers[subset], layout.points, degree)
        try:
            # every variant, also one already failed in an earlier region (its
            # first error is the one kept): the stack keeps its shape
            solved = _system.solve_systems(name, kcc[:, subset[:, None], subset],
                                           kq[:, :, subset], pc, pq, smoothing[subset],
                                           degree, layout.regularize(kernel), stacklevel=3)
        except InputError as exc:                   # the polynomial: every variant's
            failed = [exc if f is None else f for f in failed]
            break
        failed = [f if f is not None else e for f, e in zip(failed, solved.errors)]
        for j, shift in enumerate(solved.shift):
            shifts[j][name] = float(shift)
        layout.hold_out(name, subset, pc, degree, solved.matrix, solved.inverse, matrix,
                        rows_out, singular)
    for i, result, error in zip(index, layout.results(matrix, rows_out, singular, shifts),
                                failed):
        out[i] = result if error is None else error
    return out


@dataclass(frozen=True, eq=False)
class _Layout:
    """What every variant of one geometry, distance and region map shares.

    ``points``: the 3M corners of the markers' triangles, then the P vertices
    asked for (mesh coordinates); ``to_points`` (3M + P, M) their distances to
    the markers; ``blend`` (M, 3, R) the region weights at each marker's corners
    with that marker left out, ``extra_blend`` (P, R) at the P vertices.
    """

    geometry: MarkerGeometry
    distance: str
    between: np.ndarray
    to_points: np.ndarray
    points: np.ndarray
    n_corners: int
    has_extra: bool
    members: dict
    systems: dict
    blend: np.ndarray
    extra_blend: np.ndarray
    width: float | None

    @classmethod
    def make(cls, geometry, distance, regions, region_width, support_region, vertices):
        """The layout; InputError for a bad distance, region map or vertex ids."""
        m = geometry.n_markers
        between, to_corners, _ = geometry.distances(distance)
        extra = np.zeros(0, dtype=np.int64) if vertices is None else np.asarray(vertices)
        to_extra = geometry.to_vertices(distance, extra)
        points = geometry.vertices[np.r_[geometry.corners.ravel(), extra]]
        width = None
        if regions is None:
            members = {"all": np.arange(m)}
            systems = dict(members)
            blend = np.ones((m, 3, 1))
            extra_blend = np.ones((len(extra), 1))
        else:
            members = as_region_markers(regions, m, labels=geometry.labels)
            systems = _system.region_subsets(members, support_region)
            if region_width is None:
                spacing = between + np.diag(np.full(m, np.inf))
                region_width = float(np.median(spacing.min(axis=1)))
            width = region_width
            blend = _held_out_region_weights(to_corners, members, width)
            extra_blend = (region_weights(to_extra, members, width=width).weights if len(extra)
                           else np.zeros((0, len(members))))
        return cls(geometry, distance, between, np.c_[to_corners, to_extra].T, points,
                   to_corners.shape[1], vertices is not None, members, systems, blend,
                   extra_blend, width)

    def regularize(self, kernel: str) -> bool:
        """Whether the systems are shifted when not positive definite (as the operator's)."""
        return self.distance == "geodesic" or kernel == "bspline_bell"

    def kernel_matrices(self, kernel: str, epsilons: np.ndarray) -> tuple:
        """Kernel matrices (k, M, M) of the markers and rows (k, 3M + P, M) at the points."""
        scale = epsilons[:, None, None]
        return (_k.evaluate(kernel, scale * self.between),
                _k.evaluate(kernel, scale * self.to_points))

    def accumulators(self, k: int) -> tuple:
        """Zero held-out matrices (k, M, M), rows (k, P, M); k empty dicts of singular
        markers and of region shifts."""
        m = self.geometry.n_markers
        return (np.zeros((k, m, m)), np.zeros((k, len(self.extra_blend), m)),
                [{} for _ in range(k)], [{} for _ in range(k)])

    def hold_out(self, name, subset, pc, degree, w, inverse, matrix, rows_out,
                 singular) -> None:
        """Add region `name`'s share to k variants' held-out rows, in place.

        Parameters
        ----------
        name : str
        subset : ndarray of int, shape (n,)
            The region system's centers (markers).
        pc : ndarray of shape (n, q)
            Its polynomial block.
        degree : int
        w : ndarray of shape (k, 3M + P, n)
            Each variant's operator at the points.
        inverse : ndarray of shape (k, n + q, n)
            Each variant's :attr:`mocap.retarget._system.SolvedSystem.inverse`.
        matrix, rows_out, singular
            Of :meth:`accumulators`, added to.
        """
        g = self.geometry
        m, n_sub = g.n_markers, len(subset)
        col = list(self.members).index(name)
        rows_out[:, :, subset] += self.extra_blend[:, col, None] * w[:, self.n_corners:]
        at_corners = w[:, :self.n_corners].reshape(len(w), m, 3, n_sub)
        rows = np.sum((g.bary * self.blend[:, :, col])[:, :, None] * at_corners, axis=2)
        h = inverse[:, :n_sub]                                             # (k, n, n)
        own = rows[:, subset, np.arange(n_sub)]                            # (k, n)
        diag = np.diagonal(h, axis1=1, axis2=2)
        essential = _leverage(pc) > 1.0 - _LEVERAGE_TOL
        where = "" if name == "all" else f" of region {name!r}"
        for found, cannot in zip(singular, essential | (diag == 0.0)):
            for k in subset[cannot]:
                found.setdefault(g.labels[k], (
                    f"without it the {n_sub - 1} other centers{where} cannot fit the "
                    f"degree-{degree} polynomial"))
        safe = np.where(diag == 0.0, 1.0, diag)
        rows[:, subset] -= (own / safe)[:, :, None] * h
        matrix[:, :, subset] += rows

    def results(self, matrix, rows_out, singular, shifts) -> list:
        """The k LeaveOneOut of the accumulated rows (NaN rows for singular markers)."""
        out = []
        for held, rows, found, shift in zip(matrix, rows_out, singular, shifts):
            held[[self.geometry.labels.index(label) for label in found]] = np.nan
            out.append(LeaveOneOut(matrix=held, singular=found, labels=self.geometry.labels,
                                   region_width=self.width, shifts=shift,
                                   rows=rows if self.has_extra else None))
        return out


@dataclass(frozen=True, eq=False)
class CrossValidation:
    """Held-out errors of one retargeting operator on a take, per marker, in mm.

    Attributes
    ----------
    loo : LeaveOneOut
        The held-out prediction matrix.
    marker_rms : ndarray of shape (M,), mm
        RMS over the frames of each held-out marker's error (its 3-D distance
        from the prediction); NaN for markers that cannot be held out.
    motion_rms : ndarray of shape (M,), mm
        RMS over the frames of each marker's displacement from the rest pose
        (what predicting nothing would miss).
    n_frames : int
    mm_per_unit : float
        Millimetres per mesh unit of the capture.
    variant : str
        The operator, in words.
    """

    loo: LeaveOneOut
    marker_rms: np.ndarray
    motion_rms: np.ndarray
    n_frames: int
    mm_per_unit: float
    variant: str = ""

    @property
    def labels(self) -> tuple:
        """The M markers."""
        return self.loo.labels

    @property
    def rms(self) -> float:
        """RMS held-out error over every scored marker and frame, mm."""
        ok = np.isfinite(self.marker_rms)
        return float(np.sqrt(np.mean(self.marker_rms[ok] ** 2))) if ok.any() else np.nan

    @property
    def relative(self) -> float:
        """:attr:`rms` over the RMS motion of the same markers (1: no better than no motion)."""
        ok = np.isfinite(self.marker_rms)
        motion = float(np.sqrt(np.mean(self.motion_rms[ok] ** 2))) if ok.any() else np.nan
        return self.rms / motion if motion > 0 else np.nan

    def by_region(self, regions: Mapping[str, Sequence[str]]) -> list[dict]:
        """Pooled errors per region: ``region``, ``markers``, ``rms_mm``, ``motion_mm``,
        ``relative``.

        Parameters
        ----------
        regions : mapping of str to sequence of str
            Region name -> marker labels (e.g. a marker set's ``regions``);
            labels that are not among :attr:`labels` are ignored, empty regions left out.
        """
        column = {label: i for i, label in enumerate(self.labels)}
        out = []
        for name, members in regions.items():
            idx = [column[x] for x in members if x in column]
            idx = [i for i in idx if np.isfinite(self.marker_rms[i])]
            if not idx:
                continue
            rms = float(np.sqrt(np.mean(self.marker_rms[idx] ** 2)))
            motion = float(np.sqrt(np.mean(self.motion_rms[idx] ** 2)))
            out.append({"region": name, "markers": len(idx), "rms_mm": rms,
                        "motion_mm": motion, "relative": rms / motion if motion > 0 else np.nan})
        return out

    def residual_norms(self, displacements) -> np.ndarray:
        """Each held-out marker's error in every frame (T, M), mm.

        Parameters
        ----------
        displacements : array_like of shape (T, M, 3), mesh units
            The displacements the scores were made from; no NaN.
        """
        return self.mm_per_unit * np.linalg.norm(self.loo.residuals(displacements), axis=-1)

    def summary(self) -> dict:
        """Plain data for a manifest: the pooled and per-marker errors (NaN as None)."""
        def plain(x):
            return None if not np.isfinite(x) else round(float(x), 6)
        return {"variant": self.variant, "rms_mm": plain(self.rms),
                "relative": plain(self.relative),
                "markers": {label: plain(v) for label, v in zip(self.labels, self.marker_rms)},
                "singular": dict(self.loo.singular)}


def cross_validate(geometry: MarkerGeometry, displacements, *, mm_per_unit: float,
                   variant: str = "", **options) -> CrossValidation:
    """Leave-one-marker-out errors of one operator variant on a take.

    Parameters
    ----------
    geometry : MarkerGeometry
    displacements : array_like of shape (T, M, 3), mesh units
        The take's marker displacements from the rest pose; no NaN.
    mm_per_unit : float
        Millimetres per mesh unit (1 / the binding's scale).
    variant : str
        The operator in words, kept for reports.
    **options
        The operator's options, as :func:`leave_one_out`.

    Returns
    -------
    CrossValidation

    Examples
    --------
    Four markers on a square that move as one: any other three predict the fourth.

    >>> import numpy as np
    >>> v = np.array([[0., 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [.5, .5, .2]])
    >>> f = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    >>> corners = f[[0, 1, 2, 3]]
    >>> bary = np.tile([1.0, 0.0, 0.0], (4, 1))
    >>> geo = MarkerGeometry(v[corners[:, 0]], corners, bary, np.arange(4), v, f, tuple("abcd"))
    >>> d = np.tile([0.0, 0.0, 1.0], (10, 4, 1))
    >>> cv = cross_validate(geo, d, mm_per_unit=10.0, kernel="gaussian", epsilon=1.0)
    >>> round(cv.rms, 9)
    0.0
    """
    d = as_float_array(displacements, "displacements", shape=(None, geometry.n_markers, 3),
                       allow_nan=False, copy=False)         # only read
    loo = leave_one_out(geometry, **options)
    gram = gram_matrix(d)
    n = max(len(d), 1)
    marker = mm_per_unit * np.sqrt(np.maximum(loo.sum_squares(gram), 0.0) / n)
    motion = mm_per_unit * np.sqrt(np.diag(gram) / n)
    return CrossValidation(loo=loo, marker_rms=marker, motion_rms=motion, n_frames=len(d),
                           mm_per_unit=float(mm_per_unit), variant=variant)
