"""The viseme basis P̃_l on the target face: sculpted shapes, or combinations of ARKit shapes.

Ju & Lee (2008, Fig. 7) use visemes an artist sculpted on the synthetic face.
Two sources here, one shape per class of :data:`fit.gestures.visemes.VISEMES`:

- a directory of OBJ files on the neutral's topology, one per class, named by
  it (``a.obj``, ``e.obj``, ..., ``closed.obj``, ``labiodental.obj``;
  ``neutral.obj`` may be left out: it is the neutral itself);
- for an ARKit-style basis (Apple's 52 blendshapes, ICT-FaceKit's 53), the
  documented combinations of :data:`ARKIT_VISEMES` of its shapes. Shape names
  match whatever the spelling: ``jawOpen`` (ICT), ``JawOpen`` (Live Link
  Face); a shape of two sides (``mouthSmile_L``/``mouthSmile_R``,
  ``MouthSmileLeft``/``MouthSmileRight``) takes the weight on both.

The recipes, weights of ARKit shapes (each in [0, 1], the ARKit meaning of each
shape), were set by looking at ICT-FaceKit renders against the lip opening of
each vowel class in phonetics (open /a/ > /e/ /o/ /eo/ > /i/ /u/ /eu/):

============  ==================================================================
viseme        shapes
============  ==================================================================
``a``         jawOpen 0.55, mouthLowerDown 0.25, mouthUpperUp 0.1
``e``         jawOpen 0.35, mouthStretch 0.35, mouthLowerDown 0.2
``i``         jawOpen 0.15, mouthStretch 0.5, mouthSmile 0.25
``o``         jawOpen 0.3, mouthFunnel 0.6, mouthPucker 0.25
``u``         jawOpen 0.12, mouthPucker 0.85, mouthFunnel 0.35
``eu``        jawOpen 0.15, mouthStretch 0.35, mouthShrugUpper 0.15
``eo``        jawOpen 0.38, mouthFunnel 0.15, mouthLowerDown 0.1
``open``      jawOpen 0.15, mouthLowerDown 0.1
``closed``    mouthPress 0.6, mouthRollLower 0.1, mouthRollUpper 0.1
``labiodental`` mouthRollLower 0.6, mouthUpperUp 0.1
``neutral``   (the neutral face)
============  ==================================================================
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from basis.artist import ArtistBasis, load_artist_basis
from fit.gestures.visemes import NEUTRAL, VISEMES
from mocap.errors import FileFormatError, InputError
from mocap.mesh.mesh import Mesh
from mocap.util.arrays import read_only

__all__ = ["VisemeBasis", "ARKIT_VISEMES", "viseme_basis_from_shapes", "load_viseme_basis"]

#: Viseme class to ARKit shape weights (see the module docstring).
ARKIT_VISEMES = {
    "a": {"jawOpen": 0.55, "mouthLowerDown": 0.25, "mouthUpperUp": 0.1},
    "e": {"jawOpen": 0.35, "mouthStretch": 0.35, "mouthLowerDown": 0.2},
    "i": {"jawOpen": 0.15, "mouthStretch": 0.5, "mouthSmile": 0.25},
    "o": {"jawOpen": 0.3, "mouthFunnel": 0.6, "mouthPucker": 0.25},
    "u": {"jawOpen": 0.12, "mouthPucker": 0.85, "mouthFunnel": 0.35},
    "eu": {"jawOpen": 0.15, "mouthStretch": 0.35, "mouthShrugUpper": 0.15},
    "eo": {"jawOpen": 0.38, "mouthFunnel": 0.15, "mouthLowerDown": 0.1},
    "open": {"jawOpen": 0.15, "mouthLowerDown": 0.1},
    "closed": {"mouthPress": 0.6, "mouthRollLower": 0.1, "mouthRollUpper": 0.1},
    "labiodental": {"mouthRollLower": 0.6, "mouthUpperUp": 0.1},
    "neutral": {},
}
_SIDES = (("_l", "_r"), ("left", "right"))


@dataclass(frozen=True, eq=False)
class VisemeBasis:
    """One displacement field per viseme class on a neutral face.

    Attributes
    ----------
    names : tuple of str
        :data:`fit.gestures.visemes.VISEMES`, in that order.
    neutral : Mesh
    displacements : ndarray of shape (n_visemes, N, 3), mesh units
        P̃_l, displacements from the neutral (zero for ``neutral``); read-only.
    source : str
        Where the shapes come from.
    """

    names: tuple
    neutral: Mesh
    displacements: np.ndarray
    source: str = ""

    def __post_init__(self):
        if tuple(self.names) != VISEMES:
            raise InputError(f"a viseme basis has the classes {list(VISEMES)} in that order, "
                             f"got {list(self.names)}")
        if not isinstance(self.neutral, Mesh):
            raise InputError(f"neutral must be a Mesh, got {type(self.neutral).__name__}")
        disp = np.array(self.displacements, dtype=float)
        if disp.shape != (len(VISEMES), self.neutral.n_vertices, 3) or \
                not np.isfinite(disp).all():
            raise InputError(f"viseme displacements must be finite, of shape "
                             f"({len(VISEMES)}, {self.neutral.n_vertices}, 3), got {disp.shape}")
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "displacements", read_only(disp))


def _key(name: str) -> str:
    return re.sub(r"[^a-z0-9]", "", name.lower())


def _columns(names: tuple, shape: str) -> list:
    """Indices of `shape` in `names`: itself, or both of its sides."""
    keys = [_key(n) for n in names]
    want = _key(shape)
    if want in keys:
        return [keys.index(want)]
    for left, right in _SIDES:
        pair = [_key(want + left), _key(want + right)]
        if all(p in keys for p in pair):
            return [keys.index(p) for p in pair]
    return []


def viseme_basis_from_shapes(basis: ArtistBasis,
                             recipe: Mapping[str, Mapping[str, float]] = ARKIT_VISEMES
                             ) -> VisemeBasis:
    """Visemes as combinations of the shapes of an ARKit-style basis.

    Parameters
    ----------
    basis : ArtistBasis
        Expression shapes with ARKit names (ICT-FaceKit, Live Link Face spelling).
    recipe : mapping of str to mapping of str to float
        Viseme class to shape weights; default :data:`ARKIT_VISEMES`. Every
        class of :data:`fit.gestures.visemes.VISEMES` but ``neutral`` is needed.

    Returns
    -------
    VisemeBasis
        ``P̃_l = Σ_k w_lk e_k``.

    Raises
    ------
    InputError
        A class missing from `recipe` or unknown, a shape the basis does not have.
    """
    if not isinstance(basis, ArtistBasis):
        raise InputError(f"basis must be an ArtistBasis, got {type(basis).__name__}")
    unknown = sorted(set(recipe) - set(VISEMES))
    absent = [v for v in VISEMES if v != NEUTRAL and v not in recipe]
    if unknown or absent:
        raise InputError(f"a viseme recipe names the classes {list(VISEMES)}; unknown "
                         f"{unknown}, missing {absent}")
    mix = np.zeros((len(VISEMES), basis.n_shapes))
    for viseme, shapes in recipe.items():
        for shape, weight in shapes.items():
            cols = _columns(basis.names, shape)
            if not cols:
                raise InputError(f"viseme {viseme!r} needs the shape {shape!r}, which the "
                                 f"basis of {basis.n_shapes} shapes does not have (nor its "
                                 "_L/_R or Left/Right sides): give the visemes as OBJs "
                                 "(--visemes DIR)")
            mix[VISEMES.index(viseme), cols] += float(weight)
    disp = np.tensordot(mix, basis.displacements, axes=1)
    return VisemeBasis(VISEMES, basis.neutral, disp,
                       f"combinations of {basis.n_shapes} ARKit-style shapes")


def load_viseme_basis(neutral: Mesh, directory, *, units: str | None = None) -> VisemeBasis:
    """Visemes sculpted on the neutral: one OBJ per class in `directory`.

    Parameters
    ----------
    neutral : Mesh
    directory : str or os.PathLike
        ``<class>.obj`` for each class of :data:`fit.gestures.visemes.VISEMES`
        (``neutral.obj`` optional), on the neutral's topology.
    units : str, optional
        Of the OBJs, as for :func:`basis.artist.load_artist_basis`.

    Raises
    ------
    FileFormatError
        A class without its OBJ, an OBJ named after no class, other topology.
    """
    shapes = load_artist_basis(neutral, directory, units=units)
    extra = [n for n in shapes.names if n not in VISEMES]
    absent = [v for v in VISEMES if v != NEUTRAL and v not in shapes.names]
    if extra or absent:
        raise FileFormatError(directory, f"a viseme directory holds one OBJ per class "
                                         f"{list(VISEMES)}; missing {absent}, not a class "
                                         f"{extra}")
    disp = np.zeros((len(VISEMES), neutral.n_vertices, 3))
    for i, name in enumerate(shapes.names):
        disp[VISEMES.index(name)] = shapes.displacements[i]
    return VisemeBasis(VISEMES, shapes.neutral, disp, f"viseme OBJs of {directory}")
