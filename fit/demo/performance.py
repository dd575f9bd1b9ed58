"""The demo performance: muscle activations over time, and what the basis cannot show.

An actor talks (syllable-rate jaw and lip activity in phrases), smiles,
raises and knits the brows, blinks and once or twice puffs the left cheek.
The artist basis (:mod:`fit.demo.muscles`) does not span the resulting face
exactly, as a real artist basis never does:

- the jaw turns about its joints, so its displacement is not linear in the
  activation (``sin`` and ``1 - cos`` of the angle): the part beyond the
  ``jaw_open`` shape is the hidden shape ``jaw_arc``;
- blinks (orbicularis oculi) and an asymmetric cheek puff have no shape in
  the basis.

:func:`truth_basis` holds the artist shapes plus these hidden shapes, and
:meth:`DemoPerformance.truth_weights` their weights, so that the true face of
every frame is linear in them: ``v(t) = v0 + truth_weights(t) @ E_truth``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from basis.artist import ArtistBasis
from fit.demo._fields import Sculptor, radial, ramp, slit_side
from fit.demo.face import EYES, FaceModel, eye_line
from fit.demo.muscles import JAW, MUSCLES, jaw_rotation_parts

__all__ = ["HIDDEN", "TRUTH_SHAPES", "DemoPerformance", "make_performance", "truth_basis"]

#: Deformations of the performance outside the artist basis.
HIDDEN = ("jaw_arc", "blink_L", "blink_R", "cheek_puff_L")
#: Shapes of :func:`truth_basis`, in order.
TRUTH_SHAPES = MUSCLES + HIDDEN
_HIDDEN_ACTIONS = HIDDEN[1:]           # driven directly; jaw_arc follows the jaw


@dataclass(frozen=True, eq=False)
class DemoPerformance:
    """Activations of the demo performance.

    Attributes
    ----------
    activations : ndarray of shape (T, 18)
        Activation of each muscle of :data:`fit.demo.muscles.MUSCLES`, 0..1
        (1 = the artist's shape; the jaw's is its fraction of the full angle).
    hidden : ndarray of shape (T, 3)
        Activations of ``blink_L``, ``blink_R``, ``cheek_puff_L``, 0..1.
    rate : float, Hz
    """

    activations: np.ndarray
    hidden: np.ndarray
    rate: float

    def __post_init__(self):
        for name in ("activations", "hidden"):
            arr = np.array(getattr(self, name), dtype=np.float64)
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)

    @property
    def n_frames(self) -> int:
        """Number of frames T."""
        return len(self.activations)

    @property
    def times(self) -> np.ndarray:
        """Frame times (T,), s, from 0."""
        return np.arange(self.n_frames) / self.rate

    def truth_weights(self) -> np.ndarray:
        """Weights (T, 22) of :data:`TRUTH_SHAPES` giving the true face of every frame.

        ``jaw_open`` gets ``sin(a θ) / sin θ`` and ``jaw_arc`` gets
        ``(1 - cos(a θ)) / (1 - cos θ) - sin(a θ) / sin θ`` for a jaw
        activation a and full angle θ, so that both agree with the artist's
        shape at a = 0 and a = 1 and follow the rotation in between.
        """
        jaw = MUSCLES.index("jaw_open")
        theta = np.deg2rad(JAW["degrees"])
        angle = theta * self.activations[:, jaw]
        linear = np.sin(angle) / np.sin(theta)
        arc = (1 - np.cos(angle)) / (1 - np.cos(theta)) - linear
        weights = np.column_stack([self.activations, arc, self.hidden])
        weights[:, jaw] = linear
        return weights


def truth_basis(face: FaceModel, artist: ArtistBasis) -> ArtistBasis:
    """The artist shapes followed by the hidden shapes (:data:`TRUTH_SHAPES`).

    Parameters
    ----------
    face : FaceModel
    artist : ArtistBasis
        :func:`fit.demo.muscles.muscle_basis` of `face`.

    Returns
    -------
    ArtistBasis
        22 shapes, displacements in mm; ``jaw_arc`` is the second-order part
        of the full jaw rotation, ``(1 - cos θ) K K r``.
    """
    s = Sculptor(face.mesh.vertices, face.mesh.faces)
    x, y = s.x, s.y
    hidden = {"jaw_arc": (1 - np.cos(np.deg2rad(JAW["degrees"]))) * jaw_rotation_parts(s)[1]}
    for tag, eye in zip("LR", EYES):
        cx, cy = eye["center"]
        lid = radial(x, y, (cx, cy + 3.0), (eye["half_width"] + 5.0, 12.0)) * slit_side(
            x, y, lambda u, e=eye: eye_line(u, e), eye["half_width"], cx)
        hidden[f"blink_{tag}"] = s.slide(lid, (0.0, -8.0, 0.0))
    hidden["cheek_puff_L"] = s.bulge(radial(x, y, (42.0, -26.0), (20.0, 17.0), flat=0.1), 5.0)
    extra = np.stack([hidden[name] for name in HIDDEN])
    return ArtistBasis(TRUTH_SHAPES, artist.neutral,
                       np.concatenate([artist.displacements, extra]))


def _pulses(t, starts, lengths, amplitudes, rise=0.3) -> np.ndarray:
    """Sum of smooth plateau pulses over time (T,): each rises over `rise` of its length."""
    if len(starts) == 0:
        return np.zeros_like(t)
    u = (t[:, None] - starts[None]) / lengths[None]                       # (T, E)
    shape = ramp(u / rise) * (1.0 - ramp((u - 1.0 + rise) / rise))
    return shape @ amplitudes


def _events(rng, seconds, every, length, amplitude, at_least=0):
    """Random event starts (a Poisson process, mean spacing `every` s), lengths, amplitudes."""
    n = max(at_least, rng.poisson(seconds / every))
    return (np.sort(rng.uniform(-0.5, seconds, n)), rng.uniform(*length, n),
            rng.uniform(*amplitude, n))


def _speech(rng, t, seconds):
    """Jaw and lip activations of speech: syllables at ~4.5 Hz in phrases, (T, 5)."""
    phrases, cursor = [], rng.uniform(0.2, 1.0)
    while cursor < seconds:
        length = rng.uniform(1.5, 4.0)
        phrases.append((cursor, cursor + length))
        cursor += length + rng.uniform(0.6, 2.0)
    syllables = np.concatenate([np.arange(a, b, 1 / 4.5) for a, b in phrases] or [[]])
    syllables = syllables + rng.normal(0, 0.03, len(syllables))
    n = len(syllables)
    jaw = _pulses(t, syllables, rng.uniform(0.18, 0.3, n), rng.uniform(0.15, 0.55, n), 0.45)
    # lip shapes on some syllables: pucker (oo), lower-lip down, upper-lip raise, mentalis
    lips = []
    for amplitude in ((0.3, 0.8), (0.2, 0.6), (0.2, 0.6), (0.2, 0.5)):
        pick = rng.random(n) < 0.2
        lips.append(_pulses(t, syllables[pick], rng.uniform(0.2, 0.35, pick.sum()),
                            rng.uniform(*amplitude, pick.sum()), 0.45))
    return np.column_stack([jaw] + lips)


def make_performance(*, seconds: float = 20.0, rate: float = 100.0,
                     seed: int = 7) -> DemoPerformance:
    """Generate the demo performance.

    Parameters
    ----------
    seconds : float, s
    rate : float, Hz
    seed : int

    Returns
    -------
    DemoPerformance
        Smooth activations in [0, 1]; deterministic for a seed.
    """
    rng = np.random.default_rng(seed)
    n_frames = int(round(seconds * rate))
    t = np.arange(n_frames) / rate
    act = dict.fromkeys(MUSCLES, 0.0)
    speech = _speech(rng, t, seconds)
    act["jaw_open"] = speech[:, 0] + _pulses(t, *_events(rng, seconds, 15.0, (0.8, 1.4),
                                                         (0.7, 0.95)))
    for name, column in zip(("orbicularis_oris", "depressor_labii_inferioris",
                             "levator_labii_superioris", "mentalis"), speech[:, 1:].T):
        if name == "levator_labii_superioris":
            act[name + "_L"], act[name + "_R"] = column, 0.8 * column
        else:
            act[name] = column
    # paired expressions: both sides, one side a little weaker at random
    for muscles, every, length, amplitude in (
            (("zygomaticus_major",), 6.0, (1.0, 3.0), (0.4, 1.0)),
            (("frontalis_inner", "frontalis_outer"), 5.0, (0.6, 2.0), (0.3, 1.0)),
            (("corrugator", "depressor_anguli_oris"), 9.0, (0.8, 2.0), (0.3, 0.9)),
            (("risorius",), 10.0, (0.5, 1.5), (0.3, 0.8))):
        starts, lengths, amplitudes = _events(rng, seconds, every, length, amplitude)
        balance = rng.uniform(0.6, 1.0, (2, len(starts)))
        for muscle in muscles:
            for side, b in zip("LR", balance):
                act[f"{muscle}_{side}"] = _pulses(t, starts, lengths, amplitudes * b)
    blinks = _events(rng, seconds, 3.0, (0.2, 0.3), (0.9, 1.0))
    one_eyed = rng.random(len(blinks[0])) < 0.1
    puffs = _events(rng, seconds, 12.0, (0.8, 1.5), (0.7, 1.0), at_least=1)
    hidden = np.column_stack([
        _pulses(t, *blinks, 0.4),
        _pulses(t, blinks[0][~one_eyed], blinks[1][~one_eyed], blinks[2][~one_eyed], 0.4),
        _pulses(t, *puffs)])
    activations = np.column_stack([np.broadcast_to(act[m], t.shape) for m in MUSCLES])
    return DemoPerformance(_saturate(activations), _saturate(hidden), float(rate))


def _saturate(x):
    """Smooth limit of summed pulses below 1 (``x / (1 + x^6)^(1/6)``, ~x below 0.5)."""
    return x / (1.0 + x ** 6) ** (1.0 / 6.0)
