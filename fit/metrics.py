"""Reconstruction error of a take in marker (or vertex) space: α of eq. 6 and friends.

Compare several bases (hand-made, quasi-eigen, PCA) by calling
:func:`reconstruction_errors` once per basis on the same capture, then
:func:`summary_frame` for one table.

References
----------
Kim & Ko, "Intuitive quasi-eigen faces", GRAPHITE 2007, section 5.5, eq. 5-6.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import Mapping

import numpy as np
import pandas as pd

from mocap.errors import InputError, MarkerError
from mocap.util.arrays import read_only
from mocap.util.optional import compiled, compiled_if_worth
from mocap.util.order_statistics import nan_column_percentiles, percentile
from mocap.util.validation import as_choice, as_float_array, as_int, as_positions

__all__ = ["ReconstructionErrors", "reconstruction_errors", "alpha_origin", "summary_frame",
           "separated_peaks", "FRAME_METRICS"]

#: Frames whose differences NumPy's :func:`_squared_errors_by_blocks` forms at a time (they
#: stay in cache).
_ROWS = 1024
#: Samples (frames × markers) from which the compiled pass over them is worth loading numba
#: in a process that has not (its import and the kernel's load take about 0.4 s; the pass
#: saves about 35 ns a sample, 75 ms on 35,000 frames of 60 markers).
_SAMPLES_WORTH_COMPILING = 10_000_000
#: Per-frame series by which frames can be ranked (:meth:`ReconstructionErrors.worst_frames`).
FRAME_METRICS = ("alpha", "displacement_error", "rms", "max_error")


@dataclass(frozen=True, eq=False)
class ReconstructionErrors:
    """Errors of one reconstruction of a take, per frame, per marker and per sample.

    A sample (frame t, marker j) counts when the captured and the reconstructed
    positions are both present; others are excluded from every statistic and
    counted in ``n_missing``.

    Attributes
    ----------
    name : str
        Label of the reconstruction (the basis: ``"H"``, ``"QE"``, ``"PCA"``).
    labels : tuple of str
        Marker (or vertex) names, one per column.
    errors : ndarray, shape (T, M), mm
        ‖v*_tj − v_tj‖; NaN where the sample is excluded.
    alpha : ndarray, shape (T,), %
        Eq. 6 per frame: 100·‖v* − v‖/‖v* − origin‖ over the frame's samples.
    displacement_error : ndarray, shape (T,), %
        100·‖d* − d‖/‖d*‖ with d = v − neutral; NaN where ‖d*‖ = 0.
    rms : ndarray, shape (T,), mm
        Root mean square of the frame's errors.
    max_error : ndarray, shape (T,), mm
        Largest error of the frame.
    n_valid : ndarray of int, shape (T,)
        Samples counted in each frame (frames with none have NaN statistics).
    marker_mean, marker_p95, marker_rms, marker_max : ndarray, shape (M,), mm
        Per marker over its counted frames: mean, 95th percentile (linear
        interpolation), root mean square and largest error.
    n_missing : ndarray of int, shape (M,)
        Frames in which the marker was excluded.
    origin : ndarray, shape (3,), mm
        Origin used for α.
    totals : dict of str to float
        Take-wide figures; see :meth:`summary`.
    """

    name: str
    labels: tuple
    errors: np.ndarray
    alpha: np.ndarray
    displacement_error: np.ndarray
    rms: np.ndarray
    max_error: np.ndarray
    n_valid: np.ndarray
    marker_mean: np.ndarray
    marker_p95: np.ndarray
    marker_rms: np.ndarray
    marker_max: np.ndarray
    n_missing: np.ndarray
    origin: np.ndarray
    totals: dict

    @property
    def n_frames(self) -> int:
        """Number of frames T."""
        return self.errors.shape[0]

    def per_frame(self) -> ReconstructionErrors:
        """These statistics without the per-sample errors (`errors` of shape (T, 0)): what a
        chart of the per-frame series or the per-marker figures reads, cheap to send to
        another process."""
        return dataclasses.replace(self, errors=read_only(self.errors[:, :0].copy()))

    def summary(self) -> dict:
        """Take-wide figures, a new dict.

        Keys: ``alpha`` (eq. 6 pooled over all counted samples of the take, %),
        ``alpha_mean`` and ``alpha_max`` (over frames, %), ``displacement_error``
        (pooled, %), ``rms_mm``, ``mean_mm``, ``p95_mm``, ``max_mm`` (over all
        counted samples), ``worst_frame`` (index of the largest per-frame RMS),
        ``n_samples`` (counted) and ``n_missing`` (excluded).
        """
        return dict(self.totals)

    def worst_frames(self, n: int = 5, *, by: str = "rms", separation: int = 1) -> np.ndarray:
        """Indices of the `n` worst frames, worst first.

        Parameters
        ----------
        n : int
            How many frames (fewer if the take has fewer peaks).
        by : str
            One of ``FRAME_METRICS``.
        separation : int
            Minimum distance between two frames returned, frames: with
            ``separation > 1`` each is a local peak of a distinct event;
            with 1, simply the `n` largest values.

        Returns
        -------
        ndarray of int, shape (≤ n,)
            Frames with NaN statistics are never returned.
        """
        n = as_int(n, "n", minimum=1)
        separation = as_int(separation, "separation", minimum=1)
        series = getattr(self, as_choice(by, "by", FRAME_METRICS))
        if separation == 1:
            ranked = np.argsort(-np.nan_to_num(series, nan=-np.inf), kind="stable")
            return ranked[np.isfinite(series[ranked])][:n]
        return separated_peaks(series, n, separation)

    def to_frame(self, by: str = "frame") -> pd.DataFrame:
        """The statistics as a table.

        Parameters
        ----------
        by : {"frame", "marker"}
            One row per frame (columns ``alpha``, ``displacement_error``,
            ``rms_mm``, ``max_mm``, ``n_valid``) or per marker (index the labels;
            columns ``mean_mm``, ``p95_mm``, ``rms_mm``, ``max_mm``, ``n_missing``).
        """
        if as_choice(by, "by", ("frame", "marker")) == "frame":
            return pd.DataFrame({"alpha": self.alpha,
                                 "displacement_error": self.displacement_error,
                                 "rms_mm": self.rms, "max_mm": self.max_error,
                                 "n_valid": self.n_valid},
                                index=pd.RangeIndex(self.n_frames, name="frame"))
        return pd.DataFrame({"mean_mm": self.marker_mean, "p95_mm": self.marker_p95,
                             "rms_mm": self.marker_rms, "max_mm": self.marker_max,
                             "n_missing": self.n_missing},
                            index=pd.Index(self.labels, name="marker"))


def separated_peaks(series, n: int, separation: int) -> np.ndarray:
    """The `n` highest local peaks of `series` at least `separation` samples apart.

    What ``scipy.signal.find_peaks(series, distance=separation)`` keeps (a plateau's peak is
    its middle sample, left of centre for an even run; a peak within `separation` of a
    higher kept one is dropped), highest first, without importing ``scipy.signal`` (0.4 s
    of a run's start). Equal heights go to the earlier peak.

    Parameters
    ----------
    series : ndarray of shape (T,)
        NaN and infinite samples are never returned (an infinite peak still drops the
        lower ones within `separation`, as in ``find_peaks``).
    n, separation : int
        At least 1.

    Returns
    -------
    ndarray of int, shape (≤ n,)
    """
    series = np.asarray(series, dtype=float)
    values = np.concatenate(([-np.inf], np.nan_to_num(series, nan=-np.inf), [-np.inf]))
    starts = np.flatnonzero(np.r_[True, values[1:] != values[:-1]])   # runs of equal values
    ends = np.r_[starts[1:], len(values)] - 1
    heights = values[starts]
    inner = np.arange(1, len(starts) - 1)
    peak = inner[(heights[inner] > heights[inner - 1]) & (heights[inner] > heights[inner + 1])]
    position = (starts[peak] + ends[peak]) // 2 - 1             # in series, without the pads
    finite = np.isfinite(series[position])
    kept, out = [], []              # an infinite peak still keeps others away, unreturned
    for i in np.argsort(-heights[peak], kind="stable"):    # highest first: at most all peaks
        if all(abs(position[i] - j) >= separation for j in kept):
            kept.append(position[i])
            if finite[i]:
                out.append(position[i])
                if len(out) == n:
                    break
    return np.array(out, dtype=np.intp)


def _ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """100·√num/√den, NaN where den is 0 (or NaN)."""
    out = np.full(np.shape(num), np.nan)
    ok = den > 0
    np.divide(100 * np.sqrt(num), np.sqrt(den, where=ok, out=np.ones_like(den)),
              out=out, where=ok)
    return out


def reconstruction_errors(captured, reconstructed, neutral, *, origin=None,
                          labels=None, name: str = "") -> ReconstructionErrors:
    """Errors of a reconstruction v against the capture v*, per frame and per marker.

    Parameters
    ----------
    captured : array_like, shape (T, M, 3), mm
        v*, NaN where a marker is missing.
    reconstructed : array_like, shape (T, M, 3), mm
        v = neutral + Σ wᵢ eᵢ, NaN where not reconstructed.
    neutral : array_like, shape (M, 3), mm
        The rest positions v⁰ that displacements d = v − v⁰ are taken from;
        no NaN.
    origin : array_like, shape (3,), mm, optional
        Origin of the coordinates in which α measures ‖v*‖. Default: the
        centroid of `neutral`.
    labels : sequence of str, optional
        Names of the M markers (default ``"0"``, ``"1"``, ...).
    name : str
        Label of this reconstruction (the basis).

    Returns
    -------
    ReconstructionErrors

    Raises
    ------
    InputError
        Shapes disagree, or infinite values.
    MarkerError
        `neutral` has NaN for a marker.

    Notes
    -----
    Eq. 6 of the paper, per frame t over its counted samples j,

        α_t = 100 · √(Σ_j ‖v*_tj − v_tj‖²) / √(Σ_j ‖v*_tj − o‖²),

    has a numerator that does not depend on the origin o but a denominator
    that does: the same errors give a smaller α when the face sits far from
    the origin (a head 1.6 m from the capture volume's origin makes any error
    look tiny). The paper does not state its origin, so its α values (0.62 %
    to 5.2 %) only compare bases with each other. The default origin, the
    centroid of the rest positions, makes ‖v* − o‖ the size of the face.
    The displacement-relative error 100·‖d* − d‖/‖d*‖ does not depend on the
    origin but grows without bound near the neutral pose (NaN at ‖d*‖ = 0);
    the RMS in mm depends on neither.

    NaN policy: a sample missing from either array is excluded and counted in
    ``n_missing``; a frame without samples gets NaN statistics.
    """
    captured = as_positions(captured, "captured", copy=False)           # only read
    reconstructed = as_positions(reconstructed, "reconstructed", copy=False)
    if reconstructed.shape != captured.shape:
        raise InputError(f"reconstructed must have the shape of captured {captured.shape}, "
                         f"got {reconstructed.shape}")
    n_frames, n_markers, _ = captured.shape
    neutral = as_float_array(neutral, "neutral", shape=(n_markers, 3))
    labels = (tuple(str(i) for i in range(n_markers)) if labels is None
              else tuple(str(s) for s in labels))
    if len(labels) != n_markers:
        raise InputError(f"labels must name the {n_markers} markers, got {len(labels)}")
    bad = np.isnan(neutral).any(axis=1)
    if bad.any():
        raise MarkerError(labels[int(np.argmax(bad))],
                          "neutral position is NaN; displacements need every rest position")
    origin = alpha_origin(neutral, origin)

    errors, sums, marker_sums = _squared_errors(captured, reconstructed, origin, neutral)
    valid = ~np.isnan(errors)
    n_valid = valid.sum(axis=1)
    per_frame_err, per_frame_pos, per_frame_disp = sums
    has = n_valid > 0
    alpha = _ratio(per_frame_err, per_frame_pos)
    disp = _ratio(per_frame_err, per_frame_disp)
    rms = np.sqrt(per_frame_err / np.maximum(n_valid, 1)) * np.where(has, 1.0, np.nan)
    max_error = np.fmax.reduce(errors, axis=1)              # NaN for a frame without samples

    n_frames_valid = valid.sum(axis=0)
    marker_has = np.where(n_frames_valid > 0, 1.0, np.nan)
    marker_mean = marker_sums[0] / np.maximum(n_frames_valid, 1)
    marker_rms = np.sqrt(marker_sums[1] / np.maximum(n_frames_valid, 1))
    marker_max = np.fmax.reduce(errors, axis=0)             # NaN for a marker never counted
    marker_p95 = nan_column_percentiles(errors, 95)         # NaN for a marker never counted

    n_samples = int(n_valid.sum())
    all_err = errors[valid]
    total_err, total_pos, total_disp = sums.sum(axis=1)
    mean, top = (all_err.mean(), all_err.max()) if n_samples else (np.nan, np.nan)
    # (after the mean and the largest: the percentile partitions all_err in place)
    p95 = percentile(all_err, 95, overwrite_input=True) if n_samples else np.nan
    totals = {
        "alpha": float(_ratio(total_err, total_pos)),
        "alpha_mean": float(np.nanmean(alpha)) if has.any() else np.nan,
        "alpha_max": float(np.nanmax(alpha)) if has.any() else np.nan,
        "displacement_error": float(_ratio(total_err, total_disp)),
        "rms_mm": float(np.sqrt(total_err / n_samples)) if n_samples else np.nan,
        "mean_mm": float(mean),
        "p95_mm": float(p95),
        "max_mm": float(top),
        "worst_frame": int(np.nanargmax(rms)) if has.any() else -1,
        "n_samples": n_samples,
        "n_missing": int(valid.size - n_samples),
    }
    return ReconstructionErrors(
        name=str(name), labels=labels, errors=read_only(errors),
        alpha=read_only(alpha), displacement_error=read_only(disp),
        rms=read_only(rms), max_error=read_only(max_error),
        n_valid=read_only(n_valid), marker_mean=read_only(marker_mean * marker_has),
        marker_p95=read_only(marker_p95), marker_rms=read_only(marker_rms * marker_has),
        marker_max=read_only(marker_max),
        n_missing=read_only(n_frames - n_frames_valid), origin=read_only(origin),
        totals=totals)


def alpha_origin(neutral, origin=None) -> np.ndarray:
    """The origin of α (:func:`reconstruction_errors`), (3,) mm: `origin`, or by default the
    centroid of the rest positions `neutral` (M, 3), mm.

    Raises
    ------
    InputError
        `origin` not 3 finite numbers.
    """
    if origin is None:
        return np.asarray(neutral, dtype=np.float64).mean(axis=0)
    return as_float_array(origin, "origin", shape=(3,), allow_nan=False)


def _squared_errors(captured, reconstructed, origin, neutral):
    """The errors and the squared lengths' sums over the counted samples.

    By the compiled pass of :mod:`fit._metrics_kernel` in a process that has loaded numba,
    or for :data:`_SAMPLES_WORTH_COMPILING` samples or more, else by
    :func:`_squared_errors_by_blocks`: the same errors, sums that agree to rounding.

    Returns
    -------
    errors : ndarray, shape (T, M)
        ‖v* − v‖, NaN where a coordinate of either sample is.
    sums : ndarray, shape (3, T)
        Per frame over its counted samples: Σ‖v* − v‖², Σ‖v* − o‖², Σ‖v* − v⁰‖².
    marker_sums : ndarray, shape (2, M)
        Per marker over its counted frames: Σ‖v* − v‖ and Σ‖v* − v‖².
    """
    n_frames, n_markers = captured.shape[:2]
    kernel = compiled_if_worth(_compiled_errors, n_frames * n_markers,
                               _SAMPLES_WORTH_COMPILING)
    if kernel is None:
        return _squared_errors_by_blocks(captured, reconstructed, origin, neutral)
    errors, sums, marker_sums = np.empty((n_frames, n_markers)), np.empty((3, n_frames)), \
        np.empty((2, n_markers))
    kernel(*(np.ascontiguousarray(a, dtype=np.float64)
             for a in (captured, reconstructed, origin, neutral)), errors, sums, marker_sums)
    return errors, sums, marker_sums


@functools.cache
def _compiled_errors():
    """:func:`fit._metrics_kernel.squared_errors`, or None (NumPy takes the samples by blocks
    of frames): :func:`mocap.util.optional.compiled`."""
    return compiled("fit._metrics_kernel", "squared_errors", what="reconstruction-error pass",
                    fallback="NumPy takes them by blocks of frames, about five times slower")


def _squared_errors_by_blocks(captured, reconstructed, origin, neutral):
    """:func:`_squared_errors` in one pass over the frames, a block of ``_ROWS`` at a time
    (its temporaries stay in the cache)."""
    n_frames, n_markers = captured.shape[:2]
    errors = np.empty((n_frames, n_markers))
    sums = np.empty((3, n_frames))
    marker_sums = np.zeros((2, n_markers))
    differences = np.empty((3, min(_ROWS, n_frames), n_markers * 3))
    # the fixed points as one row of a frame's coordinates (subtracted along whole rows)
    fixed = (np.tile(origin, n_markers), neutral.reshape(-1))
    ones = np.ones(3)
    for first in range(0, n_frames, _ROWS):
        rows = slice(first, first + _ROWS)
        cap = captured[rows].reshape(-1, n_markers * 3)
        diff = differences[:, :len(cap)]
        for k, other in enumerate((reconstructed[rows].reshape(cap.shape), *fixed)):
            np.subtract(cap, other, out=diff[k])
        diff = diff.reshape(3, len(cap), n_markers, 3)
        # the squared lengths: one product of the squares with (1, 1, 1) (a reduction along
        # the 3 coordinates of each sample costs several times more)
        squared = np.square(diff, out=diff) @ ones                  # (3, rows, M)
        np.sqrt(squared[0], out=errors[rows])
        missing = np.isnan(squared[0])                  # the samples not counted
        squared[:, missing] = 0.0
        sums[:, rows] = squared.sum(axis=2)
        marker_sums[0] += np.where(missing, 0.0, errors[rows]).sum(axis=0)
        marker_sums[1] += squared[0].sum(axis=0)
    return errors, sums, marker_sums


def summary_frame(results) -> pd.DataFrame:
    """One row per reconstruction (basis) with the figures of :meth:`ReconstructionErrors.summary`.

    Parameters
    ----------
    results : sequence of ReconstructionErrors, or mapping of name to it
        Rows are named by the mapping's keys, else by each result's ``name``.
    """
    if isinstance(results, Mapping):
        items = list(results.items())
    else:
        items = [(r.name, r) for r in results]
    if not items:
        raise InputError("results is empty: give at least one ReconstructionErrors")
    return pd.DataFrame([r.summary() for _, r in items],
                        index=pd.Index([k for k, _ in items], name="basis"))
