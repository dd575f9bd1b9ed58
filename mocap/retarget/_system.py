"""The RBF systems shared by :mod:`mocap.retarget.rbf` (the operator) and
:mod:`mocap.retarget.cross_validation` (its leave-one-out residuals).

One system per region: kernel matrix ``K`` (m, m) of the region's centers,
polynomial block ``P`` (m, q), kernel and polynomial rows at the evaluation
points ``K_x``, ``P_x``. :func:`solve_system` solves
``[[K + S, P], [P^T, 0]] Z = [[I], [0]]`` once and keeps ``Z`` (the first m
columns of the inverse of the augmented matrix) beside ``W = K_x Z_a + P_x Z_b``;
:func:`solve_systems` does the same for a stack of kernel matrices of the same centers
(one kernel at several shape parameters), one NumPy call for the whole stack.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg

from mocap.errors import InputError
from mocap.mesh.geodesic import HeatGeodesics
from mocap.retarget import _kernels as _k
from mocap.retarget._kernels import COMPACT_KERNELS, KERNELS
from mocap.util.validation import as_choice, as_float_array, as_int, as_positive_float

__all__ = ["PD_FLOOR", "SolvedSystem", "SolvedStack", "check_options", "geodesic_distances",
           "polynomial", "solve_system", "solve_systems", "region_subsets"]

#: When a kernel matrix must be regularized, its smallest eigenvalue (on the
#: polynomial null space) is raised to this fraction of its largest.
PD_FLOOR = 1e-8


@dataclass(frozen=True)
class SolvedSystem:
    """One solved RBF system.

    Attributes
    ----------
    matrix : ndarray of shape (n_points, m)
        The operator at the evaluation points.
    inverse : ndarray of shape (m + q, m)
        The first m columns of the inverse of the augmented system matrix
        (``inverse[:m]`` is symmetric): the RBF coefficients of each unit datum.
    condition, min_eigenvalue, shift : float
        As :class:`mocap.retarget.rbf.RBFSolveInfo` (`condition` NaN when not asked).
    """

    matrix: np.ndarray
    inverse: np.ndarray
    condition: float
    min_eigenvalue: float
    shift: float


@dataclass(frozen=True)
class SolvedStack:
    """k solved RBF systems of the same centers (:func:`solve_systems`).

    Attributes
    ----------
    matrix : ndarray of shape (k, n_points, m)
        Each operator at the evaluation points.
    inverse : ndarray of shape (k, m + q, m)
        As :attr:`SolvedSystem.inverse`, each.
    min_eigenvalue, shift : ndarray of shape (k,)
        As :class:`SolvedSystem`.
    errors : tuple of InputError or None
        Why each system could not be solved (None: it was).
    """

    matrix: np.ndarray
    inverse: np.ndarray
    min_eigenvalue: np.ndarray
    shift: np.ndarray
    errors: tuple


def polynomial(centers, points, degree):
    """Polynomial blocks at centers and points, on the centers' box scaled to [-1, 1]."""
    powers = (_k.monomial_powers(3, degree) if degree >= 0
              else np.zeros((0, 3), dtype=np.int64))
    lo, hi = centers.min(axis=0), centers.max(axis=0)
    shift, scale = (hi + lo) / 2, (hi - lo) / 2
    scale = np.where(scale == 0.0, 1.0, scale)
    return (_k.polynomial_matrix((centers - shift) / scale, powers),
            _k.polynomial_matrix((points - shift) / scale, powers))


def solve_system(region, kcc, kxc, pc, px, smoothing, degree, regularize, *,
                 stacklevel: int = 4, condition: bool = True) -> SolvedSystem:
    """Solve the system for the identity (see the module docstring).

    With `regularize`, a kernel matrix that is not positive definite on the
    null space of ``P^T`` gets a diagonal shift (and a warning at `stacklevel`).
    Without `condition` the system's condition number (an SVD of it, which costs
    more than the solve) is not computed and is NaN.
    """
    m, n_mono = pc.shape
    where = _where(region)
    null = _null_space(where, pc, degree)
    dense_k = (kcc.toarray() if sp.issparse(kcc) else kcc) + np.diag(smoothing)
    eig = np.linalg.eigvalsh(null.T @ dense_k @ null) if m > n_mono else np.array([np.nan])
    lam_min, lam_max, shift, shifted = (x.item() for x in _shift(eig, m, regularize))
    if shifted:
        _warn_shift(where, lam_min, lam_max, shift, stacklevel)
    diag = smoothing + shift
    try:
        if sp.issparse(kcc):
            system = (kcc + sp.diags_array(diag)).tocsc()
            z = scipy.sparse.linalg.splu(system).solve(np.eye(m))
            w = kxc @ z
            cond = np.linalg.cond(system.toarray()) if condition else np.nan
        else:
            system = np.block([[kcc + np.diag(diag), pc], [pc.T, np.zeros((n_mono, n_mono))]])
            # np.linalg.solve: scipy.linalg.solve first inspects the matrix's structure,
            # and takes 100x longer on a compact kernel's sparse blocks
            z = np.linalg.solve(system, np.eye(m + n_mono, m))
            w = kxc @ z[:m] + px @ z[m:]
            cond = np.linalg.cond(system) if condition else np.nan
    except (np.linalg.LinAlgError, RuntimeError) as exc:
        raise _singular(where, exc) from None
    return SolvedSystem(np.asarray(w), np.asarray(z), float(cond), lam_min, float(shift))


def solve_systems(region, kcc, kxc, pc, px, smoothing, degree, regularize, *,
                  stacklevel: int = 4) -> SolvedStack:
    """Solve a stack of systems that share their centers, as :func:`solve_system` each.

    The k systems differ only in their kernel matrices (one kernel family at k
    shape parameters): the polynomial block, its SVD and null space are made
    once, the eigenvalues, the solves and the products at the evaluation points
    are one NumPy call for the whole stack (a loop over the stack in LAPACK and
    BLAS, the same routine on the same matrix as :func:`solve_system`).

    Parameters
    ----------
    region : str
        The system's region (``"all"``: none), for the messages.
    kcc : ndarray of shape (k, m, m)
        Dense kernel matrices of the centers.
    kxc : ndarray of shape (k, n_points, m)
        Kernel rows at the evaluation points.
    pc : ndarray of shape (m, q)
        Polynomial block at the centers.
    px : ndarray of shape (n_points, q)
        Polynomial rows at the evaluation points.
    smoothing : ndarray of shape (m,)
    degree : int
    regularize : bool
        Shift each kernel matrix that is not positive definite on the null
        space of ``P^T`` (a warning at `stacklevel` for each).

    Returns
    -------
    SolvedStack
        A system that is singular has NaN in `matrix` and `inverse` and the
        :class:`InputError` :func:`solve_system` raises for it in `errors`.

    Raises
    ------
    InputError
        A polynomial block with fewer rows than columns or of deficient rank
        (the same for every system of the stack).
    """
    k, m, _ = kcc.shape
    n_mono = pc.shape[1]
    where = _where(region)
    null = _null_space(where, pc, degree)
    on_diagonal = np.arange(m)
    dense_k = kcc.copy()
    dense_k[:, on_diagonal, on_diagonal] += smoothing
    eig = (np.linalg.eigvalsh(null.T @ dense_k @ null) if m > n_mono
           else np.full((k, 1), np.nan))
    lam_min, lam_max, shift, shifted = _shift(eig, m, regularize)
    for i in np.flatnonzero(shifted):
        _warn_shift(where, lam_min[i], lam_max[i], shift[i], stacklevel)
    # [[K + diag(smoothing + shift), P], [P^T, 0]], as solve_system's np.block makes it
    system = np.zeros((k, m + n_mono, m + n_mono))
    system[:, :m, :m] = kcc
    system[:, on_diagonal, on_diagonal] += smoothing + shift[:, None]
    system[:, :m, m:] = pc
    system[:, m:, :m] = pc.T
    identity = np.eye(m + n_mono, m)
    errors = [None] * k
    try:
        z = np.linalg.solve(system, identity)
    except np.linalg.LinAlgError:
        # one singular system fails the whole stack: solve each to know which
        z = np.full((k, m + n_mono, m), np.nan)
        for i in range(k):
            try:
                z[i] = np.linalg.solve(system[i], identity)
            except np.linalg.LinAlgError as exc:
                errors[i] = _singular(where, exc)
    w = kxc @ z[:, :m] + px @ z[:, m:]
    return SolvedStack(w, z, lam_min, shift, tuple(errors))


def _where(region: str) -> str:
    """The start of a message about `region`'s system ("" without regions)."""
    return "" if region == "all" else f"region {region!r}: "


def _null_space(where: str, pc: np.ndarray, degree: int) -> np.ndarray:
    """Orthonormal basis (m, m - q) of the null space of ``P^T``, P of shape (m, q).

    Raises
    ------
    InputError
        Fewer centers than monomials, or centers on which the polynomial block
        loses rank.
    """
    m, n_mono = pc.shape
    if n_mono > m:
        raise InputError(f"{where}{m} centers, but a degree-{degree} "
                         f"polynomial needs at least {n_mono}")
    u, sv, _ = np.linalg.svd(pc, full_matrices=True)
    rank = int(np.sum(sv > sv[0] * max(pc.shape) * np.finfo(float).eps)) if n_mono else 0
    if rank < n_mono:
        raise InputError(f"{where}the centers lie on a low-dimensional set: the "
                         f"polynomial block has rank {rank} < {n_mono}; lower `degree`")
    return u[:, n_mono:]


def _shift(eig: np.ndarray, m: int, regularize: bool) -> tuple:
    """``(smallest, largest |.|, shift, shifted)`` eigenvalue of each system, arrays of shape (...).

    `eig` (..., m - q): the ascending eigenvalues of each kernel matrix on the
    null space of ``P^T`` (NaN when it is empty). With `regularize`, a system
    whose smallest is not clearly positive gets the diagonal shift that raises
    it to :data:`PD_FLOOR` times the largest (`shifted`); the others get 0.
    """
    lam_min = eig[..., 0]
    lam_max = np.nanmax(np.abs(eig), axis=-1, initial=0.0)
    shifted = regularize & (lam_min <= m * np.finfo(float).eps * lam_max)
    shift = np.where(shifted, PD_FLOOR * lam_max - 2.0 * lam_min, 0.0)
    return lam_min, lam_max, shift, shifted


def _warn_shift(where: str, lam_min: float, lam_max: float, shift: float,
                stacklevel: int) -> None:
    """Warn of a shifted system, at `stacklevel` as counted from the caller."""
    warnings.warn(f"{where}the kernel matrix is not positive definite (smallest "
                  f"eigenvalue {lam_min:.3g}, largest {lam_max:.3g}): a diagonal "
                  f"shift of {shift:.3g} was added, which smooths the data; a "
                  "compact or narrower kernel avoids it", stacklevel=stacklevel + 1)


def _singular(where: str, exc: Exception) -> InputError:
    """The error of a system that cannot be solved."""
    return InputError(f"{where}the RBF system is singular ({exc}): coincident "
                      "centers? add smoothing")


def check_options(kernel, epsilon, degree, smoothing, n_centers, *, stacklevel: int = 3):
    """Validated ``(kernel, epsilon, degree, smoothing (n_centers,))``, defaults filled in."""
    kernel = as_choice(kernel, "kernel", KERNELS)
    if epsilon is None:
        if kernel not in _k.SCALE_INVARIANT:
            raise InputError(f"epsilon is required for kernel {kernel!r}"
                             + (" (support radius = 1/epsilon, mesh units)"
                                if kernel in COMPACT_KERNELS else ""))
        epsilon = 1.0
    epsilon = as_positive_float(epsilon, "epsilon")
    min_degree = _k.MIN_DEGREE.get(kernel, -1)
    if degree is None:
        degree = -1 if kernel in COMPACT_KERNELS else max(min_degree, 0)
    degree = as_int(degree, "degree", minimum=-1)
    if kernel in COMPACT_KERNELS and degree != -1:
        raise InputError(f"kernel {kernel!r} is used without a polynomial term "
                         f"(its support would be infinite): degree must be -1, got {degree}")
    if -1 < degree < min_degree:
        warnings.warn(f"degree {degree} is below the minimum {min_degree} of kernel "
                      f"{kernel!r}: the interpolant may not be unique", stacklevel=stacklevel)
    smoothing = as_float_array(smoothing, "smoothing", allow_nan=False)
    if smoothing.ndim == 0:
        smoothing = np.full(n_centers, float(smoothing))
    if smoothing.shape != (n_centers,) or (smoothing < 0).any():
        got = smoothing.tolist() if smoothing.size < 8 else smoothing.shape
        raise InputError(f"smoothing must be a scalar or an array of shape ({n_centers},), "
                         f">= 0, got {got}")
    return kernel, epsilon, degree, smoothing


def geodesic_distances(centers, points, mesh, center_faces, center_bary):
    """Heat-method fields (M, N) from each center and symmetric center distances (M, M).

    Raises
    ------
    InputError
        No or a bad mesh, `points` that are not its vertices, centers not on
        the surface points `center_faces` / `center_bary` give.
    """
    if mesh is None:
        raise InputError("distance='geodesic' needs mesh=(vertices, faces)")
    if not isinstance(mesh, Sequence) or len(mesh) != 2:
        raise InputError("mesh must be a pair (vertices (N, 3), faces (F, 3))")
    geo = HeatGeodesics(*mesh)
    if geo.vertices.shape != points.shape or not np.allclose(geo.vertices, points):
        raise InputError("with distance='geodesic', points must be the mesh vertices "
                         f"({geo.n_vertices} of them)")
    if (center_faces is None) != (center_bary is None):
        raise InputError("give both center_faces and center_bary, or neither")
    if center_faces is None:
        center_faces, center_bary = geo.locate(centers)
    fields = geo.from_surface_points(center_faces, center_bary, symmetric=True)
    faces = np.asarray(center_faces, dtype=np.int64)
    on_mesh = np.einsum("pk,pkd->pd", np.asarray(center_bary, dtype=np.float64),
                        geo.vertices[geo.faces[faces]])
    gap = np.linalg.norm(on_mesh - centers, axis=1)
    tol = 1e-4 * np.linalg.norm(np.ptp(geo.vertices, axis=0))
    if (gap > tol).any():
        bad = int(np.argmax(gap > tol))
        raise InputError(f"center {bad} is {gap[bad]:.4g} from its surface point "
                         f"(face {faces[bad]}); center_faces/center_bary must locate "
                         "the centers on the mesh")
    between = geo.at_surface_points(fields, faces, center_bary)
    # the heat method can return -1e-16 at a source; a distance is never negative
    # (and the thin-plate kernel takes its logarithm)
    return np.maximum(fields, 0.0), np.maximum(0.5 * (between + between.T), 0.0)


def region_subsets(members: dict, support_region: str | None) -> dict:
    """Centers of each region's system: its markers plus the support region's (sorted).

    Regions without markers are left out (they drive nothing).
    """
    support = members.get(support_region, np.zeros(0, dtype=np.int64))
    return {name: np.union1d(idx, support) for name, idx in members.items() if len(idx)}
