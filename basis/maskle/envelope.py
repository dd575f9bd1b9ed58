"""The envelope baseline: weights from the distance to each bone, as DCC "closest distance" binds.

Each bone has an origin (template frame, mapped onto a face by the Maskle's
landmark placement) and an inner and outer radius (template cm): the weight is
1 inside the inner radius, 0 beyond the outer, a smooth step between. Bones
are weighted independently (no normalization across bones).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from basis.maskle.fitting import MaskFit
from mocap.util.validation import as_float_array

__all__ = ["Envelope", "envelope_weights", "calibrate_envelope"]

#: Default inner and outer radius of a bone's envelope, template cm.
_DEFAULT_RADII = (0.5, 2.5)


@dataclass(frozen=True)
class Envelope:
    """Bone envelopes in the template frame.

    Attributes
    ----------
    origins : ndarray of shape (B, 3), template cm
    radii : ndarray of shape (B, 2), template cm
        Inner and outer radius of each bone.
    """

    origins: np.ndarray
    radii: np.ndarray

    @classmethod
    def from_origins(cls, origins) -> "Envelope":
        """Envelopes of default radii (0.5, 2.5) template cm around `origins` (B, 3)."""
        origins = as_float_array(origins, "origins", shape=(None, 3), allow_nan=False)
        return cls(origins, np.tile(_DEFAULT_RADII, (len(origins), 1)))

    def weights(self, vertices, fit: MaskFit) -> np.ndarray:
        """Weights (N, B) of face `vertices` (N, 3) placed by `fit` (its similarity)."""
        return envelope_weights(vertices, fit.to_mesh(self.origins), self.radii * fit.scale)


def envelope_weights(vertices, origins, radii) -> np.ndarray:
    """Envelope weights of points around bones.

    Parameters
    ----------
    vertices : array_like of shape (N, 3)
    origins : array_like of shape (B, 3)
    radii : array_like of shape (B, 2)
        Inner < outer radius per bone, same units as the vertices.

    Returns
    -------
    ndarray of shape (N, B), in [0, 1]
    """
    vertices = as_float_array(vertices, "vertices", shape=(None, 3), allow_nan=False)
    origins = as_float_array(origins, "origins", shape=(None, 3), allow_nan=False)
    radii = as_float_array(radii, "radii", shape=(len(origins), 2), allow_nan=False)
    d = np.linalg.norm(vertices[:, None] - origins[None], axis=2)
    s = np.clip((radii[:, 1] - d) / (radii[:, 1] - radii[:, 0]), 0.0, 1.0)
    return s * s * (3 - 2 * s)


def calibrate_envelope(vertices, weights, fit: MaskFit, *,
                       inner=np.linspace(0.0, 3.0, 13), outer=np.linspace(0.5, 6.0, 23)):
    """Envelopes that best reproduce given weights on one face (least absolute error).

    Each bone's origin is the weight-weighted centroid of the vertices; its
    radii are the pair of the grids (template cm) with the smallest mean
    absolute error over the vertices.

    Parameters
    ----------
    vertices : array_like of shape (N, 3)
    weights : array_like of shape (N, B)
        Reference weights (e.g. gold weights), NaN rows ignored.
    fit : MaskFit
        The mask fitted to this face (gives the template frame).

    Returns
    -------
    Envelope
    """
    vertices = as_float_array(vertices, "vertices", shape=(None, 3), allow_nan=False)
    weights = as_float_array(weights, "weights", shape=(len(vertices), None))
    keep = ~np.isnan(weights).any(axis=1)
    v, w = vertices[keep], weights[keep]
    centroids = (w.T @ v) / w.sum(axis=0)[:, None]
    origins = (centroids - fit.translation) @ fit.rotation / fit.scale
    pairs = np.array([(i, o) for i in inner for o in outer if o > i])
    radii = np.zeros((w.shape[1], 2))
    d = np.linalg.norm(v[:, None] - centroids[None], axis=2) / fit.scale
    for bone in range(w.shape[1]):
        s = np.clip((pairs[:, 1][:, None] - d[:, bone]) / (pairs[:, 1] - pairs[:, 0])[:, None],
                    0.0, 1.0)
        err = np.abs(s * s * (3 - 2 * s) - w[:, bone]).mean(axis=1)
        radii[bone] = pairs[np.argmin(err)]
    return Envelope(origins, radii)
