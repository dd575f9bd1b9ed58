"""Gold-standard bone weights from an artist's expression shapes (for tests and the bench).

The weight of a vertex for a bone is the length of its displacement in the
bone's expression shape(s), divided by the largest over the mesh (the largest
over several shapes when a bone has more than one): 1 where the bone moves the
skin most, 0 where it does not move it.
"""

from __future__ import annotations

import numpy as np

from basis.artist import ArtistBasis

__all__ = ["GOLD_SHAPES", "gold_weights"]

#: The ICT-FaceKit (ARKit-named) expression shapes that define each bone of
#: the default rig (:data:`basis.maskle.build_default.BONES`).
GOLD_SHAPES = {
    "jaw": ("jawOpen",),
    "upper_lip_left": ("mouthUpperUp_L",),
    "upper_lip_right": ("mouthUpperUp_R",),
    "lower_lip_left": ("mouthLowerDown_L",),
    "lower_lip_right": ("mouthLowerDown_R",),
    "brow_left": ("browOuterUp_L", "browInnerUp_L"),
    "brow_right": ("browOuterUp_R", "browInnerUp_R"),
}


def gold_weights(basis: ArtistBasis, bones=tuple(GOLD_SHAPES)) -> np.ndarray:
    """Per-vertex gold weights (N, B) in [0, 1] of the named bones.

    Parameters
    ----------
    basis : ArtistBasis
        Holding every shape of ``GOLD_SHAPES[bone]`` for the requested bones.
    bones : sequence of str
        Keys of :data:`GOLD_SHAPES`.

    Returns
    -------
    ndarray of shape (N, B)
    """
    out = []
    for bone in bones:
        mags = [np.linalg.norm(basis.displacements[basis.index(s)], axis=1)
                for s in GOLD_SHAPES[bone]]
        out.append(np.max([m / m.max() for m in mags], axis=0))
    return np.stack(out, axis=1)
