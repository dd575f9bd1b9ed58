"""Ingestion of one take: gap filling, low-pass, resampling, head stabilization.

The library function behind ``mocap2mesh ingest`` and the first stage of
``mocap2mesh run``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

from mocap.clean import FILL_OPTIONS as FILL_CHOICES
from mocap.clean import (
    FillResult,
    ImplausibleSamples,
    LabelSwap,
    fill_gaps,
    find_implausible_samples,
    find_label_swaps,
    fix_label_swaps,
    lowpass,
    remove_implausible_samples,
    resample,
)
from mocap.clean.fill_report import fill_notices, marker_visibility
from mocap.clean.gapfill import DEFAULT_MIN_VISIBLE
from mocap.errors import InputError
from mocap.head_frame import STABILIZATIONS, HeadFrame, as_stabilization, find_head_frame
from mocap.markerset import MarkerSet
from mocap.stabilize import ROBUST_GUARD_DEG, Stabilization
from mocap.take import Take
from mocap.util.validation import as_choice, as_fraction, as_int, as_positive_float

__all__ = ["IngestOptions", "IngestResult", "ingest", "FILL_CHOICES", "EXTRA_MARKERS",
           "STABILIZATIONS"]

#: What :func:`ingest` does with the markers of a take that its marker set does
#: not name (``Unlabeled1``, another subject's markers): keep them as they are,
#: gaps and all, or leave them out. Never filled.
EXTRA_MARKERS = ("carry", "drop")


@dataclass(frozen=True)
class IngestOptions:
    """Options of the ingestion stage.

    Attributes
    ----------
    fill : str
        Gap-filling method, one of ``FILL_CHOICES`` (``"none"`` keeps gaps).
    max_gap : int or None
        Longest gap to fill, frames; None:
        :data:`mocap.clean.gapfill.DEFAULT_MAX_GAP_S` at the take's rate
        (10 frames at 100 Hz). Longer gaps are reported, not filled.
    min_visible : float in [0, 1]
        Markers visible in fewer than this fraction of the frames are
        reported, not filled (:func:`mocap.clean.fill_gaps`).
    extra_markers : str
        One of :data:`EXTRA_MARKERS`: markers outside the marker set are
        carried unfilled ("carry") or dropped ("drop").
    lowpass_hz : float or None
        Cut-off of the zero-lag Butterworth low-pass, Hz; None for no filter.
    resample_hz : float or None
        New frame rate, Hz; None keeps the rate.
    stabilize : {"head", "auto", "none"} or None
        How the head frame is found: "head" markers, "auto" (the face markers
        that hold their shape best) or "none" (the take is in it already).
        All markers are then expressed in the head frame
        (:func:`mocap.head_frame.find_head_frame`); None: not stabilized (the
        chain always stabilizes, "head" by default). True and False, the old
        spelling, mean "head" and None.
    robust_stabilization : bool
        Fit the head frame with the slip-tolerant robust weights rather than
        plain least squares (:func:`mocap.stabilize.stabilize`).
    robust_guard_deg : float
        Report the frames where the robust and the plain head fits turn the
        head more than this many degrees apart (default 2).
    fix_swaps : bool
        Find runs of frames where two markers exchanged labels and exchange them
        back, before gap filling (:func:`mocap.clean.find_label_swaps`).
    reject_implausible : bool
        Remove samples that cannot be a real marker (teleports, one marker with
        two labels, interpolated ghost slides; :func:`mocap.clean.find_implausible_samples`,
        in the head frame when the marker set names head markers), after swap
        repair and before gap filling, which fills them again.
    """

    fix_swaps: bool = False
    reject_implausible: bool = False
    fill: str = "auto"
    max_gap: int | None = None
    min_visible: float = DEFAULT_MIN_VISIBLE
    extra_markers: str = "carry"
    lowpass_hz: float | None = None
    resample_hz: float | None = None
    stabilize: str | None = None
    robust_stabilization: bool = True
    robust_guard_deg: float = ROBUST_GUARD_DEG

    def __post_init__(self):
        object.__setattr__(self, "stabilize", as_stabilization(self.stabilize))
        if not isinstance(self.robust_stabilization, bool):
            raise InputError(f"robust_stabilization must be true or false, got "
                             f"{self.robust_stabilization!r}")
        as_positive_float(self.robust_guard_deg, "robust_guard_deg")
        as_choice(self.fill, "fill", FILL_CHOICES)
        if self.max_gap is not None:
            as_int(self.max_gap, "max_gap", minimum=1)
        as_fraction(self.min_visible, "min_visible")
        as_choice(self.extra_markers, "extra_markers", EXTRA_MARKERS)
        if self.lowpass_hz is not None:
            as_positive_float(self.lowpass_hz, "lowpass_hz")
        if self.resample_hz is not None:
            as_positive_float(self.resample_hz, "resample_hz")


@dataclass(frozen=True)
class IngestResult:
    """What ingestion made of a take.

    Attributes
    ----------
    raw : Take
        The take as read.
    swaps : tuple of LabelSwap
        Label swaps found and repaired (empty unless asked).
    implausible : ImplausibleSamples or None
        Samples found implausible and removed before filling (None unless asked).
    fill : FillResult or None
        What gap filling did, gap by gap (None when filling was off).
    cleaned : Take
        After filling, filtering and resampling, in the capture's frame.
    extra_markers : tuple of str
        Markers of the raw take outside the marker set: carried unfilled in
        `cleaned`, or dropped from it (``IngestOptions.extra_markers``).
    notices : tuple of str
        What the user should know (warned too): markers outside the set,
        what filling did and left (:func:`mocap.clean.fill_report.fill_notices`).
    head_frame : HeadFrame or None
        How the head frame was found (head markers, the ``auto`` choice, or
        ``none`` and its check), if stabilization was asked.
    """

    raw: Take
    swaps: tuple[LabelSwap, ...]
    implausible: ImplausibleSamples | None
    fill: FillResult | None
    cleaned: Take
    extra_markers: tuple = ()
    notices: tuple = ()
    head_frame: HeadFrame | None = None

    @property
    def stabilization(self) -> Stabilization | None:
        """Head transforms, residuals and the take in the head frame, if asked."""
        return None if self.head_frame is None else self.head_frame.stabilization

    @property
    def take(self) -> Take:
        """The final take: stabilized if stabilization was asked, else cleaned."""
        return self.cleaned if self.stabilization is None else self.stabilization.take


def ingest(take: Take, *, markerset: MarkerSet | None = None,
           options: IngestOptions = IngestOptions()) -> IngestResult:
    """Clean and stabilize a take.

    Stages, in order: label-swap repair (if asked), removal of implausible
    samples (if asked), gap filling (rigid clusters
    from the marker set), low-pass, resampling, head stabilization.
    With a marker set, only its markers are filled (and fill each other);
    the take's other markers are carried as they are or dropped.

    Parameters
    ----------
    take : Take
    markerset : MarkerSet, optional
        Needed for rigid fills (clusters) and for ``stabilize = "head"`` (head
        markers); ``"auto"`` chooses among its face markers (or its
        ``stabilization`` list). Its markers must all be in the take (after
        its subject ``prefix`` is stripped from the take's labels: the
        result's takes carry the labels without it).
    options : IngestOptions

    Returns
    -------
    IngestResult

    Raises
    ------
    InputError
        The take has no frames; ``stabilize = "head"`` without a marker set
        naming head markers; a resampling rate out of bounds
        (:func:`~mocap.clean.resample`).
    MarkerError
        A marker of the marker set is absent from the take, or too few head
        markers are visible for a rigid fit.

    Warns
    -----
    UserWarning
        Each of :attr:`IngestResult.notices`.
    """
    if take.n_frames == 0:
        raise InputError(f"{take.source.path or 'the take'}: the take has no frames")
    if markerset is not None:
        take = markerset.own_labels(take)
        markerset.check_labels(take.labels, source=take.source.path or "the take")
    if options.stabilize == "head" and (markerset is None or not markerset.head):
        raise InputError("stabilize = 'head' needs a marker set naming the head markers; "
                         "without head markers use 'auto' or 'none'")
    clusters = dict(markerset.clusters) if markerset is not None else None
    where = take.source.path or "the take"
    known = set(markerset.markers) if markerset is not None else set(take.labels)
    extra = tuple(label for label in take.labels if label not in known)
    notices = []
    if extra:
        kept = options.extra_markers == "carry"
        notices.append(f"{where}: {len(extra)} marker(s) outside marker set "
                       f"{markerset.name!r} {'carried unfilled' if kept else 'dropped'} "
                       f"(ingest extra_markers = {options.extra_markers!r}): "
                       + ", ".join(marker_visibility(take, extra)))
    cleaned, fill, swaps, implausible = take, None, (), None
    if extra and options.extra_markers == "drop":
        cleaned = take.select([label for label in take.labels if label in known])
    if options.fix_swaps:
        swaps = find_label_swaps(cleaned)
        cleaned = fix_label_swaps(cleaned, swaps)
    if options.reject_implausible:
        implausible = find_implausible_samples(
            cleaned, head=markerset.head if markerset is not None and markerset.head else None)
        cleaned = remove_implausible_samples(cleaned, implausible)
    if options.fill != "none":
        fill = fill_gaps(cleaned, method=options.fill, max_gap=options.max_gap,
                         min_visible=options.min_visible,
                         markers=None if markerset is None else markerset.markers,
                         clusters=clusters)
        notices += fill_notices(fill, cleaned, where=where)
        cleaned = fill.take
    if options.lowpass_hz is not None:
        cleaned = lowpass(cleaned, options.lowpass_hz)
    if options.resample_hz is not None:
        cleaned = resample(cleaned, options.resample_hz)
    head = None
    if options.stabilize is not None:
        head = find_head_frame(cleaned, markerset, method=options.stabilize,
                               robust=options.robust_stabilization,
                               guard_deg=options.robust_guard_deg)
    for notice in notices:
        warnings.warn(notice, UserWarning, stacklevel=2)
    return IngestResult(raw=take, swaps=swaps, implausible=implausible, fill=fill,
                        cleaned=cleaned, head_frame=head, extra_markers=extra,
                        notices=tuple(notices))


def save_head_motion(stabilization: Stabilization, path, *, inputs=()) -> None:
    """Write head transforms and residuals to ``.npz``, atomically.

    Arrays: ``rotation`` (T, 3, 3), ``translation`` (T, 3) mm (world = R @ head + t),
    ``head_residuals`` (T, H) mm, ``valid`` (T,), ``head_markers`` (H,),
    ``reference_shape`` (H, 3) mm, ``rate`` Hz. `stabilization` may be the
    :class:`~mocap.head_frame.HeadFrame` that holds it: its ``method`` is then
    written too (``"head"``, ``"auto"`` or ``"none"``).
    """
    import numpy as np

    from mocap.util.atomic import atomic_path

    method = {}
    if isinstance(stabilization, HeadFrame):
        method = {"method": np.array(stabilization.method)}
        stabilization = stabilization.stabilization
    # stored, not deflated: rotations, translations and residuals at capture precision
    # deflate by a few percent, at many times the cost of writing them
    with atomic_path(path, inputs=inputs) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(
                fh, rotation=stabilization.rotation, translation=stabilization.translation,
                head_residuals=stabilization.head_residuals, valid=stabilization.valid,
                head_markers=np.array(stabilization.head_markers, dtype=str),
                reference_shape=stabilization.reference_shape,
                rate=np.array(stabilization.take.rate), **method)
