"""Lips from the visemes, the rest of the face from the MRF: the talking face's morph targets.

Ju & Lee (2008, sec. 4-5) split the face by marker region: the lip movement P
comes from its own marker group, the details D_j from theirs, and on the
synthetic face ``F̃ = R̃ Ñ + Σ c̃_i B̃_i + Σ d̃_l P̃_l + Σ D̃_j + T̃``. An expression
basis that moves the mouth (ICT's jawOpen, ARKit's mouth shapes) would add the
reference subject's mouth, speaking other words, to the visemes and open the
lips on a /p/; so here the lip region takes its motion from the visemes only
and the rest of the face from the MRF, blended across a border band:

    u(v, t) = (1 − m(v)) Σ_i c̃_i(t) B̃_i(v) + m(v) Σ_l d̃_l(t) P̃_l(v) + Σ_j D̃_j(v, t)

The lip region m is where the viseme basis moves the face: with
``a(v) = max_l |P̃_l(v)|`` and ``r = a / max_v a``, ``m = smoothstep((r − 0.05) /
(0.25 − 0.05))``: 1 where some viseme moves a vertex by at least a quarter of
the largest viseme motion (lips, chin), 0 where none moves it by 5 % (brows,
eyes, nose), a C¹ ramp in between (the cheeks). The blend is linear in the
weights, so the masked shapes are ordinary morph targets (``.glb``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fit.gestures.viseme_basis import VisemeBasis
from fit.gestures.visemes import NEUTRAL, VisemeCurves
from mocap.errors import InputError
from mocap.util.arrays import read_only
from mocap.util.validation import as_float_array

__all__ = ["LIP_BORDER", "lip_region", "TalkingFace", "talking_face"]

#: The border band of the lip region: relative viseme motion where m goes 0 -> 1.
LIP_BORDER = (0.05, 0.25)


def lip_region(visemes: VisemeBasis, *, border=LIP_BORDER) -> np.ndarray:
    """The lip region m(v) of a viseme basis: 1 on the lips, 0 away, smooth between.

    Parameters
    ----------
    visemes : VisemeBasis
    border : (float, float), default (0.05, 0.25)
        Relative viseme motion r (see the module docstring) where m leaves 0 and
        reaches 1.

    Returns
    -------
    ndarray of shape (N,)
        In [0, 1]: ``3 s² − 2 s³`` of ``s = clip((r − lo) / (hi − lo), 0, 1)``.

    Raises
    ------
    InputError
        A basis whose visemes move nothing, a bad border.
    """
    if not isinstance(visemes, VisemeBasis):
        raise InputError(f"visemes must be a VisemeBasis, got {type(visemes).__name__}")
    lo, hi = (float(x) for x in border)
    if not 0 <= lo < hi <= 1:
        raise InputError(f"border must be 0 <= lo < hi <= 1, got {border!r}")
    motion = np.linalg.norm(visemes.displacements, axis=2).max(axis=0)
    top = motion.max()
    if top <= 0:
        raise InputError("the visemes do not move the face: every viseme shape is the neutral")
    s = np.clip((motion / top - lo) / (hi - lo), 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


@dataclass(frozen=True, eq=False)
class TalkingFace:
    """The morph targets and weights of a lip-synced, MRF-animated face.

    Attributes
    ----------
    displacements : ndarray of shape (n_targets, N, 3), mesh units
        ``(1 − m) B̃_i``, then ``m P̃_l`` for each viseme but ``neutral``, then the
        extra fields given (details), unmasked.
    names : tuple of str
        Expression names, ``viseme:<class>``, the extra names.
    weights : ndarray of shape (n_frames, n_targets)
        c̃(t), d̃_l(t), the extra weights.
    region : ndarray of shape (N,)
        m(v).
    """

    displacements: np.ndarray
    names: tuple
    weights: np.ndarray
    region: np.ndarray

    def vertices(self, neutral, frames=slice(None)) -> np.ndarray:
        """Vertex positions (n, N, 3) of the frames: ``neutral + weights @ targets``.

        Parameters
        ----------
        neutral : array_like of shape (N, 3), mesh units
        frames : int, slice or array of int
        """
        w = np.atleast_2d(self.weights[frames])
        flat = self.displacements.reshape(len(self.names), -1)
        return (w @ flat).reshape(len(w), -1, 3) + np.asarray(neutral, float)


def talking_face(expressions, weights, visemes: VisemeBasis, curves: VisemeCurves, *,
                 extra=None, extra_names=(), extra_weights=None,
                 border=LIP_BORDER) -> TalkingFace:
    """Blend the MRF's expressions with the visemes by region (module docstring).

    Parameters
    ----------
    expressions : ArtistBasis
        B̃_i on the same neutral as `visemes`.
    weights : array_like of shape (n_frames, n_shapes)
        c̃(t) (:attr:`fit.gestures.GestureSynthesis.weights`).
    visemes : VisemeBasis
    curves : VisemeCurves
        d̃_l(t), as many frames as `weights`.
    extra : array_like of shape (n_extra, N, 3), optional
        Fields added unmasked (the transferred details D̃_j).
    extra_names : sequence of str
    extra_weights : array_like of shape (n_frames, n_extra), optional
    border : (float, float)
        Of :func:`lip_region`.

    Returns
    -------
    TalkingFace

    Raises
    ------
    InputError
        Other neutral topologies, frame counts or shapes that disagree.
    """
    if not visemes.neutral.same_topology(expressions.neutral):
        raise InputError("the viseme basis and the expression shapes are on different meshes")
    weights = as_float_array(weights, "weights", shape=(None, expressions.n_shapes),
                             allow_nan=False)
    if not isinstance(curves, VisemeCurves) or curves.n_frames != len(weights):
        raise InputError(f"curves must be VisemeCurves of {len(weights)} frames")
    region = lip_region(visemes, border=border)
    keep = [i for i, n in enumerate(visemes.names) if n != NEUTRAL]
    fields = [(1.0 - region)[None, :, None] * expressions.displacements,
              region[None, :, None] * visemes.displacements[keep]]
    names = list(expressions.names) + [f"viseme:{visemes.names[i]}" for i in keep]
    columns = [weights, curves.weights[:, keep]]
    if extra is not None:
        extra = as_float_array(extra, "extra", shape=(None, visemes.neutral.n_vertices, 3),
                               allow_nan=False)
        extra_weights = as_float_array(extra_weights, "extra_weights",
                                       shape=(len(weights), len(extra)), allow_nan=False)
        if len(tuple(extra_names)) != len(extra):
            raise InputError(f"extra_names must name the {len(extra)} extra fields")
        fields.append(extra)
        names += list(extra_names)
        columns.append(extra_weights)
    return TalkingFace(read_only(np.concatenate(fields)), tuple(names),
                       read_only(np.concatenate(columns, axis=1)), read_only(region))
