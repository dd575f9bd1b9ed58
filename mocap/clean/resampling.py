"""Resampling of marker tracks to another frame rate, gap-aware."""

from __future__ import annotations

import numpy as np

from mocap.clean._segments import visible_segments
from mocap.clean.filtering import lowpass
from mocap.errors import InputError
from mocap.take import Take, as_take
from mocap.util.arrays import read_only
from mocap.util.budget import ENV_VAR, format_bytes, max_bytes
from mocap.util.validation import as_int, as_positive_float

__all__ = ["resample", "MAX_UPSAMPLING"]

#: Largest ratio of the new rate to the take's (up-sampling invents no motion:
#: beyond this, it only multiplies the frames).
MAX_UPSAMPLING = 16.0

#: Default anti-aliasing cut-off when down-sampling, as a fraction of the new
#: Nyquist frequency (the value ``scipy.signal.decimate`` uses).
ANTI_ALIAS_FRACTION = 0.8


def resample(take: Take, rate: float, *, cutoff_hz: float | None = None,
             order: int = 4) -> Take:
    """Resample the marker tracks to `rate`, up or down.

    Parameters
    ----------
    take : Take
        Positions (n_frames, n_markers, 3) in mm, NaN where missing. Not modified.
    rate : float
        New frame rate, Hz.
    cutoff_hz : float, optional
        Low-pass applied (with :func:`~mocap.clean.lowpass`) before
        interpolating. Default: ``0.8 * rate / 2`` when down-sampling (the
        anti-aliasing filter), none when up-sampling.
    order : int
        Order of that Butterworth filter.

    Returns
    -------
    Take
        New frames at times ``k / rate`` for every k with ``k / rate`` within the
        take's span; same labels, `first_frame`, `source` and `analog` (analog
        data keep their own rate, untouched).

    Raises
    ------
    InputError
        `rate` or `cutoff_hz` not positive, `rate` above :data:`MAX_UPSAMPLING`
        times the take's, new positions larger than ``MOCAP2MESH_MAX_BYTES``,
        `cutoff_hz` at or above the Nyquist frequency of the input.

    Notes
    -----
    NaN policy: within each run of visible samples the tracks are
    interpolated by a not-a-knot cubic spline (linear for a run of two
    samples); a new sample is missing unless both input frames around it
    are visible (or it falls exactly on a visible one), so gaps keep
    their extent and never grow interpolated values. A new sample is marked
    filled with the code of the nearer of the two input samples around it, or
    of the other one if the nearer was captured.

    Examples
    --------
    >>> import numpy as np
    >>> from mocap import Take
    >>> pos = np.arange(12.0).reshape(4, 1, 3)
    >>> resample(Take(("a",), pos, rate=100.0), 200.0).positions[:, 0, 0].tolist()
    [0.0, 1.5, 3.0, 4.5, 6.0, 7.5, 9.0]
    """
    take = as_take(take)
    rate = as_positive_float(rate, "rate")
    order = as_int(order, "order", minimum=1)
    if rate > MAX_UPSAMPLING * take.rate:
        raise InputError(f"rate {rate:g} Hz is more than {MAX_UPSAMPLING:g} times the take's "
                         f"{take.rate:g} Hz; up-sampling that far adds frames, not detail")
    n_bytes = 24.0 * (take.n_frames * rate / take.rate + 1) * take.n_markers
    if n_bytes > max_bytes():
        raise InputError(f"resampling to {rate:g} Hz would take {format_bytes(n_bytes)} of "
                         f"positions, more than {ENV_VAR} ({format_bytes(max_bytes())})")
    if cutoff_hz is None and rate < take.rate:
        cutoff_hz = ANTI_ALIAS_FRACTION * rate / 2
    source = take if cutoff_hz is None else lowpass(take, cutoff_hz, order=order)

    n_old = take.n_frames
    n_new = int(np.floor((n_old - 1) * rate / take.rate + 1e-9)) + 1 if n_old else 0
    at = np.arange(n_new) * (take.rate / rate)        # in input frame units
    nearest = np.rint(at)
    at = np.where(np.abs(at - nearest) < 1e-9, nearest, at)

    # here: a run that does not resample does not pay for scipy.interpolate's import (75 ms)
    from scipy.interpolate import CubicSpline

    out = np.full((n_new, take.n_markers, 3), np.nan)
    for start, stop, markers in visible_segments(take.missing):
        inside = (at >= start) & (at <= stop - 1)
        if not inside.any():
            continue
        rows = np.flatnonzero(inside)
        if stop - start == 1:
            out[np.ix_(rows, markers)] = source.positions[start, markers]
        else:
            spline = CubicSpline(np.arange(start, stop), source.positions[start:stop, markers],
                                 axis=0)
            out[np.ix_(rows, markers)] = spline(at[rows])

    lo = np.floor(at).astype(np.intp)
    hi = np.minimum(lo + 1, max(n_old - 1, 0))
    near_is_lo = (at - lo) <= 0.5
    near = np.where(near_is_lo[:, None], take.filled[lo], take.filled[hi])
    other = np.where(near_is_lo[:, None], take.filled[hi], take.filled[lo])
    other = np.where((at == lo)[:, None], 0, other)
    filled = np.where(near > 0, near, other).astype(np.uint8)
    filled[np.isnan(out[:, :, 0])] = 0
    return take.replace(positions=read_only(out), rate=rate, filled=read_only(filled))
