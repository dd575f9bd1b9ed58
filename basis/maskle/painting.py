"""Painting a mask by example: mask weights that reproduce given weights on one face.

The transfer is linear (``face = T @ mask``, :class:`~basis.maskle.transfer.TransferOperator`),
so the mask weights that best reproduce reference face weights G solve, per
channel, the bounded least-squares problem

    min_w |T w - g|^2 + λ |L w|^2,  0 <= w <= 1

over the hit vertices, L being the mask's neighbour Laplacian (it fills mask
vertices that no ray reaches, e.g. tongue tips, from their neighbours).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.optimize import lsq_linear

from basis.maskle.fitting import MaskFit, neighbour_mean
from basis.maskle.mask import Mask
from basis.maskle.transfer import transfer_operator
from mocap.errors import InputError
from mocap.mesh.mesh import Mesh
from mocap.util.validation import as_float_array, as_positive_float

__all__ = ["paint_mask"]


def paint_mask(mask: Mask, fit: MaskFit, mesh: Mesh, weights, channels, *, support=None,
               regularization: float = 0.05, **transfer_options) -> Mask:
    """A copy of `mask` whose channels `channels` reproduce `weights` on `mesh`.

    Parameters
    ----------
    mask : Mask
    fit : MaskFit
        `mask` fitted to `mesh`.
    mesh : Mesh
    weights : array_like of shape (N, C)
        Reference weights in [0, 1] of `mesh`'s vertices (NaN rows ignored).
    channels : sequence of str
        The C mask channels to repaint (others are kept).
    support : array_like of bool, shape (V, C), optional
        Mask vertices each channel may weight (0 elsewhere), e.g. a lip bone
        only on its own band (:attr:`~basis.maskle.mask.Mask.lip_bands`), as an
        artist paints it; default everywhere.
    regularization : float
        λ relative to the mean squared column norm of T.
    **transfer_options
        ``max_distance``, ``smoothing`` of :func:`~basis.maskle.transfer.transfer_operator`.

    Returns
    -------
    Mask
    """
    channels = list(channels)
    weights = as_float_array(weights, "weights", shape=(mesh.n_vertices, len(channels)))
    regularization = as_positive_float(regularization, "regularization")
    unknown = [c for c in channels if c not in mask.channel_names]
    if unknown:
        raise InputError(f"mask has no channel {', '.join(unknown)}")
    support = np.ones((mask.n_vertices, len(channels)), bool) if support is None \
        else np.asarray(support, bool)
    if support.shape != (mask.n_vertices, len(channels)):
        raise InputError(f"support must have shape {(mask.n_vertices, len(channels))}, got "
                         f"{support.shape}")
    op = transfer_operator(mask, fit, mesh, **transfer_options)
    rows = op.hit & ~np.isnan(weights).any(axis=1)
    t = op.matrix[rows]
    lam = regularization * float(t.multiply(t).sum()) / mask.n_vertices
    lap = sp.identity(mask.n_vertices) - neighbour_mean(mask)
    system = sp.vstack([t, np.sqrt(lam) * lap]).toarray()
    out = mask.weights.copy()
    for k, name in enumerate(channels):
        rhs = np.concatenate([weights[rows, k], np.zeros(mask.n_vertices)])
        col = np.zeros(mask.n_vertices)
        if support[:, k].any():
            col[support[:, k]] = lsq_linear(system[:, support[:, k]], rhs, bounds=(0.0, 1.0),
                                            method="bvls").x
        out[:, mask.channel_names.index(name)] = col
    return mask.with_weights(np.clip(out, 0.0, 1.0))
