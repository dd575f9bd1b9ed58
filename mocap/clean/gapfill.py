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
from mocap.util.validation import as_choice, as_int

__all__ = ["FILL_OPTIONS", "FillResult", "fill_gaps"]

#: Values of ``fill_gaps(method=...)``: a fill method for every gap, ``"auto"``
#: to choose per gap, or ``"none"`` to only report the gaps.
FILL_OPTIONS = ("spline", "rigid", "pca", "auto", "none")

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
    """

    take: Take
    gaps: pd.DataFrame
    n_filled: int
    n_missing: int
    message: str


def _clusters(take: Take, clusters) -> list[np.ndarray]:
    """Clusters as arrays of columns; each needs a target plus MIN_DONORS donors."""
    if clusters is None:
        return []
    if not isinstance(clusters, Mapping):
        raise InputError("clusters must be a mapping of cluster name to marker labels, "
                         f"got {type(clusters).__name__}")
    out = []
    for name, labels in clusters.items():
        if isinstance(labels, str):
            raise InputError(f"cluster {name!r} must be a list of marker labels, got a string")
        cols = np.unique(take.indices(list(labels)))
        if len(cols) < _rigid_fill.MIN_DONORS + 1:
            raise InputError(
                f"cluster {name!r} has {len(cols)} markers: a rigid fill needs "
                f"{_rigid_fill.MIN_DONORS} donors besides the missing marker, so at least "
                f"{_rigid_fill.MIN_DONORS + 1} markers")
        out.append(cols)
    return out


def _rigid_donors(clusters, visible, target, start, stop):
    """Donors of the target's cluster with the most markers visible over the gap."""
    best, best_count = None, -1
    for cols in clusters:
        if target in cols:
            donors = cols[cols != target]
            count = int(visible[start:stop, donors].all(axis=0).sum())
            if count > best_count:
                best, best_count = donors, count
    return best, best_count


def _fill_one(method, clusters, positions, visible, target, start, stop):
    """Estimate (stop - start, 3) by `method`, NaN where impossible, and why."""
    length = stop - start
    if method == "spline":
        values = fill_spline(positions, visible, target, np.arange(start, stop))
        why = "fewer than 2 visible samples"
    elif method == "rigid":
        donors, _ = _rigid_donors(clusters, visible, target, start, stop)
        if donors is None:
            return np.full((length, 3), np.nan), "not in any rigid cluster"
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
    _, n_rigid = _rigid_donors(clusters, visible, target, start, stop)
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
        Longest gap filled, in frames; longer gaps stay missing. None: no limit.
        0 fills nothing.
    clusters : mapping of str to sequence of str, optional
        Rigid clusters: name -> marker labels (e.g. the head markers). Each
        needs at least 4 markers. Required by ``method="rigid"``.
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
        Unknown method, negative `max_gap`, a cluster with fewer than 4 markers,
        ``method="rigid"`` without clusters.
    MarkerError
        A cluster names a marker not in the take.

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
    if max_gap is not None:
        max_gap = as_int(max_gap, "max_gap", minimum=0)
    if not isinstance(extrapolate, (bool, np.bool_)):
        raise InputError(f"extrapolate must be True or False, got {extrapolate!r}")
    cluster_cols = _clusters(take, clusters)
    if method == "rigid" and not cluster_cols:
        raise InputError("method 'rigid' needs clusters: a mapping of cluster name to "
                         "marker labels")

    positions = take.positions
    visible = ~take.missing
    gaps = find_gaps(take.missing)
    out = positions.copy()
    filled = take.filled.copy()
    rows = []
    for target, start, stop, edge in zip(gaps.marker.tolist(), gaps.start.tolist(),
                                         gaps.stop.tolist(), gaps.at_edge.tolist()):
        used, n, reason = "none", 0, ""
        if method == "none":
            reason = "method is 'none'"
        elif edge and not extrapolate:
            reason = "touches the first or last frame (extrapolate=False)"
        elif max_gap is not None and stop - start > max_gap:
            reason = f"longer than max_gap={max_gap}"
        else:
            if method == "auto":
                used, values, reason = _auto(cluster_cols, positions, visible,
                                             target, start, stop)
            else:
                used = method
                values, reason = _fill_one(method, cluster_cols, positions, visible,
                                           target, start, stop)
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
    message = (f"filled {n_filled} samples in {int((table['filled'] > 0).sum())} of "
               f"{len(table)} gaps; {n_missing} samples still missing")
    return FillResult(take=take.replace(positions=out, filled=filled), gaps=table,
                      n_filled=n_filled, n_missing=n_missing, message=message)
