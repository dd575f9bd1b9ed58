"""The demo's artist basis: 18 shapes, each the full actuation of one expression muscle.

As in the quasi-eigen paper (section 5.3), every hand-made shape is the face
with one expression muscle fully actuated and the others relaxed: 6 for the
upper face (:data:`UPPER_FACE`), 12 for the lower face (:data:`LOWER_FACE`).
Each is a smooth displacement field of a few millimetres, exactly zero
outside its muscle's reach: upper-face shapes never move the lips, lower-face
shapes never move the brows or eyes, and shapes acting on one lip leave the
other lip (across the mouth slit) still. ``_L``/``_R`` are the subject's own
left (+x) and right.
"""

from __future__ import annotations

import numpy as np

from basis.artist import ArtistBasis
from fit.demo._fields import Sculptor, above_mouth, radial, ramp, window
from fit.demo.face import MOUTH, FaceModel, mouth_line

__all__ = ["UPPER_FACE", "LOWER_FACE", "MUSCLES", "JAW", "muscle_basis"]

#: Upper-face shapes: brow raisers (frontalis, inner and outer) and brow lowerers.
UPPER_FACE = ("frontalis_inner_L", "frontalis_inner_R", "frontalis_outer_L",
              "frontalis_outer_R", "corrugator_L", "corrugator_R")
#: Lower-face shapes: mouth-corner, lip and jaw muscles.
LOWER_FACE = ("zygomaticus_major_L", "zygomaticus_major_R", "risorius_L", "risorius_R",
              "depressor_anguli_oris_L", "depressor_anguli_oris_R",
              "levator_labii_superioris_L", "levator_labii_superioris_R",
              "orbicularis_oris", "mentalis", "depressor_labii_inferioris", "jaw_open")
#: All shape names, in basis order.
MUSCLES = UPPER_FACE + LOWER_FACE
#: The jaw: rotation about the x axis through the jaw joints (pivot mm, degrees
#: at full opening); the lower face follows it with weight :func:`jaw_weight`.
JAW = {"pivot": (0.0, 5.0, -20.0), "axis": (1.0, 0.0, 0.0), "degrees": 10.0}
#: Within this fraction of the mouth's half-width the jaw moves the lower lip
#: only; towards the corners both lips follow it in part.
_JAW_EXACT = 0.5


def jaw_weight(x, y) -> np.ndarray:
    """How much of the jaw's rotation each point follows, 0..1 (1 on the lower lip and chin).

    Exactly 0 on the upper lip within ``_JAW_EXACT`` of the mouth's half-width
    and above y = 8 mm.
    """
    below = 1.0 - above_mouth(x, y, start=_JAW_EXACT, growth=0.7)
    return below * (1.0 - ramp((y + 15.0) / 23.0))


def _side_fields(s: Sculptor, side: int) -> dict:
    """The paired muscles of one side (+1 the subject's left, -1 the right), (N, 3) mm."""
    x, y = side * s.x, s.y                      # mirrored: x > 0 on the muscle's side
    tag = "L" if side > 0 else "R"
    corner = (MOUTH["half_width"] + 1.0, float(mouth_line(MOUTH["half_width"])))
    upper = above_mouth(s.x, s.y)
    return {
        f"frontalis_inner_{tag}": s.slide(window(x, -8, 2, 12, 30) * window(y, 32, 44, 52, 95),
                                          (0.0, 8.0, 0.0)),
        f"frontalis_outer_{tag}": s.slide(window(x, 8, 22, 40, 60) * window(y, 33, 45, 54, 92),
                                          (side * 1.0, 7.0, 0.0)),
        f"corrugator_{tag}": (lambda w: s.slide(w, (-side * 3.5, -4.0, 0.0)) + s.bulge(w, 1.5))(
            window(x, -3, 5, 14, 28) * window(y, 36, 41, 47, 60)),
        f"zygomaticus_major_{tag}": s.slide(radial(x, y, corner, (24, 22)), (side * 5.0, 8.0, 0.0))
        + s.bulge(radial(x, y, (38, -12), (20, 15), flat=0.0), 2.5),
        f"risorius_{tag}": s.slide(radial(x, y, corner, (22, 15)), (side * 7.0, 0.5, 0.0)),
        f"depressor_anguli_oris_{tag}": s.slide(radial(x, y, (24, -41), (18, 22)),
                                                (side * 1.0, -6.0, 0.0)),
        f"levator_labii_superioris_{tag}": (lambda w: s.slide(w, (0.0, 5.0, 0.0))
                                            + s.bulge(w, 1.5))(
            radial(x, y, (10, -31), (14, 11)) * upper)
        + s.slide(radial(x, y, (14, -6), (8, 8)), (0.0, 2.5, 0.0)),
    }


def _fields(s: Sculptor) -> dict:
    """All 18 muscle fields by name, (N, 3) mm."""
    x, y = s.x, s.y
    lower = 1.0 - above_mouth(x, y)
    fields = {**_side_fields(s, 1), **_side_fields(s, -1)}
    pucker = radial(x, y, (0, -38), (34, 22), flat=0.3)
    fields["orbicularis_oris"] = s.slide(pucker, np.column_stack(
        [-0.3 * x, -0.15 * (y - mouth_line(x)), 0 * x])) + s.bulge(pucker, 7.0)
    fields["mentalis"] = s.slide(radial(x, y, (0, -55), (24, 22), flat=0.3) * lower,
                                 (0.0, 4.0, 0.0)) \
        + s.bulge(radial(x, y, (0, -46), (16, 10)) * lower, 3.0)
    dli = radial(x, y, (0, -46), (22, 13)) * lower
    fields["depressor_labii_inferioris"] = s.slide(dli, (0.0, -5.0, 0.0)) + s.bulge(dli, 1.5)
    fields["jaw_open"] = jaw_open_field(s, 1.0)
    return fields


def jaw_open_field(s: Sculptor, activation: float) -> np.ndarray:
    """Displacement (N, 3) mm of the jaw opened to `activation` of its full angle.

    Not linear in `activation`: the lower face turns rigidly about the jaw
    joints (see :data:`JAW`), blended by :func:`jaw_weight`.
    """
    sin_part, cos_part = jaw_rotation_parts(s)
    angle = np.deg2rad(JAW["degrees"]) * activation
    return np.sin(angle) * sin_part + (1.0 - np.cos(angle)) * cos_part


def jaw_rotation_parts(s: Sculptor) -> tuple[np.ndarray, np.ndarray]:
    """The two Rodrigues fields of the jaw rotation, (N, 3) mm per radian each."""
    return s.rotation_parts(jaw_weight(s.x, s.y), JAW["pivot"], JAW["axis"])


def muscle_basis(face: FaceModel) -> ArtistBasis:
    """The 18-shape muscle basis of the demo face.

    Parameters
    ----------
    face : FaceModel
        From :func:`fit.demo.face.make_face`.

    Returns
    -------
    ArtistBasis
        Shapes :data:`MUSCLES` in that order, displacements (18, N, 3) in mm
        (the face's units); deterministic.
    """
    sculptor = Sculptor(face.mesh.vertices, face.mesh.faces)
    fields = _fields(sculptor)
    return ArtistBasis(MUSCLES, face.mesh, np.stack([fields[name] for name in MUSCLES]))
