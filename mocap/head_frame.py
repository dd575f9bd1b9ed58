"""The head frame of a take, for every kind of capture: ``stabilize = "head" | "auto" | "none"``.

- ``"head"``: the marker set's head markers (a headband, a helmet; 3 or more)
  are fitted rigidly in every frame (:func:`mocap.stabilize.stabilize`);
- ``"auto"``: no head markers; the face markers that hold their shape best
  over the take (:func:`mocap.stable_markers.find_stable_markers`, or the
  marker set's ``stabilization`` list) are fitted instead, and the choice,
  each marker's residual and the frames it could not hold are reported;
- ``"none"``: the take is in the head frame already (stabilized upstream, or
  a head-mounted camera); the rigid motion of the face over the take is
  measured, and a warning names it when it looks like head motion.

:func:`find_head_frame` is what ``ingest``, ``bind``, ``retarget``,
``gestures analyze`` and ``run`` call.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from mocap.errors import InputError
from mocap.markerset import MarkerSet
from mocap.stabilize import ROBUST_GUARD_DEG, Stabilization, stabilize
from mocap.stable_markers import StableMarkers, find_stable_markers
from mocap.take import Take, as_take
from mocap.util.arrays import read_only
from mocap.util.order_statistics import nan_column_medians
from mocap.util.validation import as_choice

__all__ = ["STABILIZATIONS", "HeadFrame", "FaceMotion", "find_head_frame", "face_motion",
           "as_stabilization", "stabilization_candidates", "NONE_MAX_DEG", "NONE_MAX_MM",
           "AUTO_SLIP_MM", "JAW_REGIONS"]

#: How the head frame of a take is found.
STABILIZATIONS = ("head", "auto", "none")
#: ``stabilize = "none"`` warns when the face, over the median frame, is
#: turned or shifted by more than this from its mean pose (degrees, mm).
NONE_MAX_DEG = 1.0
NONE_MAX_MM = 2.0
#: A stand-in head marker (``"auto"``) is said not to hold the head frame
#: where it is farther than this from its place on the fitted head, mm. Face
#: skin over bone moves by a millimetre or so with expressions; beyond twice
#: that the marker moves with the face, not with the skull.
AUTO_SLIP_MM = 2.0
#: Regions moved by the jaw and the lips: never stabilization markers when a
#: marker set names them. A jaw-and-cheek set can hold its distances over a
#: take and still turn with the jaw: on a simulated ICT capture it gave
#: 0.56 deg median head error, the upper face 0.20 deg.
JAW_REGIONS = ("upper_lip", "lower_lip", "mouth_corners", "chin", "jaw")


def as_stabilization(value, name: str = "stabilize"):
    """A stabilization option as ``"head"``, ``"auto"``, ``"none"`` or None (off).

    The old boolean spelling is kept: True means ``"head"``, False (and None)
    no stabilization.

    Raises
    ------
    InputError
        Another value.

    Examples
    --------
    >>> as_stabilization(True), as_stabilization("auto"), as_stabilization(False)
    ('head', 'auto', None)
    """
    if value is True:
        return "head"
    if value is False or value is None:
        return None
    return as_choice(value, name, STABILIZATIONS)


@dataclass(frozen=True, eq=False)
class FaceMotion:
    """The rigid motion of the face over a take: the evidence behind ``stabilize = "none"``.

    Attributes
    ----------
    markers : tuple of str
        The markers whose rigid fit measured it (those that hold their shape
        best, :func:`mocap.stable_markers.find_stable_markers`).
    angle : ndarray of shape (n_frames,), degrees
        Rotation of the fit away from its mean over the take (NaN without a fit).
    shift : ndarray of shape (n_frames,), mm
        Displacement of the markers' centroid away from its median.
    median_angle, median_shift : float
        Over the frames (deg, mm).
    worst_frame : int
        Index of the frame turned farthest.
    moves : bool
        Whether a median exceeds :data:`NONE_MAX_DEG` or :data:`NONE_MAX_MM`.
    message : str
    """

    markers: tuple
    angle: np.ndarray
    shift: np.ndarray
    median_angle: float
    median_shift: float
    worst_frame: int
    moves: bool
    message: str


@dataclass(frozen=True, eq=False)
class HeadFrame:
    """How the head frame of a take was found, and the take in it.

    Attributes
    ----------
    method : str
        One of :data:`STABILIZATIONS`.
    stabilization : Stabilization
        Transforms, residuals and the take in the head frame. For ``"none"``
        the identity (``world = head``) with no stabilization markers.
    stable : StableMarkers or None
        ``"auto"``: the markers chosen and why.
    motion : FaceMotion or None
        ``"none"``: the face's rigid motion over the take.
    """

    method: str
    stabilization: Stabilization
    stable: StableMarkers | None = None
    motion: FaceMotion | None = None

    @property
    def take(self) -> Take:
        """The take in the head frame (mm)."""
        return self.stabilization.take

    @property
    def markers(self) -> tuple:
        """The markers fitted rigidly (head markers, the ``auto`` choice, or none)."""
        return self.stabilization.head_markers

    def report(self) -> list:
        """Lines saying how the head frame was found (what ``init`` and ``ingest -v`` print)."""
        st = self.stabilization
        first = st.take.first_frame
        if self.method == "none":
            return [f"head frame: none (the take is taken as in the head frame): "
                    f"{self.motion.message}"]
        what = "head markers" if self.method == "head" else "stabilization markers (auto)"
        lines = [f"head frame: {what} {', '.join(st.head_markers)}; {st.message}"]
        if self.stable is not None:
            lines.append(f"  choice: {self.stable.message}")
        median = nan_column_medians(st.head_residuals)     # NaN: a marker never fitted
        for j, label in enumerate(st.head_markers):
            runs = [s for s in st.slips if s.marker == label]
            held = ("holds the head frame throughout" if not runs else
                    f"does not hold it in {sum(s.stop - s.start for s in runs)} frames: "
                    + ", ".join(f"{first + s.start}-{first + s.stop - 1} "
                                f"({s.max_residual:.1f} mm)" for s in runs[:4])
                    + (" ..." if len(runs) > 4 else ""))
            lines.append(f"  {label}: residual median {median[j]:.2f} mm, {held}")
        for run in st.disagreements[:4]:
            lines.append(f"  robust and plain fits disagree in frames {first + run.start}-"
                         f"{first + run.stop - 1} (up to {run.max_angle:.1f} deg)")
        return lines


def _identity(take: Take) -> Stabilization:
    """The stabilization of a take already in the head frame: R = I, t = 0, no markers."""
    n = take.n_frames
    return Stabilization(
        rotation=read_only(np.broadcast_to(np.eye(3), (n, 3, 3)), copy=True),
        translation=read_only(np.zeros((n, 3))), reference_shape=read_only(np.zeros((0, 3))),
        head_markers=(), head_residuals=read_only(np.zeros((n, 0))),
        valid=read_only(np.ones(n, dtype=bool)), interpolated=read_only(np.zeros(n, dtype=bool)),
        weights=read_only(np.zeros((n, 0))), slips=(), take=take, reference_frame=0, noise=0.0,
        n_iter=0, converged=True, message="the take is in the head frame (stabilize = 'none')",
        robust=False)


def stabilization_candidates(markerset: MarkerSet) -> tuple:
    """Face markers ``"auto"`` may choose: those outside :data:`JAW_REGIONS` (all if < 3 are).

    Examples
    --------
    >>> ms = MarkerSet("x", (), {"upper_lip": ("u",), "nose": ("n1", "n2", "n3")})
    >>> stabilization_candidates(ms)
    ('n1', 'n2', 'n3')
    """
    upper = tuple(x for region, labels in markerset.regions.items() if region not in JAW_REGIONS
                  for x in labels)
    return upper if len(upper) >= 3 else markerset.face_markers


def face_motion(take: Take, labels=None) -> FaceMotion:
    """How much the face of a take moves rigidly: the check of ``stabilize = "none"``.

    Parameters
    ----------
    take : Take
        Positions (n_frames, n_markers, 3), mm, said to be in the head frame.
    labels : sequence of str, optional
        The face markers (default: every marker of the take).

    Returns
    -------
    FaceMotion

    Raises
    ------
    InputError, MarkerError
        As :func:`mocap.stable_markers.find_stable_markers`.

    Notes
    -----
    A rigid fit of all face markers also follows expressions: on the
    head-stabilized ``facial-sing.c3d`` it turns by 1 deg and shifts by 2 mm
    over the median frame (up to 9 deg when the jaw opens). The fit is
    therefore made to the markers that hold their shape best over the take
    (the ``"auto"`` choice, fitted robustly), and the medians over the frames
    are compared with :data:`NONE_MAX_DEG` and :data:`NONE_MAX_MM`: a take in
    the head frame leaves them near the noise, a moving head does not.
    """
    take = as_take(take)
    stable = find_stable_markers(take, labels)
    fit = stabilize(take, stable.labels, guard_deg=None)
    ok = fit.valid
    angle = np.full(take.n_frames, np.nan)
    shift = np.full(take.n_frames, np.nan)
    rotations = Rotation.from_matrix(fit.rotation[ok])
    angle[ok] = np.degrees((rotations.mean().inv() * rotations).magnitude())
    centre = fit.reference_shape.mean(axis=0)
    moved = rotations.apply(centre) + fit.translation[ok]
    shift[ok] = np.linalg.norm(moved - np.median(moved, axis=0), axis=1)
    median_angle, median_shift = float(np.nanmedian(angle)), float(np.nanmedian(shift))
    worst = int(np.nanargmax(angle))
    moves = median_angle > NONE_MAX_DEG or median_shift > NONE_MAX_MM
    message = (f"the {len(stable.labels)} markers that hold their shape best "
               f"({', '.join(stable.labels)}) turn by {median_angle:.2f} deg and shift by "
               f"{median_shift:.2f} mm over the median frame (up to {angle[worst]:.1f} deg at "
               f"frame {take.first_frame + worst})")
    return FaceMotion(markers=stable.labels, angle=read_only(angle), shift=read_only(shift),
                      median_angle=median_angle, median_shift=median_shift, worst_frame=worst,
                      moves=moves, message=message)


def find_head_frame(take: Take, markerset: MarkerSet | None = None, *, method: str = "head",
                    robust: bool = True, guard_deg: float | None = ROBUST_GUARD_DEG,
                    candidates=None) -> HeadFrame:
    """Find the head frame of a take and express the take in it.

    Parameters
    ----------
    take : Take
        Positions (n_frames, n_markers, 3), mm, NaN where missing (fill gaps
        first: a frame needs 3 visible stabilization markers).
    markerset : MarkerSet, optional
        ``"head"``: its head markers. ``"auto"``: its ``stabilization``
        markers if it lists them, else the choice is made among its face
        markers. Without a marker set, ``"auto"`` and ``"none"`` look at every
        marker of the take (or `candidates`).
    method : {"head", "auto", "none"}
        See the module docstring.
    robust : bool, default True
        Fit with the slip-tolerant robust weights (:func:`mocap.stabilize.stabilize`).
    guard_deg : float or None, default ROBUST_GUARD_DEG (2)
        Report (and warn about) the frames where the robust fit turns the
        head by more than this away from the plain least-squares fit.
    candidates : sequence of str, optional
        ``"auto"`` and ``"none"``: the markers to choose among (default: the
        marker set's face markers outside the regions the jaw moves,
        :func:`stabilization_candidates`, or every marker of the take).

    Returns
    -------
    HeadFrame

    Raises
    ------
    InputError
        An unknown method; ``"head"`` without a marker set or with a marker set
        that names no head markers (the message says to use ``"auto"`` or
        ``"none"``).
    MarkerError
        The errors of :func:`mocap.stabilize.stabilize` and
        :func:`mocap.stable_markers.find_stable_markers`.

    Warns
    -----
    UserWarning
        ``"none"`` on a take whose face moves rigidly (:func:`face_motion`);
        robust and plain fits that disagree.

    Examples
    --------
    A take already in the head frame is left as it is:

    >>> rng = np.random.default_rng(1)
    >>> still = rng.uniform(-50, 50, (4, 3)) + 0.05 * rng.standard_normal((200, 4, 3))
    >>> head = find_head_frame(Take(("a", "b", "c", "d"), still, 100.0), method="none")
    >>> head.markers, bool(head.motion.moves), head.take.positions is not None
    ((), False, True)
    """
    take = as_take(take)
    method = as_choice(method, "stabilize", STABILIZATIONS)
    if markerset is not None and not isinstance(markerset, MarkerSet):
        raise InputError(f"markerset must be a MarkerSet, got {type(markerset).__name__}")
    if candidates is None and markerset is not None:
        candidates = stabilization_candidates(markerset)
    if method == "head":
        if markerset is None or not markerset.head:
            named = "no marker set" if markerset is None else \
                f"marker set {markerset.name!r} names no head markers"
            raise InputError(f"stabilize = 'head' needs head markers, but {named}: use "
                             "stabilize = 'auto' (stabilization markers found among the face "
                             "markers) or 'none' (the take is in the head frame already)")
        return HeadFrame("head", stabilize(take, markerset.head, robust=robust,
                                           guard_deg=guard_deg))
    if method == "none":
        motion = face_motion(take, candidates)
        if motion.moves:
            warnings.warn(f"stabilize = 'none' takes {take.source.path or 'the take'} as in the "
                          f"head frame, but {motion.message}: more than {NONE_MAX_DEG:g} deg or "
                          f"{NONE_MAX_MM:g} mm; the head seems to move: use stabilize = "
                          "'head' or 'auto'", stacklevel=2)
        return HeadFrame("none", _identity(take), motion=motion)
    fixed = markerset.stabilization if markerset is not None else ()
    if fixed:
        stable = find_stable_markers(take, fixed, min_markers=len(fixed))
    else:
        stable = find_stable_markers(take, candidates)
    weights = 1.0 / np.maximum(stable.marker_variation, 1e-3)
    fit = stabilize(take, stable.labels, weights=weights / weights.max(), robust=robust,
                    guard_deg=guard_deg, slip_threshold=AUTO_SLIP_MM)
    return HeadFrame("auto", fit, stable=stable)
