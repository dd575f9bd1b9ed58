"""``kernel = "auto"``: the retargeting variant chosen by cross-validation.

Every variant of a grid (kernel, shape parameter, Euclidean or geodesic
distance, with or without lip regions) is scored by its leave-one-marker-out
error (:mod:`mocap.retarget.cross_validation`), in closed form from the
(M, M) Gram matrix of the take's displacements, so the whole grid costs about
a second whatever the take's length. Where the mesh's lips are known, each
variant's mesh is also read at the lips in the frames where the lip markers
open the mouth widest: a variant that keeps the mouth shut there
(:mod:`mocap.retarget.lip_seal`) is set aside whenever another one opens it.
The lowest score among the rest wins.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import groupby
from operator import itemgetter

import numpy as np

from mocap.errors import InputError
from mocap.retarget.cross_validation import (
    LeaveOneOut,
    MarkerGeometry,
    gram_matrix,
    leave_one_out_many,
)
from mocap.retarget.lip_seal import (
    OPEN_MM,
    OPEN_SPAN,
    SHUT_FRACTION,
    contradicts,
    marker_open_mm,
)
from mocap.retarget.rbf import DISTANCES

__all__ = ["Candidate", "RetargetSelection", "select_variant", "candidate_grid", "SHAPES",
           "LIP_FRAMES"]

#: Kernels "auto" tries, with their shape parameters as multiples of 1/h (h: the
#: median distance from a marker to its nearest neighbour): epsilon·h for the
#: Gaussian and the inverse multiquadric, the support radius in units of h for
#: Wendland's C2 function (epsilon = 1 / (r h)); None: the scale-invariant TPS.
SHAPES = {"thin_plate_spline": (None,),
          "gaussian": tuple(np.round(np.geomspace(0.2, 1.2, 7), 3)),
          "inverse_multiquadric": tuple(np.round(np.geomspace(0.2, 1.2, 7), 3)),
          "wendland_c2": tuple(np.round(np.geomspace(1.5, 8.0, 7), 3))}
#: Frames (the widest marker openings) at which each variant's lips are read.
LIP_FRAMES = 32


@dataclass(frozen=True)
class Candidate:
    """One variant tried and how it did.

    Attributes
    ----------
    kernel : str
    epsilon : float or None
        Shape parameter, 1/mesh units (None: the kernel's default).
    distance : str
    use_regions : bool
    shape : float or None
        The grid's value (epsilon·h, or the support radius over h).
    score_mm : float
        RMS over every marker and frame of the held-out marker's error, mm
        (NaN when it could not be scored).
    lips_open : float or None
        Median, over the frames where the lip markers open widest, of the
        mesh's opening over the markers' (None: lips not read).
    lips_shut_frames : int or None
        Of those frames, how many the mesh keeps shut (:mod:`mocap.retarget.lip_seal`).
    shift : float
        The largest diagonal shift that made a system positive definite (0: none).
    note : str
        Why it could not be scored, or "".
    """

    kernel: str
    epsilon: float | None
    distance: str
    use_regions: bool
    shape: float | None
    score_mm: float
    lips_open: float | None = None
    lips_shut_frames: int | None = None
    shift: float = 0.0
    note: str = ""

    @property
    def name(self) -> str:
        """A short label, e.g. ``gaussian ε·h=0.5 geodesic +regions``."""
        shape = "" if self.shape is None else (
            f" r/h={self.shape:g}" if self.kernel == "wendland_c2" else f" ε·h={self.shape:g}")
        return f"{self.kernel}{shape} {self.distance}" + (" +regions" if self.use_regions else "")

    def options(self) -> dict:
        """The retargeting options of this variant (keyword arguments)."""
        return {"kernel": self.kernel, "epsilon": self.epsilon, "distance": self.distance,
                "use_regions": self.use_regions}


@dataclass(frozen=True)
class RetargetSelection:
    """What ``kernel = "auto"`` tried, the scores and the choice.

    Attributes
    ----------
    candidates : tuple of Candidate
        Every variant, in grid order.
    chosen : int
        Index of the variant chosen.
    spacing : float
        h, the median nearest-marker distance, mesh units.
    mm_per_unit : float
    lips_checked : bool
        The lips were read (a mouth and lip markers were given, and the
        markers open the mouth by at least :data:`mocap.retarget.lip_seal.OPEN_MM`).
    rule : str
        How the choice was made, in words.
    seconds : float
        Wall time of the selection.
    """

    candidates: tuple
    chosen: int
    spacing: float
    mm_per_unit: float
    lips_checked: bool
    rule: str
    seconds: float

    @property
    def best(self) -> Candidate:
        """The chosen variant."""
        return self.candidates[self.chosen]

    def to_dict(self) -> dict:
        """Plain data for a manifest (NaN as None)."""
        def plain(c: Candidate) -> dict:
            score = None if not np.isfinite(c.score_mm) else round(float(c.score_mm), 6)
            return {"name": c.name, **c.options(), "shape": c.shape, "score_mm": score,
                    "lips_open": None if c.lips_open is None else round(float(c.lips_open), 4),
                    "lips_shut_frames": c.lips_shut_frames, "shift": c.shift, "note": c.note}
        return {"chosen": plain(self.best), "rule": self.rule,
                "spacing": self.spacing, "lips_checked": self.lips_checked,
                "seconds": round(self.seconds, 3),
                "tried": [plain(c) for c in self.candidates]}


def candidate_grid(spacing: float, *, distances=DISTANCES,
                   use_regions=(False, True)) -> list[tuple]:
    """``(kernel, epsilon, distance, use_regions, shape)`` of every variant to try.

    Parameters
    ----------
    spacing : float
        h, the median nearest-marker distance, mesh units.
    distances : sequence of str
    use_regions : sequence of bool

    Examples
    --------
    >>> grid = candidate_grid(1.5)
    >>> len(grid), grid[0]
    (88, ('thin_plate_spline', None, 'euclidean', False, None))
    """
    grid = []
    for distance in distances:
        for regions in use_regions:
            for kernel, shapes in SHAPES.items():
                for shape in shapes:
                    if shape is None:
                        epsilon = None
                    elif kernel == "wendland_c2":
                        epsilon = 1.0 / (shape * spacing)
                    else:
                        epsilon = shape / spacing
                    grid.append((kernel, epsilon, distance, bool(regions), shape))
    return grid


def _spacing(geometry: MarkerGeometry) -> float:
    between, _, _ = geometry.distances("euclidean")
    return float(np.median((between + np.diag(np.full(len(between), np.inf))).min(axis=1)))


def select_variant(geometry: MarkerGeometry, displacements, *,
                   regions: Mapping[str, Sequence] | None, mm_per_unit: float,
                   distances: Sequence[str] = DISTANCES,
                   use_regions: Sequence[bool] = (False, True),
                   smoothing: float = 0.0, region_width: float | None = None,
                   mouth=None, witness=None, open_mm: float = OPEN_MM,
                   fraction: float = SHUT_FRACTION) -> RetargetSelection:
    """Choose the retargeting variant by leave-one-marker-out cross-validation.

    Parameters
    ----------
    geometry : MarkerGeometry
        The face markers on the neutral mesh.
    displacements : array_like of shape (T, M, 3), mesh units
        The take's marker displacements from the rest pose; no NaN.
    regions : mapping of str to sequence of str, or None
        The region map of the region variants (the split regions and
        ``"other"``, as :func:`mocap.retarget.retargeting.build_retarget_operator`
        makes it); None: no region variants.
    mm_per_unit : float
        Millimetres per mesh unit of the capture (1 / binding scale), for the scores.
    distances, use_regions : sequences
        What to try (both distances, with and without regions, by default).
    smoothing : float
        Kernel-diagonal smoothing of every variant.
    region_width : float, optional
        Blend width of the region weights (default: the median marker spacing).
    mouth : mocap.mesh.mouth.MouthOpening, optional
        The neutral mesh's lips: with `witness`, each variant's lips are read.
    witness : mocap.retarget.lip_seal.LipWitness, optional
        The lip markers (indices into the geometry's markers).
    open_mm, fraction : float
        The lip-seal thresholds (:func:`mocap.retarget.lip_seal.check_lip_seal`;
        the markers' threshold also scales with their rest distance).

    Returns
    -------
    RetargetSelection

    Raises
    ------
    InputError
        Bad displacements, or no variant that could be scored.
    """
    tic = time.perf_counter()
    d = np.asarray(displacements, dtype=np.float64)
    gram = gram_matrix(d)
    n_samples = d.shape[0] * d.shape[1]
    spacing = _spacing(geometry)
    if regions is None:
        use_regions = [r for r in use_regions if not r]
    lips = _lip_frames(geometry, d, mouth, witness, mm_per_unit, open_mm)
    candidates = []
    grid = candidate_grid(spacing, distances=distances, use_regions=use_regions)
    # the variants of one distance, region map and kernel differ only in their shape
    # parameter: solved together, as stacks (leave_one_out_many)
    for (kernel, distance, with_regions), family in groupby(grid, key=itemgetter(0, 2, 3)):
        family = list(family)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")              # regularization shifts: scored anyway
            results = leave_one_out_many(
                geometry, kernel=kernel, epsilons=[v[1] for v in family], smoothing=smoothing,
                distance=distance, regions=regions if with_regions else None,
                region_width=region_width, vertices=None if lips is None else mouth.vertex_ids)
        candidates += _family_candidates(family, results, gram, n_samples, mm_per_unit,
                                         mouth, lips, fraction)
    scores = np.array([c.score_mm for c in candidates])
    if not np.isfinite(scores).any():
        raise InputError("kernel='auto': no retargeting variant could be cross-validated ("
                         + "; ".join(sorted({c.note for c in candidates}))[:300] + ")")
    opening = np.array([c.lips_shut_frames == 0 for c in candidates])
    if lips is not None and (opening & np.isfinite(scores)).any():
        eligible = opening & np.isfinite(scores)
        rule = ("lowest held-out marker error among the variants whose mesh opens the mouth "
                f"at the {len(lips[3])} frames where the lip markers open it widest")
    else:
        eligible = np.isfinite(scores)
        rule = "lowest held-out marker error" + (
            " (no variant opens the mouth where the lip markers do)" if lips is not None else
            "" if mouth is not None and witness is not None else " (lips not read)")
    chosen = int(np.flatnonzero(eligible)[np.argmin(scores[eligible])])
    return RetargetSelection(candidates=tuple(candidates), chosen=chosen, spacing=spacing,
                             mm_per_unit=float(mm_per_unit), lips_checked=lips is not None,
                             rule=rule, seconds=time.perf_counter() - tic)


def _lip_frames(geometry, d, mouth, witness, mm_per_unit, open_mm):
    """The frames to read the lips at, or None.

    ``(neutral lip vertices (P, 3), rest gap, displacements (K, M, 3), the
    markers' opening (K,) mm, the markers' open threshold mm)`` at the K
    frames (at most :data:`LIP_FRAMES`) where the lip markers open the mouth
    widest, by at least :func:`mocap.retarget.lip_seal.marker_open_mm`.
    """
    if mouth is None or witness is None:
        return None
    if witness.labels != geometry.labels:
        raise InputError("witness must refer to the geometry's markers")
    # the witness's markers only (the same distances): no (T, M, 3) sum of every marker
    own = witness.own_markers()
    columns = [geometry.labels.index(label) for label in own.labels]
    centers = geometry.centers[columns]
    rest = mm_per_unit * own.distance(centers[None])[0]
    opening = mm_per_unit * own.distance(centers + d[:, columns]) - rest
    open_mm = marker_open_mm(rest, open_mm=open_mm, open_span=OPEN_SPAN)
    frames = np.flatnonzero(opening >= open_mm)
    if not len(frames):
        return None
    frames = frames[np.argsort(opening[frames])[::-1][:LIP_FRAMES]]
    neutral = geometry.vertices[mouth.vertex_ids]
    return neutral, float(mouth.gap(neutral)), d[frames], opening[frames], open_mm


def _family_candidates(family, results, gram, n_samples, mm_per_unit, mouth, lips,
                       fraction) -> list[Candidate]:
    """The Candidate of each variant of a family from its :func:`leave_one_out_many` result.

    An InputError or a marker that cannot be held out leaves the variant unscored
    (NaN, with why); the others are scored from the Gram matrix and, with `lips`,
    their lips read (every variant of the family at once).
    """
    scored = [i for i, loo in enumerate(results) if isinstance(loo, LeaveOneOut)
              and not loo.singular]
    if lips is not None and scored:
        lips_open, shut = _read_lips(np.stack([results[i].rows for i in scored]), mouth, lips,
                                     mm_per_unit, fraction)
        read = {i: (float(o), int(n)) for i, o, n in zip(scored, lips_open, shut)}
    else:
        read = {}
    out = []
    for i, ((kernel, epsilon, distance, with_regions, shape), loo) in enumerate(
            zip(family, results)):
        base = dict(kernel=kernel, epsilon=epsilon, distance=distance,
                    use_regions=with_regions, shape=shape)
        if isinstance(loo, InputError):
            out.append(Candidate(**base, score_mm=np.nan, note=str(loo)))
            continue
        if loo.singular:
            label, why = next(iter(loo.singular.items()))
            out.append(Candidate(**base, score_mm=np.nan,
                                 note=f"marker {label!r} cannot be held out: {why}"))
            continue
        score = mm_per_unit * float(np.sqrt(max(loo.sum_squares(gram).sum(), 0.0) / n_samples))
        lips_open, shut = read.get(i, (None, None))
        out.append(Candidate(**base, score_mm=score if np.isfinite(score) else np.nan,
                             lips_open=lips_open, lips_shut_frames=shut,
                             shift=max(loo.shifts.values(), default=0.0),
                             note="" if np.isfinite(score) else "the score is not finite"))
    return out


def _read_lips(rows, mouth, lips, mm_per_unit, fraction):
    """Median mesh-over-marker opening (k,) and number of shut frames (k,) of k variants.

    `rows` (k, P, M): each variant's operator at the lip vertices; `lips`: of
    :func:`_lip_frames`.
    """
    neutral, rest, d, marker_opening, open_mm = lips
    mesh_opening = mm_per_unit * (mouth.gap(neutral + np.matmul(rows[:, None], d)) - rest)
    shut = contradicts(marker_opening, mesh_opening, open_mm=open_mm, fraction=fraction)
    return np.median(mesh_opening / marker_opening, axis=1), shut.sum(axis=1)
