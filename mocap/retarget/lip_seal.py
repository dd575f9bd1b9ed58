"""Lip seal and contact: does the mesh open its mouth when the markers do?

The markers of the lips (the marker set's lip landmarks, else the centroids of
its ``upper_lip`` and ``lower_lip`` regions) say how far the mouth opens from
the rest pose; the mesh says it with its lip gap (:mod:`mocap.mesh.mouth`).
A retargeting that keeps the mesh's mouth shut while the markers open it (the
lips interpolated together across the mouth), or the reverse, is flagged frame
by frame, with the capture's frame numbers.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from mocap.errors import InputError
from mocap.util.validation import as_float_array, as_positive_float

__all__ = ["LipWitness", "lip_witness", "LipSealCheck", "check_lip_seal", "contradicts",
           "marker_open_mm", "OPEN_MM", "OPEN_SPAN", "SHUT_FRACTION"]

#: A mouth is open when it opens this much from rest, mm.
OPEN_MM = 6.0
#: ... and, said by the lip markers, by at least this fraction of their rest distance:
#: the lips can stay sealed while the jaw drops, the skin between them stretching, and
#: markers that sit off the lips then part with no opening (on the ICT face driven by
#: the ARKit performances, up to 20 mm for lip markers 34 mm apart at rest; never more
#: than 60 % of their rest distance).
OPEN_SPAN = 0.6
#: A mouth opened by less than this fraction of what the other side says is shut.
SHUT_FRACTION = 0.25
#: Marker-set landmarks on the upper and on the lower lip, the nearest to the lip line first.
_UPPER = ("upper_lip_bottom", "upper_lip_top")
_LOWER = ("lower_lip_top", "lower_lip_bottom")
#: Frame ranges named in a message before "and n more".
_SHOWN_RUNS = 6


@dataclass(frozen=True)
class LipWitness:
    """The markers that say how far the mouth is open.

    Attributes
    ----------
    upper, lower : tuple of int
        Column indices (in `labels`) of the upper-lip and lower-lip markers;
        the distance between the two groups' centroids is the markers' lip distance.
    labels : tuple of str
        The markers the indices refer to.
    source : str
        How they were chosen: ``"landmarks"`` or ``"regions"``.
    """

    upper: tuple
    lower: tuple
    labels: tuple
    source: str

    def describe(self) -> str:
        """The witness in words, for reports."""
        def names(idx):
            return ", ".join(self.labels[i] for i in idx)
        return f"upper lip: {names(self.upper)}; lower lip: {names(self.lower)} ({self.source})"

    def own_markers(self) -> "LipWitness":
        """The same witness over its own markers only (`labels` cut to them, upper first):
        a take's distance from those columns alone, without gathering its other markers."""
        own = tuple(dict.fromkeys(self.labels[i] for i in self.upper + self.lower))
        column = {label: i for i, label in enumerate(own)}
        return LipWitness(tuple(column[self.labels[i]] for i in self.upper),
                          tuple(column[self.labels[i]] for i in self.lower), own, self.source)

    def distance(self, positions) -> np.ndarray:
        """Distance (T,) between the upper and lower markers' centroids, unit of `positions`.

        Parameters
        ----------
        positions : array_like of shape (T, M, 3)
            Positions (or rest pose plus displacements) of the `labels` markers.
            NaN propagates.
        """
        x = as_float_array(positions, "positions", shape=(None, len(self.labels), 3),
                           copy=False)             # only read
        upper = x[:, list(self.upper)].mean(axis=1)
        lower = x[:, list(self.lower)].mean(axis=1)
        return np.linalg.norm(upper - lower, axis=-1)


def lip_witness(markerset, labels: Sequence[str]) -> LipWitness:
    """The lip markers of `markerset` among `labels`.

    Landmark markers (``upper_lip_bottom`` or ``upper_lip_top``, ``lower_lip_top``
    or ``lower_lip_bottom``) when the set names them, else every marker of the
    ``upper_lip`` and ``lower_lip`` regions.

    Raises
    ------
    InputError
        Neither landmarks nor region markers for one of the lips.
    """
    labels = tuple(labels)
    column = {label: i for i, label in enumerate(labels)}
    groups, sources = [], set()
    for points, region in ((_UPPER, "upper_lip"), (_LOWER, "lower_lip")):
        marked = [markerset.landmarks[p] for p in points
                  if markerset.landmarks.get(p) in column]
        if marked:
            groups.append((column[marked[0]],))
            sources.add("landmarks")
            continue
        members = tuple(column[x] for x in markerset.regions.get(region, ()) if x in column)
        if not members:
            raise InputError(f"marker set {markerset.name!r} has no {region.replace('_', ' ')} "
                             f"marker to check the lips with (landmark {' or '.join(points)}, "
                             f"or markers in region {region!r})")
        groups.append(members)
        sources.add("regions")
    return LipWitness(groups[0], groups[1], labels, "+".join(sorted(sources)))


def marker_open_mm(rest_distance: float, *, open_mm: float = OPEN_MM,
                   open_span: float = OPEN_SPAN) -> float:
    """How far the lip markers must part from rest to say the mouth is open, mm.

    ``max(open_mm, open_span * rest_distance)`` (see :data:`OPEN_SPAN`).
    """
    return max(float(open_mm), float(open_span) * float(rest_distance))


def contradicts(opening, other, *, open_mm: float = OPEN_MM,
                fraction: float = SHUT_FRACTION) -> np.ndarray:
    """Frames (mask) where `other` stays shut while `opening` says the mouth is open.

    ``opening >= open_mm`` and ``other < fraction * opening``: both openings
    from the rest pose, in mm, any matching shapes.
    """
    opening, other = np.asarray(opening, dtype=np.float64), np.asarray(other, dtype=np.float64)
    return (opening >= open_mm) & (other < fraction * opening)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) index of every run of True in a 1-D mask."""
    edges = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(edges == 1).tolist(),
                    (np.flatnonzero(edges == -1) - 1).tolist()))


@dataclass(frozen=True, eq=False)
class LipSealCheck:
    """The mesh's lip gap against the markers', frame by frame.

    Attributes
    ----------
    frames : ndarray of int, shape (T,)
        The capture's frame numbers.
    marker_opening : ndarray of shape (T,), mm
        How much farther apart the lip markers are than at rest.
    mesh_gap : dict of str to ndarray of shape (T,), mm
        Each mesh's lip gap.
    rest_gap : float, mm
        The neutral mesh's lip gap (what a mesh opening is measured from).
    open_mm, marker_open_mm, fraction : float
        The thresholds (see :func:`check_lip_seal`): a mesh opened by
        `open_mm` is open, the markers parted by `marker_open_mm` say so.
    witness : str
        Which markers gave `marker_opening`.
    """

    frames: np.ndarray
    marker_opening: np.ndarray
    mesh_gap: dict
    rest_gap: float
    open_mm: float
    marker_open_mm: float
    fraction: float
    witness: str = ""

    def mesh_opening(self, name: str) -> np.ndarray:
        """How much wider mesh `name`'s lip gap is than at rest (T,), mm."""
        return self.mesh_gap[name] - self.rest_gap

    def shut(self, name: str) -> np.ndarray:
        """Frames (mask) where mesh `name` stays shut while the markers open the mouth."""
        return contradicts(self.marker_opening, self.mesh_opening(name),
                           open_mm=self.marker_open_mm, fraction=self.fraction)

    def parted(self, name: str) -> np.ndarray:
        """Frames (mask) where mesh `name` opens the mouth while the markers keep it shut."""
        return contradicts(self.mesh_opening(name), self.marker_opening, open_mm=self.open_mm,
                           fraction=self.fraction)

    def runs(self, name: str, kind: str = "shut") -> list[tuple[int, int]]:
        """``(first, last)`` capture frame numbers of each run of `kind` frames of mesh `name`."""
        if kind not in ("shut", "parted"):
            raise InputError(f"kind must be 'shut' or 'parted', got {kind!r}")
        mask = self.shut(name) if kind == "shut" else self.parted(name)
        return [(int(self.frames[a]), int(self.frames[b])) for a, b in _runs(mask)]

    def messages(self) -> list[str]:
        """One sentence per mesh that contradicts the markers, naming the frames."""
        out = []
        for name in self.mesh_gap:
            for kind in ("shut", "parted"):
                mask = self.shut(name) if kind == "shut" else self.parted(name)
                if not mask.any():
                    continue
                runs = self.runs(name, kind)
                shown = ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in runs[:_SHOWN_RUNS])
                more = f" and {len(runs) - _SHOWN_RUNS} more" if len(runs) > _SHOWN_RUNS else ""
                if kind == "shut":
                    widest = float(self.marker_opening[mask].max())
                    what = (f"the {name} mesh keeps the mouth shut while the lip markers open "
                            f"it (by up to {widest:.0f} mm)")
                else:
                    widest = float(self.mesh_opening(name)[mask].max())
                    what = (f"the {name} mesh opens the mouth (by up to {widest:.0f} mm) while "
                            "the lip markers keep it shut")
                out.append(f"lip seal: {what} in {int(mask.sum())} frames: {shown}{more}")
        return out

    def summary(self) -> dict:
        """Plain data for a manifest: thresholds, widest openings, contradicting frames."""
        return {"open_mm": self.open_mm, "marker_open_mm": self.marker_open_mm,
                "fraction": self.fraction, "witness": self.witness,
                "rest_gap_mm": self.rest_gap,
                "widest_marker_opening_mm": float(np.max(self.marker_opening, initial=0.0)),
                "meshes": {name: {"widest_opening_mm": float(np.max(self.mesh_opening(name),
                                                                    initial=0.0)),
                                  "shut_frames": int(self.shut(name).sum()),
                                  "parted_frames": int(self.parted(name).sum()),
                                  "shut_runs": self.runs(name, "shut"),
                                  "parted_runs": self.runs(name, "parted")}
                           for name in self.mesh_gap}}


def check_lip_seal(marker_distance, mesh_gap: Mapping, *, rest_distance: float,
                   rest_gap: float, first_frame: int = 0, open_mm: float = OPEN_MM,
                   open_span: float = OPEN_SPAN, fraction: float = SHUT_FRACTION,
                   witness: str = "") -> LipSealCheck:
    """Compare the mesh's lip gap with the markers' lip distance, frame by frame.

    Parameters
    ----------
    marker_distance : array_like of shape (T,), mm
        The lip markers' distance (:meth:`LipWitness.distance`); no NaN.
    mesh_gap : mapping of str to array_like of shape (T,), mm
        Lip gap of each mesh (:meth:`mocap.mesh.mouth.MouthOpening.gap`), by name.
    rest_distance : float, mm
        The lip markers' distance in the rest pose.
    rest_gap : float, mm
        The neutral mesh's lip gap.
    first_frame : int
        The capture's number of the first frame.
    open_mm : float
        An opening of at least this much, mm, is open.
    open_span : float
        The markers say the mouth is open when they part by at least this
        fraction of `rest_distance` too (:func:`marker_open_mm`).
    fraction : float
        Shut: opened by less than this fraction of what the other side says.
    witness : str
        Which markers gave `marker_distance` (for the report).

    Returns
    -------
    LipSealCheck

    Raises
    ------
    InputError
        Lengths that differ, NaN, bad thresholds.

    Notes
    -----
    With ``o_m(t)`` the markers' opening (distance minus the rest pose's) and
    ``o_v(t)`` a mesh's (gap minus the neutral's): a frame is *shut* when
    ``o_m >= max(open_mm, open_span * rest_distance)`` and ``o_v < fraction * o_m``,
    *parted* when ``o_v >= open_mm`` and ``o_m < fraction * o_v``.

    Examples
    --------
    Lip markers 30 mm apart at rest part by 20 mm in frames 102-103; the mesh
    opens by half a millimetre:

    >>> check = check_lip_seal([30.0, 50.0, 50.0, 30.0], {"W·D": [1.0, 1.5, 1.5, 1.0]},
    ...                        rest_distance=30.0, rest_gap=1.0, first_frame=101)
    >>> check.runs("W·D")
    [(102, 103)]
    """
    distance = as_float_array(marker_distance, "marker_distance", ndim=1, allow_nan=False)
    n = len(distance)
    open_mm = as_positive_float(open_mm, "open_mm")
    open_span = float(as_float_array(open_span, "open_span", ndim=0, allow_nan=False))
    if open_span < 0:
        raise InputError(f"open_span must be >= 0, got {open_span}")
    fraction = as_positive_float(fraction, "fraction")
    if fraction >= 1:
        raise InputError(f"fraction must be below 1, got {fraction}")
    gaps = {}
    for name, gap in mesh_gap.items():
        gap = as_float_array(gap, f"mesh_gap[{name!r}]", ndim=1, allow_nan=False)
        if len(gap) != n:
            raise InputError(f"mesh_gap[{name!r}] has {len(gap)} frames, the markers {n}")
        gaps[str(name)] = gap
    rest_gap = float(as_float_array(rest_gap, "rest_gap", ndim=0, allow_nan=False))
    rest_distance = float(as_float_array(rest_distance, "rest_distance", ndim=0,
                                         allow_nan=False))
    return LipSealCheck(frames=first_frame + np.arange(n), marker_opening=distance
                        - rest_distance, mesh_gap=gaps, rest_gap=rest_gap,
                        open_mm=open_mm, marker_open_mm=marker_open_mm(
                            rest_distance, open_mm=open_mm, open_span=open_span),
                        fraction=fraction, witness=witness)
