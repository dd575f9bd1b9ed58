"""Weights fitted on every vertex of the mesh through the RBF operator, without forming W·D."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from fit.solve.weights import WeightSolution, solve_weights
from mocap.errors import InputError

__all__ = ["solve_mesh_space"]


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
