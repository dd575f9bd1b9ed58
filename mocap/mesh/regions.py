"""Soft face regions: per-vertex weights of named marker regions, summing to 1.

A marker set groups its markers into regions (``upper_lip``, ``lower_lip``,
``left_brow``, ... and ``other``). Each vertex gets one weight per region from
its distance to the region's markers, so that stages which act per region
(RBF retargeting, per-region residuals) blend smoothly at region borders.
With geodesic distances the blend respects the mouth opening: a vertex of the
lower lip is far from every upper-lip marker.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from mocap.errors import InputError
from mocap.util.validation import as_float_array, as_positive_float

__all__ = ["RegionWeights", "region_weights", "painted_region_weights",
           "as_region_markers"]


@dataclass(frozen=True)
class RegionWeights:
    """Per-vertex weights of named regions.

    Attributes
    ----------
    names : tuple of str
        Region names, in column order.
    weights : ndarray of shape (n_vertices, n_regions)
        Non-negative, each row sums to 1.
    """

    names: tuple[str, ...]
    weights: np.ndarray

    def __getitem__(self, name: str) -> np.ndarray:
        """Weights (n_vertices,) of region `name`."""
        if name not in self.names:
            raise InputError(f"unknown region {name!r}; regions are {list(self.names)}")
        return self.weights[:, self.names.index(name)]


def _marker_name(index: int, labels) -> str:
    return repr(labels[index]) if labels is not None else str(index)


def as_region_markers(regions: Mapping[str, Sequence], n_markers: int, *,
                      labels: Sequence[str] | None = None) -> dict[str, np.ndarray]:
    """Validate a region map: name -> marker indices (or labels), a partition of the markers.

    Parameters
    ----------
    regions : mapping of str to sequence of int or str
        Marker indices, or marker labels when `labels` is given.
    n_markers : int
        Number of markers.
    labels : sequence of str, optional
        Marker labels, to accept labels in `regions` and to name markers in errors.

    Returns
    -------
    dict of str to ndarray of int
        Sorted marker indices of each region, in the mapping's order.

    Raises
    ------
    InputError
        Not a mapping, an unknown marker, or a marker in no region or in two.
        (A region may be empty.)
    """
    if not isinstance(regions, Mapping) or not regions:
        raise InputError("regions must be a non-empty mapping of region name to "
                         f"marker indices, got {type(regions).__name__}")
    lookup = {label: i for i, label in enumerate(labels)} if labels is not None else {}
    owner: dict[int, str] = {}
    out = {}
    for name, members in regions.items():
        if not isinstance(name, str) or not name:
            raise InputError(f"region names must be non-empty strings, got {name!r}")
        if isinstance(members, (str, bytes)) or not hasattr(members, "__len__"):
            raise InputError(f"region {name!r} must be a sequence of markers, "
                             f"got {members!r}")
        indices = []
        for item in members:
            if isinstance(item, str) and item in lookup:
                item = lookup[item]
            if (isinstance(item, (bool, str)) or not isinstance(item, (int, np.integer))
                    or not 0 <= item < n_markers):
                raise InputError(f"region {name!r}: {item!r} is not a marker (expected "
                                 f"an index in 0..{n_markers - 1} or a marker label)")
            if int(item) in owner:
                raise InputError(f"marker {_marker_name(int(item), labels)} is in regions "
                                 f"{owner[int(item)]!r} and {name!r}: expected one region")
            owner[int(item)] = name
            indices.append(int(item))
        out[name] = np.array(sorted(indices), dtype=np.int64)
    missing = sorted(set(range(n_markers)) - set(owner))
    if missing:
        raise InputError(f"marker {_marker_name(missing[0], labels)} is in no region "
                         f"({len(missing)} markers unassigned): every marker needs one")
    return out


def _falloff(t: np.ndarray) -> np.ndarray:
    # 1 at t = 0 with zero slope, 0 (with zero slope) from t = 1 on.
    t = np.clip(t, 0.0, 1.0)
    return 1.0 - t * t * (3.0 - 2.0 * t)


def region_weights(distances, regions: Mapping[str, Sequence], *, width: float,
                   labels: Sequence[str] | None = None) -> RegionWeights:
    """Soft region weights of every vertex from marker-to-vertex distances.

    Parameters
    ----------
    distances : array_like of shape (n_markers, n_vertices)
        Distance from each marker to each vertex, mesh units (geodesic to
        respect the mouth opening, or Euclidean). No NaN.
    regions : mapping of str to sequence of int or str
        Region name -> marker indices (or labels); a partition of the markers.
    width : float, keyword-only
        Blend width, mesh units: a vertex takes a share of region ``r`` while
        it is less than `width` farther from ``r``'s markers than from the
        nearest region's markers.
    labels : sequence of str, optional
        Marker labels (see :func:`as_region_markers`).

    Returns
    -------
    RegionWeights
        Weights (n_vertices, n_regions), rows summing to 1.

    Notes
    -----
    With ``d_r(v)`` the distance from vertex ``v`` to the nearest marker of
    region ``r`` and ``d(v) = min_r d_r(v)``, the raw weight is
    ``g((d_r(v) - d(v)) / width)`` with the smooth step ``g(t) = 1 - 3t^2 +
    2t^3`` on [0, 1] and 0 beyond; rows are then normalized. The nearest
    region always has raw weight 1, and ``g'(0) = 0`` smooths the kink of
    ``d(v)`` on region borders. A weight is exactly 0 beyond the blend band,
    and everywhere for a region without markers.
    """
    distances = as_float_array(distances, "distances", ndim=2, allow_nan=False)
    width = as_positive_float(width, "width")
    members = as_region_markers(regions, distances.shape[0], labels=labels)
    nearest = np.stack([distances[idx].min(axis=0) if len(idx)
                        else np.full(distances.shape[1], np.inf)
                        for idx in members.values()], axis=1)
    raw = _falloff((nearest - nearest.min(axis=1, keepdims=True)) / width)
    return RegionWeights(tuple(members), raw / raw.sum(axis=1, keepdims=True))


def painted_region_weights(masks, names: Sequence[str]) -> RegionWeights:
    """Region weights from externally painted masks, normalized per vertex.

    Parameters
    ----------
    masks : array_like of shape (n_vertices, n_regions)
        Non-negative painted weights (any scale); every vertex needs a
        positive weight in some region. No NaN.
    names : sequence of str
        Region names, one per column.

    Returns
    -------
    RegionWeights
        The masks divided by their row sums.

    Raises
    ------
    InputError
        Wrong shape, duplicate names, negative weights, or a vertex with no weight.
    """
    names = tuple(names)
    masks = as_float_array(masks, "masks", shape=(None, len(names)), allow_nan=False)
    if len(set(names)) != len(names) or not all(isinstance(n, str) for n in names):
        raise InputError(f"names must be distinct strings, got {list(names)}")
    if (masks < 0).any():
        vertex, col = np.argwhere(masks < 0)[0]
        raise InputError(f"masks: vertex {vertex} has a negative weight in region "
                         f"{names[col]!r}; painted weights must be >= 0")
    total = masks.sum(axis=1, keepdims=True)
    empty = np.flatnonzero(total[:, 0] <= 0)
    if len(empty):
        raise InputError(f"masks: vertex {empty[0]} has no weight in any region "
                         f"({len(empty)} such vertices); every vertex needs one")
    return RegionWeights(names, masks / total)
