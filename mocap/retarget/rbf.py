"""RBF retargeting as a linear operator: marker displacements -> vertex displacements.

The RBF interpolant of data ``d`` given at M centers (markers on the neutral
mesh), evaluated at N points (mesh vertices), is linear in ``d``. Solving the
system once for the identity gives ``W`` (N, M), the same for x, y and z, so a
whole take costs one matrix product per chunk of frames: ``Xi(t) = W D(t)``.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from mocap.errors import InputError
from mocap.mesh import regions as _regions
from mocap.mesh.regions import RegionWeights, as_region_markers, painted_region_weights
from mocap.retarget import _kernels as _k
from mocap.retarget import _system
from mocap.retarget._kernels import COMPACT_KERNELS, KERNELS
from mocap.util.blas import blas_threads, map_on_blas_threads
from mocap.util.validation import as_choice, as_float_array, as_int

__all__ = ["RBFOperator", "RBFSolveInfo", "build_rbf_operator", "KERNELS", "DISTANCES"]

#: Distances the kernels may be evaluated on.
DISTANCES = ("euclidean", "geodesic")

#: Compact-kernel operators are stored sparse up to this fraction of nonzeros
#: (denser, a sparse product is slower than the dense GEMM).
_SPARSE_DENSITY = 0.25
#: Memory of one block of the result when `chunk_frames` is not given, bytes.
_CHUNK_BYTES = 64 * 2 ** 20


@dataclass(frozen=True)
class RBFSolveInfo:
    """Diagnostics of one solved RBF system (one per region).

    Attributes
    ----------
    region : str
        Region name, or ``"all"`` without regions.
    n_centers : int
        Centers in the system (the region's markers plus support markers).
    condition : float
        2-norm condition number of the system matrix that was solved.
    min_eigenvalue : float
        Smallest eigenvalue of the kernel matrix (smoothing included, shift
        not) restricted to the null space of the polynomial block, i.e. the
        quantity that must be positive for a unique interpolant.
    shift : float
        Diagonal shift added to make it positive definite (0 if none was needed).
    """

    region: str
    n_centers: int
    condition: float
    min_eigenvalue: float
    shift: float


@dataclass(frozen=True)
class RBFOperator:
    """A built RBF retargeting operator ``W`` (N, M); see :func:`build_rbf_operator`.

    Attributes
    ----------
    matrix : ndarray or scipy.sparse.csr_array of shape (n_points, n_centers)
        Vertex displacement = ``matrix @`` marker displacement, per coordinate.
        Sparse (exact zeros dropped) for compact kernels when at most a
        quarter of its entries are nonzero.
    kernel, distance : str
        Options used.
    epsilon : float
        Shape parameter (support radius ``1/epsilon`` for compact kernels), 1/mesh units.
    degree : int
        Degree of the polynomial tail (-1: none).
    smoothing : ndarray of shape (n_centers,)
        Smoothing added to the kernel matrix diagonal.
    labels : tuple of str or None
        Marker labels, used in error messages.
    regions : dict of str to ndarray of int, or None
        Marker indices of each region.
    region_weights : RegionWeights or None
        Per-vertex region weights the region operators were blended with.
    diagnostics : tuple of RBFSolveInfo
        One per solved system.
    """

    matrix: np.ndarray | sp.csr_array
    kernel: str
    epsilon: float
    degree: int
    smoothing: np.ndarray
    distance: str
    labels: tuple[str, ...] | None
    regions: dict[str, np.ndarray] | None
    region_weights: RegionWeights | None
    diagnostics: tuple[RBFSolveInfo, ...]

    @property
    def n_points(self) -> int:
        """Number of evaluation points (vertices), N."""
        return self.matrix.shape[0]

    @property
    def n_centers(self) -> int:
        """Number of centers (markers), M."""
        return self.matrix.shape[1]

    def apply(self, displacements, *, chunk_frames: int | None = None,
              dtype=np.float32, out: np.ndarray | None = None) -> np.ndarray:
        """Vertex displacements of every frame, one GEMM per cache-sized tile of frames.

        Parameters
        ----------
        displacements : array_like of shape (n_frames, n_centers, 3)
            Marker displacements from the neutral pose, any length unit. NaN
            is rejected (fill gaps first).
        chunk_frames : int, optional
            Frames per block of the result (the blocks of :meth:`iter_chunks`,
            ``3 * n_points * chunk_frames`` values; default: 64 MiB of them).
        dtype : float32 or float64
            Precision of the product and of the result.
        out : ndarray of shape (n_frames, n_points, 3), optional
            C-contiguous array of `dtype` to write into.

        Returns
        -------
        ndarray of shape (n_frames, n_points, 3)
            Vertex displacements, in the unit of `displacements`.

        Raises
        ------
        InputError
            Wrong shape, NaN (naming the marker and frame), bad `out` or `dtype`.
        """
        d, chunk, dtype = self._prepare(displacements, chunk_frames, dtype)
        shape = (len(d), self.n_points, 3)
        if out is None:
            out = np.empty(shape, dtype)
        elif (not isinstance(out, np.ndarray) or out.shape != shape or out.dtype != dtype
              or not out.flags.c_contiguous or not out.flags.writeable):
            raise InputError(f"out must be a writeable C-contiguous {dtype} array of "
                             f"shape {shape}")
        for _ in self._blocks(d, chunk, dtype, out):
            pass
        return out

    def iter_chunks(self, displacements, *, chunk_frames: int | None = None,
                    dtype=np.float32) -> Iterator[tuple[slice, np.ndarray]]:
        """Iterate over ``(frames, block)``: a slice of frames and its (c, n_points, 3) result.

        For streaming a take to disk without holding it whole: each block is a
        new array. Parameters and errors as :meth:`apply`; the input is
        validated when this is called, before the first block.
        """
        d, chunk, dtype = self._prepare(displacements, chunk_frames, dtype)
        return self._blocks(d, chunk, dtype, None)

    def _prepare(self, displacements, chunk_frames, dtype):
        d = as_float_array(displacements, "displacements", shape=(None, self.n_centers, 3))
        missing = np.isnan(d).any(axis=2)
        if missing.any():
            frame, marker = (int(i) for i in np.argwhere(missing)[0])
            name = (f"{self.labels[marker]!r} (index {marker})" if self.labels
                    else f"{marker}")
            raise InputError(f"displacements: marker {name} is NaN in frame {frame} "
                             f"({int(missing.sum())} missing marker-frames); fill gaps "
                             "before retargeting")
        dtype = np.dtype(dtype)
        if dtype not in (np.float32, np.float64):
            raise InputError(f"dtype must be float32 or float64, got {dtype}")
        chunk = None if chunk_frames is None else as_int(chunk_frames, "chunk_frames",
                                                         minimum=1)
        return d, chunk, dtype

    def _blocks(self, d, chunk, dtype, out):
        matrix = self.matrix.astype(dtype)
        n_points = matrix.shape[0]
        if chunk is None:
            chunk = max(1, _CHUNK_BYTES // (3 * n_points * dtype.itemsize))
        if sp.issparse(matrix):
            product = _sparse_product(matrix)
        else:
            product = _TiledProduct(np.ascontiguousarray(matrix.T), min(chunk, _TILE_FRAMES))
        for start in range(0, len(d), chunk):
            frames = slice(start, min(start + chunk, len(d)))
            c = frames.stop - frames.start
            block = out[frames] if out is not None else np.empty((c, n_points, 3), dtype)
            product(d[frames], block)
            yield frames, block


#: Frames and vertices of one tile of the dense product: its (3 * frames, vertices)
#: result and W's (M, vertices) columns stay in a core's L2 cache (384 KiB and 132 KiB
#: in float32 for M = 66), so the result is moved to the (frames, vertices, 3) layout
#: from cache and the output is written to memory once.
_TILE_FRAMES = 64
_TILE_POINTS = 512


class _TiledProduct:
    """``block[t] = W @ d[t]`` for a chunk of frames, one GEMM per cache-sized tile.

    The tiles are too small for a threaded BLAS to split well (its threads meet
    at every one of ~10,000 small GEMMs), so with a BLAS of k threads the frames'
    tiles are shared among k Python threads instead, the BLAS running on one
    thread (numpy releases the GIL in the GEMM and the copies). One-thread tiles
    also make the result independent of the thread count, bit for bit.

    Parameters
    ----------
    wt : ndarray of shape (n_centers, n_points)
        W transposed, C-contiguous, in the precision of the product.
    tile_frames : int
        Frames per tile (at most the chunk's frames, to size the scratch).
    """

    def __init__(self, wt: np.ndarray, tile_frames: int):
        self.wt = wt
        self.tile_frames = tile_frames
        self.workers = blas_threads()
        shape = (3 * tile_frames, min(_TILE_POINTS, wt.shape[1]))
        self.scratch = [(np.empty((3, tile_frames, wt.shape[0]), wt.dtype),
                         np.empty(shape, wt.dtype)) for _ in range(self.workers)]

    def __call__(self, d: np.ndarray, block: np.ndarray) -> None:
        """Write the vertex displacements of marker displacements `d` (c, M, 3) into
        `block` (c, N, 3)."""
        starts = range(0, len(d), self.tile_frames)
        workers = min(self.workers, len(starts))
        # each share of the tiles with a scratch of its own, on threads kept for the
        # process (not started anew for each chunk: 0.2-0.7 ms a start on a virtual machine)
        map_on_blas_threads(
            lambda k: self._tiles(d, block, starts[k::workers], *self.scratch[k]),
            range(workers))

    def _tiles(self, d, block, starts, lhs_scratch, scratch) -> None:
        """The tiles of the frames starting at `starts`, with one thread's scratch."""
        n_centers, n_points = self.wt.shape
        for first in starts:
            frames = slice(first, min(first + self.tile_frames, len(d)))
            f = frames.stop - frames.start
            # rows (coordinate, frame) of D: (3f, M) @ W^T tile (M, n) = (W_tile @ D)^T
            lhs = lhs_scratch[:, :f]
            lhs[...] = d[frames].transpose(2, 0, 1)
            lhs = lhs.reshape(3 * f, n_centers)
            for v in range(0, n_points, _TILE_POINTS):
                points = slice(v, min(v + _TILE_POINTS, n_points))
                n = points.stop - points.start
                prod = np.matmul(lhs, self.wt[:, points], out=scratch[:3 * f, :n])
                _interleave(prod.reshape(3, f, n), block[frames, points])


def _sparse_product(matrix):
    """``block[t] = W @ d[t]`` for a chunk of frames, by one sparse product (W CSR)."""
    def product(d, block):
        lhs = np.ascontiguousarray(d.transpose(2, 0, 1), dtype=matrix.dtype)
        rows = lhs.reshape(-1, matrix.shape[1])                         # (3c, M)
        _interleave((matrix @ rows.T).T.reshape(3, len(d), -1), block)
    return product


def _interleave(planes: np.ndarray, block: np.ndarray) -> None:
    """Copy coordinate planes (3, c, n) into `block` (c, n, 3), a view whose rows may
    be strided but whose points and coordinates are adjacent (a slice of a
    C-contiguous array). OpenCV's channel merge does it in one pass that writes each
    output cache line whole; numpy's per-axis strided copies would write every line
    three times, a third each time, and cost the apply a third more than the bare
    GEMM on a take larger than the caches."""
    cv2.merge(list(planes), dst=block)


def build_rbf_operator(centers, points, *, kernel: str = "thin_plate_spline",
                       epsilon: float | None = None, degree: int | None = None,
                       smoothing=0.0, distance: str = "euclidean", mesh=None,
                       center_faces=None, center_bary=None,
                       regions: Mapping[str, Sequence] | None = None,
                       region_weights=None, region_width: float | None = None,
                       support_region: str | None = "other",
                       labels: Sequence[str] | None = None,
                       precomputed: tuple | None = None) -> RBFOperator:
    """Build the RBF operator from marker displacements to vertex displacements.

    Parameters
    ----------
    centers : array_like of shape (n_centers, 3)
        Marker positions on the neutral mesh, mesh units. No NaN.
    points : array_like of shape (n_points, 3)
        Evaluation points (mesh vertices), mesh units. No NaN.
    kernel : str
        One of :data:`KERNELS`. The scipy kernels match
        ``scipy.interpolate.RBFInterpolator`` with the same epsilon, degree and
        smoothing; ``wendland_c2`` and ``bspline_bell`` (the compact cubic
        B-spline of Ju & Lee 2008) have support radius ``1/epsilon`` and no
        polynomial term.
    epsilon : float, optional
        Shape parameter, 1/mesh units. Default 1 for the scale-invariant
        kernels, required for the others.
    degree : int, optional
        Polynomial degree (-1: none). Default: the kernel's minimum
        (scipy's rule), -1 for compact kernels.
    smoothing : float or array_like of shape (n_centers,)
        Added to the kernel matrix diagonal, as in scipy (noisy markers).
    distance : {"euclidean", "geodesic"}
        Geodesic: heat-method distances on `mesh`; `points` must be its vertices.
    mesh : (vertices (n_points, 3), faces (n_faces, 3)), optional
        Triangle mesh for geodesic distances and region weights.
    center_faces, center_bary : array_like of shape (n_centers,) and (n_centers, 3), optional
        Surface location of each center (default: closest point).
    regions : mapping of str to sequence of int or str, optional
        Region name -> marker indices (or labels): a partition of the markers.
        The markers of a region drive only that region's vertices.
    region_weights : RegionWeights or array_like of shape (n_points, n_regions), optional
        Per-vertex region weights (e.g. painted), columns in `regions` order.
        Default: :func:`mocap.mesh.regions.region_weights` on the same distance.
    region_width : float, optional
        Blend width of the default region weights, mesh units. Default: the
        median distance from a center to its nearest other center.
    support_region : str or None
        Region whose markers also support every other region's system
        (ignored when absent from `regions`).
    labels : sequence of str, optional
        Marker labels, for error messages.
    precomputed : (to_points (n_centers, n_points), between (n_centers, n_centers)), optional
        Distances from each center to each point and between the centers,
        mesh units, used instead of computing `distance` (which then only
        names them), e.g. geodesic fields computed once for several
        operators. No NaN, >= 0, `between` symmetric.

    Returns
    -------
    RBFOperator

    Raises
    ------
    InputError
        Bad shapes or options, too few centers for the polynomial, a singular
        system, or an inconsistent mesh or region map.

    Notes
    -----
    With kernel matrix ``K`` (M, M), smoothing ``S``, polynomial blocks ``P``
    (centers) and ``P_x`` (points) and ``K_x`` (N, M), the system
    ``[[K + S, P], [P^T, 0]] Z = [[I], [0]]`` is solved once and
    ``W = K_x Z_a + P_x Z_b``. With regions, ``W = sum_r diag(w_r) W_r`` where
    ``W_r`` is built from region ``r``'s markers (plus the support markers).
    Geodesic distances and the B-spline bell give no positive-definiteness
    guarantee: the kernel matrix is checked on the polynomial null space and,
    when not positive definite, the diagonal is shifted just enough to lift
    its smallest eigenvalue to 1e-8 of its largest (reported in
    ``diagnostics``). Euclidean scipy kernels are solved as scipy does.
    """
    centers = as_float_array(centers, "centers", shape=(None, 3), allow_nan=False)
    points = as_float_array(points, "points", shape=(None, 3), allow_nan=False)
    m = len(centers)
    kernel, epsilon, degree, smoothing = _system.check_options(kernel, epsilon, degree,
                                                               smoothing, m)
    distance = as_choice(distance, "distance", DISTANCES)
    if labels is not None:
        labels = tuple(str(label) for label in labels)
        if len(labels) != m:
            raise InputError(f"labels must name the {m} centers, got {len(labels)}")
    if precomputed is not None:
        to_points, between = _as_precomputed(precomputed, m, len(points))
    elif distance == "geodesic":
        to_points, between = _system.geodesic_distances(centers, points, mesh, center_faces,
                                                        center_bary)
    else:
        to_points = between = None
    if to_points is None and not smoothing.any():
        pairs = cKDTree(centers).query_pairs(0.0, output_type="ndarray")
        if len(pairs):
            i, j = (repr(labels[p]) if labels else int(p) for p in pairs[0])
            raise InputError(f"centers {i} and {j} coincide: the RBF system is singular "
                             "(merge them or add smoothing)")
    compact = kernel in COMPACT_KERNELS
    if to_points is not None:
        kcc = _k.evaluate(kernel, epsilon * between)
        kxc = _k.evaluate(kernel, epsilon * to_points.T)
        if compact:
            kcc, kxc = sp.csr_array(kcc), sp.csr_array(kxc)
    elif compact:
        kcc = _k.compact_kernel_matrix(kernel, centers, centers, epsilon)
        kxc = _k.compact_kernel_matrix(kernel, points, centers, epsilon)
    else:
        kcc = _k.evaluate(kernel, epsilon * cdist(centers, centers))
        kxc = _k.evaluate(kernel, epsilon * cdist(points, centers))
    regularize = to_points is not None or kernel == "bspline_bell"

    def solve(name, subset):
        pc, px = _system.polynomial(centers[subset], points, degree)
        sub_kcc = kcc[subset][:, subset] if compact else kcc[np.ix_(subset, subset)]
        solved = _system.solve_system(name, sub_kcc, kxc[:, subset], pc, px,
                                      smoothing[subset], degree, regularize)
        return solved.matrix, RBFSolveInfo(name, len(subset), solved.condition,
                                           solved.min_eigenvalue, solved.shift)

    weights = None
    if regions is None:
        matrix, info = solve("all", np.arange(m))
        diagnostics = (info,)
    else:
        members = as_region_markers(regions, m, labels=labels)
        if to_points is None:
            to_points, between = cdist(centers, points), cdist(centers, centers)
        weights = _as_region_weights(region_weights, members, to_points, between,
                                     region_width, labels)
        for col, (name, idx) in enumerate(members.items()):
            if len(idx) == 0 and weights.weights[:, col].any():
                raise InputError(f"region {name!r} has no markers but positive "
                                 "region weights: nothing would drive those vertices")
        matrix = np.zeros((len(points), m))
        diagnostics = []
        for name, subset in _system.region_subsets(members, support_region).items():
            w_r, info = solve(name, subset)
            matrix[:, subset] += weights[name][:, None] * w_r
            diagnostics.append(info)
        diagnostics = tuple(diagnostics)
    if compact and np.count_nonzero(matrix) <= _SPARSE_DENSITY * matrix.size:
        matrix = sp.csr_array(matrix)
    return RBFOperator(matrix, kernel, epsilon, degree, smoothing, distance, labels,
                       None if regions is None else members, weights, diagnostics)


def _as_region_weights(given, members, to_points, between, width, labels) -> RegionWeights:
    names = tuple(members)
    n_points = to_points.shape[1]
    if given is None:
        if width is None:
            spacing = between + np.diag(np.full(len(between), np.inf))
            width = float(np.median(spacing.min(axis=1)))
        return _regions.region_weights(to_points, members, width=width, labels=labels)
    if not isinstance(given, RegionWeights):
        given = painted_region_weights(given, names)
    if given.names != names or given.weights.shape != (n_points, len(names)):
        raise InputError(f"region_weights must have regions {list(names)} in that order "
                         f"and {n_points} rows, got {list(given.names)} and shape "
                         f"{given.weights.shape}")
    return given


def _as_precomputed(precomputed, n_centers: int, n_points: int):
    """Validated (to_points (M, N), between (M, M)) distances."""
    if not isinstance(precomputed, Sequence) or len(precomputed) != 2:
        raise InputError("precomputed must be a pair (to_points (n_centers, n_points), "
                         "between (n_centers, n_centers))")
    to_points = as_float_array(precomputed[0], "precomputed to_points",
                               shape=(n_centers, n_points), allow_nan=False)
    between = as_float_array(precomputed[1], "precomputed between",
                             shape=(n_centers, n_centers), allow_nan=False)
    if (to_points < 0).any() or (between < 0).any():
        raise InputError("precomputed distances must be >= 0")
    if not np.allclose(between, between.T, rtol=0.0, atol=1e-12 * max(1.0, between.max())):
        raise InputError("precomputed between-center distances must be symmetric")
    return to_points, between
