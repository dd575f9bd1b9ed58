"""Gap filling of marker tracks: spline, rigid cluster, PCA, or chosen per gap."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

from mocap.clean import _pca_fill, _rigid_fill
from mocap.clean._pca_fill import fill_pca, pca_donors
from mocap.clean._rigid_fill import fill_rigid
from mocap.clean._spline_fill import fill_spline
from mocap.errors import InputError
from mocap.gaps import find_gaps
from mocap.take import Take, as_take, fill_code
from mocap.util.arrays import read_only
from mocap.util.blas import map_on_blas_threads
from mocap.util.validation import as_choice, as_fraction, as_int

__all__ = ["FILL_OPTIONS", "DEFAULT_MAX_GAP_S", "DEFAULT_MIN_VISIBLE", "FillResult",
           "default_max_gap", "fill_gaps"]

#: Values of ``fill_gaps(method=...)``: a fill method for every gap, ``"auto"``
#: to choose per gap, or ``"none"`` to only report the gaps.
FILL_OPTIONS = ("spline", "rigid", "pca", "auto", "none")
#: Longest gap filled unless a longer one is asked for, s: a tenth of a second,
#: the order of the frame limits that capture software fills on its own (QTM's
#: "Max frame gap", Nexus' and Motive's gap-fill limits, all counted in frames).
#: Given in time because what a fill risks grows with the time the marker was
#: unseen, whatever the frame rate: 10 frames at 100 Hz, 12 at 120 Hz.
DEFAULT_MAX_GAP_S = 0.1
#: A marker seen in fewer than this fraction of the frames is reported, not
#: filled: most of its track would be invented (an ``Unlabeled`` marker seen for
#: a moment, a marker that fell off).
DEFAULT_MIN_VISIBLE = 0.5

_GAP_COLUMNS = ("marker", "start", "stop", "length", "method", "filled", "reason")


@dataclass(frozen=True)
class FillResult:
    """Outcome of :func:`fill_gaps`.

    Attributes
    ----------
    take : Take
        The new take: filled samples set, recorded in ``take.filled`` with
        ``mocap.take.fill_code(method)``; samples left missing stay NaN.
    gaps : pandas.DataFrame
        One row per gap of the input take, ordered by marker then start, with
        columns ``marker`` (label), ``start``, ``stop`` (frame indices, stop
        exclusive; frame number = ``take.first_frame + start``), ``length``
        (frames), ``method`` (``"spline"``, ``"rigid"``, ``"pca"``, or
        ``"none"`` if nothing was filled), ``filled`` (samples filled) and
        ``reason`` (empty when the whole gap was filled, else why not).
    n_filled : int
        Samples filled.
    n_missing : int
        Samples still missing.
    message : str
        One-line summary.
    max_gap : int
        The longest gap that could be filled, frames (the default or as asked).
    unfilled_markers : tuple of str
        Markers left as they were: outside the markers to fill, or seen in
        fewer than ``min_visible`` of the frames.
    """

    take: Take
    gaps: pd.DataFrame
    n_filled: int
    n_missing: int
    message: str
    max_gap: int = 0
    unfilled_markers: tuple = ()


def default_max_gap(rate: float) -> int:
    """The default longest gap filled at a frame rate, frames: :data:`DEFAULT_MAX_GAP_S`, at least 1.

    Examples
    --------
    >>> default_max_gap(100.0), default_max_gap(120.0), default_max_gap(30.0)
    (10, 12, 3)
    """
    return max(1, int(round(DEFAULT_MAX_GAP_S * float(rate))))


def _clusters(take: Take, clusters) -> dict[str, np.ndarray]:
    """Clusters as arrays of columns, by name.

    A cluster of any size is accepted here: its size is checked only when a
    rigid fill is tried for one of its markers (:func:`_rigid_donors`).
    """
    if clusters is None:
        return {}
    if not isinstance(clusters, Mapping):
        raise InputError("clusters must be a mapping of cluster name to marker labels, "
                         f"got {type(clusters).__name__}")
    out = {}
    for name, labels in clusters.items():
        if isinstance(labels, str):
            raise InputError(f"cluster {name!r} must be a list of marker labels, got a string")
        out[str(name)] = np.unique(take.indices(list(labels)))
    return out


def _too_small(name: str, cols) -> str:
    return (f"its cluster {name!r} has {len(cols)} markers: a rigid fill needs "
            f"{_rigid_fill.MIN_DONORS} donors besides the missing marker, so at least "
            f"{_rigid_fill.MIN_DONORS + 1} markers")


def _rigid_donors(clusters, visible, target, start, stop):
    """Donors of the target's cluster with the most markers visible over the gap.

    Returns (donors or None, how many are visible throughout the gap, why
    there are none). Clusters too small to carry the target (fewer than
    MIN_DONORS markers besides it: three markers give two donors, which
    leave the rotation about their axis free) are skipped.
    """
    best, best_count, why = None, -1, "not in any rigid cluster"
    for name, cols in clusters.items():
        if target not in cols:
            continue
        donors = cols[cols != target]
        if len(donors) < _rigid_fill.MIN_DONORS:
            why = _too_small(name, cols)
            continue
        count = int(visible[start:stop, donors].all(axis=0).sum())
        if count > best_count:
            best, best_count = donors, count
    return best, best_count, why


def _fill_one(method, clusters, positions, visible, target, start, stop):
    """Estimate (stop - start, 3) by `method`, NaN where impossible, and why."""
    length = stop - start
    if method == "spline":
        values = fill_spline(positions, visible, target, np.arange(start, stop))
        why = "fewer than 2 visible samples"
    elif method == "rigid":
        donors, _, none_why = _rigid_donors(clusters, visible, target, start, stop)
        if donors is None:
            return np.full((length, 3), np.nan), none_why
        values = fill_rigid(positions, visible, target, start, stop, donors)
        why = (f"{_rigid_fill.MIN_DONORS} donors of its cluster not visible both there "
               "and in a reference frame")
    else:
        donors = pca_donors(visible, target, start, stop)
        if len(donors) < _pca_fill.MIN_DONORS:
            return np.full((length, 3), np.nan), (
                f"only {len(donors)} markers visible throughout the gap; a PCA fill needs "
                f"{_pca_fill.MIN_DONORS}")
        values = fill_pca(positions, visible, target, start, stop, donors)
        why = "marker never visible"
    left = int(np.isnan(values[:, 0]).sum())
    return values, (f"{left} frames left: {why}" if left else "")


def _auto(clusters, positions, visible, target, start, stop):
    """First of rigid, pca, spline that is applicable and fills the whole gap."""
    _, n_rigid, _ = _rigid_donors(clusters, visible, target, start, stop)
    candidates = []
    if n_rigid >= _rigid_fill.MIN_DONORS:
        candidates.append("rigid")
    if len(pca_donors(visible, target, start, stop)) >= _pca_fill.MIN_DONORS:
        candidates.append("pca")
    candidates.append("spline")
    for method in candidates:
        values, reason = _fill_one(method, clusters, positions, visible, target, start, stop)
        if not reason:
            break
    return method, values, reason


def fill_gaps(take: Take, *, method: str = "auto", max_gap: int | None = None,
              min_visible: float = DEFAULT_MIN_VISIBLE, markers=None,
              clusters: Mapping | None = None, extrapolate: bool = False) -> FillResult:
    """Fill the gaps of a take's marker tracks.

    Parameters
    ----------
    take : Take
        Positions (n_frames, n_markers, 3) in mm, NaN where missing. Not modified.
    method : {"spline", "rigid", "pca", "auto", "none"}
        ``"spline"``: cubic spline through the marker's own visible samples.
        ``"rigid"``: carried along with at least three donors of its rigid
        cluster (one batched fit of the donors' mean shape to every frame,
        each donor weighted by how rigidly it moved with the marker next to
        the gap; the marker's position in the donors' frame interpolated
        between the reference frames before and after the gap).
        ``"pca"``: from the markers visible throughout the gap through the
        principal components of the marker coordinates (Gløersen & Federolf
        2016). ``"auto"``: per gap, rigid if the marker's cluster has three
        donors visible throughout it, else PCA if at least 4 other markers
        are, else spline (falling through to the next when one cannot fill
        the whole gap). ``"none"``: fill nothing,
        only report the gaps.
    max_gap : int or None
        Longest gap filled, in frames; longer gaps stay missing (reported).
        None: :func:`default_max_gap` of the take's rate
        (:data:`DEFAULT_MAX_GAP_S`); to fill longer gaps, say how long. 0
        fills nothing.
    min_visible : float in [0, 1]
        A marker visible in fewer than this fraction of the frames is not
        filled at all (its gaps are reported); 0 fills every marker.
    markers : sequence of str, optional
        The markers to fill, and the only ones a fill reads (as donors);
        default every marker of the take. The others are left as they are,
        gaps and all (a marker outside a marker set is never invented).
    clusters : mapping of str to sequence of str, optional
        Rigid clusters: name -> marker labels (e.g. the head markers).
        Required by ``method="rigid"``. A rigid fill of a marker needs 3
        donors of its cluster, so 4 markers: the markers of a smaller
        cluster (3 head markers) are filled by the other methods (``"auto"``)
        or reported (``"rigid"``).
    extrapolate : bool
        Also fill gaps touching the first or last frame. Default False: they
        stay missing (a spline fill there is an extrapolation; rigid and PCA
        fills use the one reference side).

    Returns
    -------
    FillResult
        The new take and a per-gap table of what was done.

    Raises
    ------
    InputError
        Unknown method, negative `max_gap`, `min_visible` outside [0, 1],
        ``method="rigid"`` without clusters.
    MarkerError
        A cluster or `markers` names a marker not in the take.

    Notes
    -----
    NaN policy: fills NaN samples; those it cannot (or may not) fill stay NaN.
    Every gap is filled from the captured samples only, never from samples
    filled for another gap, so the result does not depend on the order of
    the gaps. Filled samples already recorded in ``take.filled`` are kept.

    Examples
    --------
    >>> import numpy as np
    >>> from mocap import Take
    >>> t = np.arange(20.0)
    >>> pos = np.stack([t, t ** 2 / 10, 0 * t], axis=1)[:, None, :].copy()
    >>> pos[8:12] = np.nan
    >>> result = fill_gaps(Take(("a",), pos, rate=100.0), method="spline")
    >>> bool(np.allclose(result.take.positions[8:12, 0, 1], t[8:12] ** 2 / 10))
    True
    >>> result.gaps[["marker", "start", "stop", "method"]].values.tolist()
    [['a', 8, 12, 'spline']]
    """
    take = as_take(take)
    method = as_choice(method, "method", FILL_OPTIONS)
    max_gap = default_max_gap(take.rate) if max_gap is None else as_int(max_gap, "max_gap",
                                                                          minimum=0)
    min_visible = as_fraction(min_visible, "min_visible")
    if not isinstance(extrapolate, (bool, np.bool_)):
        raise InputError(f"extrapolate must be True or False, got {extrapolate!r}")
    cluster_cols = _clusters(take, clusters)
    if method == "rigid" and not cluster_cols:
        raise InputError("method 'rigid' needs clusters: a mapping of cluster name to "
                         "marker labels")
    to_fill = np.zeros(take.n_markers, dtype=bool)
    to_fill[take.indices(take.labels if markers is None else list(markers))] = True

    positions = take.positions
    seen = ~take.missing
    n_seen = seen.sum(axis=0)
    scarce = n_seen < min_visible * take.n_frames
    visible = seen & to_fill                 # only the markers to fill are donors
    found = find_gaps(take.missing)
    gaps = list(zip(found.marker.tolist(), found.start.tolist(), found.stop.tolist(),
                    found.at_edge.tolist()))

    def left_as_it_is(target, start, stop, edge) -> str:
        """Why a gap is not filled ("" when it is)."""
        if not to_fill[target]:
            return "not among the markers to fill"
        if method == "none":
            return "method is 'none'"
        if scarce[target]:
            return (f"visible in {n_seen[target]} of {take.n_frames} frames "
                    f"({100 * n_seen[target] / take.n_frames:.1f} %), under "
                    f"min_visible = {min_visible:g}")
        if edge and not extrapolate:
            return "touches the first or last frame (extrapolate=False)"
        if stop - start > max_gap:
            return f"longer than max_gap={max_gap}"
        return ""

    def estimate(gap) -> tuple:
        """(method used, values (length, 3) NaN where not filled, why not)."""
        target, start, stop, _ = gap
        if method == "auto":
            return _auto(cluster_cols, positions, visible, target, start, stop)
        return (method, *_fill_one(method, cluster_cols, positions, visible, target, start,
                                   stop))

    skipped = [left_as_it_is(*gap) for gap in gaps]
    # every gap is filled from the captured samples only: the gaps are estimated apart,
    # on the BLAS's threads (one GEMM and eigh, or one batched fit, each)
    estimates = iter(map_on_blas_threads(estimate, [gap for gap, why in zip(gaps, skipped)
                                                    if not why]))
    out = positions.copy()
    filled = take.filled.copy()
    rows = []
    for (target, start, stop, _), why in zip(gaps, skipped):
        used, n, reason = "none", 0, why
        if not why:
            used, values, reason = next(estimates)
            ok = ~np.isnan(values[:, 0])
            n = int(ok.sum())
            if n:
                frames = np.arange(start, stop)[ok]
                out[frames, target] = values[ok]
                filled[frames, target] = fill_code(used)
            else:
                used = "none"
        rows.append((take.labels[target], start, stop, stop - start, used, n, reason))

    table = pd.DataFrame(rows, columns=list(_GAP_COLUMNS))
    table = table.astype({"start": np.int64, "stop": np.int64, "length": np.int64,
                          "filled": np.int64})
    n_filled = int(table["filled"].sum())
    n_missing = int(np.isnan(out[:, :, 0]).sum())
    unfilled = tuple(take.labels[j] for j in np.flatnonzero(~to_fill | scarce))
    message = (f"filled {n_filled} samples in {int((table['filled'] > 0).sum())} of "
               f"{len(table)} gaps (max_gap {max_gap} frames); {n_missing} samples still "
               "missing")
    return FillResult(take=take.replace(positions=read_only(out), filled=read_only(filled)),
                      gaps=table, n_filled=n_filled, n_missing=n_missing, message=message,
                      max_gap=max_gap, unfilled_markers=unfilled)
