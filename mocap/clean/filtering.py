"""Zero-lag Butterworth low-pass of marker tracks that respects gaps."""

from __future__ import annotations

import warnings

import numpy as np

from mocap.clean._segments import visible_segments
from mocap.errors import InputError
from mocap.take import Take, as_take
from mocap.util.arrays import read_only
from mocap.util.validation import as_int, as_positive_float

__all__ = ["lowpass"]


def _pad_length(sos: np.ndarray) -> int:
    """The pad length ``sosfiltfilt`` uses by default for `sos`."""
    zeros = min(int((sos[:, 2] == 0).sum()), int((sos[:, 5] == 0).sum()))
    return 3 * (2 * len(sos) + 1 - zeros)


def lowpass(take: Take, cutoff_hz: float, *, order: int = 4) -> Take:
    """Low-pass every marker track with a zero-lag Butterworth filter.

    Parameters
    ----------
    take : Take
        Positions (n_frames, n_markers, 3) in mm, NaN where missing. Not modified.
    cutoff_hz : float
        Cut-off frequency, Hz; must be below the Nyquist frequency ``rate / 2``.
    order : int
        Order of the Butterworth design (applied forward and backward, so the
        effective order is doubled and the phase lag is zero).

    Returns
    -------
    Take
        A new take with filtered positions; `filled`, `analog` and the rest
        are carried over.

    Raises
    ------
    InputError
        `cutoff_hz` not positive or at or above the Nyquist frequency; `order`
        not a positive integer.

    Warns
    -----
    UserWarning
        When some visible segments are too short to filter (see Notes).

    Notes
    -----
    NaN policy: gaps are kept. Each contiguous run of visible (or filled)
    samples is filtered separately with ``scipy.signal.sosfiltfilt`` (markers
    whose runs span the same frames in one call), and the NaNs stay where
    they were. A run of at most ``3 * (2 * n_sections + 1)`` samples (15 for
    order 4), the filter's default pad length, is left unfiltered: padding it
    would extrapolate more than the data.

    Examples
    --------
    >>> import numpy as np
    >>> from mocap import Take
    >>> t = np.arange(200) / 100.0
    >>> pos = np.zeros((200, 1, 3)); pos[:, 0, 0] = np.sin(2 * np.pi * t)
    >>> smooth = lowpass(Take(("a",), pos, rate=100.0), 10.0)
    >>> bool(np.abs(smooth.positions[20:-20, 0, 0] - pos[20:-20, 0, 0]).max() < 1e-3)
    True
    """
    take = as_take(take)
    cutoff_hz = as_positive_float(cutoff_hz, "cutoff_hz")
    order = as_int(order, "order", minimum=1)
    nyquist = take.rate / 2
    if cutoff_hz >= nyquist:
        raise InputError(f"cutoff_hz={cutoff_hz:g} Hz must be below the Nyquist frequency "
                         f"{nyquist:g} Hz of the take's rate {take.rate:g} Hz")
    from scipy.signal import butter, sosfiltfilt  # here: scipy.signal takes ~0.5 s to import

    sos = butter(order, cutoff_hz, fs=take.rate, output="sos")
    pad = _pad_length(sos)
    out = take.positions.copy()
    short = 0
    for start, stop, markers in visible_segments(take.missing):
        if stop - start <= pad:
            short += len(markers)
            continue
        out[start:stop, markers] = sosfiltfilt(sos, out[start:stop, markers], axis=0)
    if short:
        warnings.warn(f"{short} visible segments of at most {pad} samples were left "
                      f"unfiltered (too short for an order-{order} filter's padding)",
                      UserWarning, stacklevel=2)
    return take.replace(positions=read_only(out))
