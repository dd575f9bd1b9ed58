"""Gap-aware low-pass (mocap.clean.lowpass) and resampling (mocap.clean.resample).

Oracles: scipy.signal.sosfiltfilt per segment, the Butterworth magnitude
response, analytic band-limited signals, a brute-force loop over new samples.
"""

import numpy as np
import pytest
from scipy.signal import butter, sosfiltfilt
from tolerances import (
    LOWPASS_GAIN,
    LOWPASS_PASSBAND,
    LOWPASS_STOPBAND,
    LOWPASS_VS_SCIPY_MM,
    RESAMPLE_ALIAS_REL,
    RESAMPLE_COARSE_MM,
    RESAMPLE_MM,
)

from mocap import Analog, InputError, Take
from mocap.clean import lowpass, resample
from mocap.take import fill_code

RATE = 100.0


def sine_take(freqs, n_frames=1000, rate=RATE, amp=10.0):
    """One marker per frequency, x = amp sin(2π f t), y = amp cos(2π f t), z = f."""
    t = np.arange(n_frames) / rate
    f = np.asarray(freqs, float)
    pos = np.stack([amp * np.sin(2 * np.pi * f * t[:, None]),
                    amp * np.cos(2 * np.pi * f * t[:, None]),
                    np.broadcast_to(f, (n_frames, len(f)))], axis=2)
    return Take([f"m{i}" for i in range(len(f))], pos, rate=rate)


def with_gaps(take, gaps):
    pos = take.positions.copy()
    for m, start, stop in gaps:
        pos[start:stop, m] = np.nan
    return take.replace(positions=pos)


# -- lowpass --------------------------------------------------------------------------
@pytest.mark.parametrize("order", [2, 4, 6])
def test_lowpass_matches_sosfiltfilt_without_gaps(order):
    rng = np.random.default_rng(0)
    take = Take(["a", "b"], rng.normal(size=(300, 2, 3)).cumsum(axis=0), rate=RATE)
    sos = butter(order, 8.0, fs=RATE, output="sos")
    expected = sosfiltfilt(sos, take.positions, axis=0)
    np.testing.assert_allclose(lowpass(take, 8.0, order=order).positions, expected,
                               atol=LOWPASS_VS_SCIPY_MM, rtol=0)


@pytest.mark.parametrize("freq", [1.0, 5.0, 10.0, 20.0])
def test_lowpass_gain_is_the_squared_butterworth_response(freq):
    cutoff, order = 6.0, 4
    take = sine_take([freq], n_frames=2000)
    out = lowpass(take, cutoff, order=order).positions[500:1500, 0, :2]
    amplitude = np.sqrt((out ** 2).sum(axis=1)).mean() / 10.0
    warp = np.tan(np.pi * freq / RATE) / np.tan(np.pi * cutoff / RATE)   # bilinear transform
    expected = 1.0 / (1.0 + warp ** (2 * order))   # |H|² of the forward-backward filter
    assert amplitude == pytest.approx(expected, abs=LOWPASS_GAIN)
    if freq < cutoff / 2:
        assert amplitude > LOWPASS_PASSBAND
    if freq > 2 * cutoff:
        assert amplitude < LOWPASS_STOPBAND


def test_lowpass_filters_each_segment_and_keeps_gaps():
    rng = np.random.default_rng(1)
    take = Take(["a", "b", "c"], rng.normal(size=(200, 3, 3)), rate=RATE)
    take = with_gaps(take, [(0, 50, 60), (1, 50, 60), (2, 0, 5), (2, 15, 120)])
    sos = butter(4, 10.0, fs=RATE, output="sos")
    with pytest.warns(UserWarning, match="1 visible segments of at most 15 samples were left"):
        out = lowpass(take, 10.0).positions
    np.testing.assert_array_equal(np.isnan(out), np.isnan(take.positions))
    segments = {0: [(0, 50), (60, 200)], 1: [(0, 50), (60, 200)], 2: [(120, 200)]}
    for m, runs in segments.items():
        for start, stop in runs:
            np.testing.assert_allclose(
                out[start:stop, m], sosfiltfilt(sos, take.positions[start:stop, m], axis=0),
                atol=LOWPASS_VS_SCIPY_MM, rtol=0)
    np.testing.assert_array_equal(out[5:15, 2], take.positions[5:15, 2])   # too short


def test_lowpass_keeps_caller_take_filled_and_analog():
    take = sine_take([2.0], n_frames=100)
    filled = np.zeros((100, 1), np.uint8)
    filled[40:50] = fill_code("pca")
    analog = Analog(np.zeros((1000, 1)), rate=1000.0, labels=("mic",), units=("V",))
    take = take.replace(filled=filled, analog=analog)
    before = take.positions.copy()
    out = lowpass(take, 10.0)
    np.testing.assert_array_equal(take.positions, before)
    np.testing.assert_array_equal(out.filled, filled)
    assert out.analog is analog


@pytest.mark.parametrize("cutoff", [50.0, 60.0])
def test_lowpass_rejects_cutoff_at_or_above_nyquist(cutoff):
    with pytest.raises(InputError, match="below the Nyquist frequency 50 Hz of the take's "
                                         "rate 100 Hz"):
        lowpass(sine_take([1.0], n_frames=50), cutoff)


@pytest.mark.parametrize("kwargs, match", [
    ({"cutoff_hz": -1.0}, "cutoff_hz must be positive"),
    ({"cutoff_hz": 5.0, "order": 0}, "order must be at least 1"),
])
def test_lowpass_rejects_bad_options(kwargs, match):
    with pytest.raises(InputError, match=match):
        lowpass(sine_take([1.0], n_frames=50), **kwargs)


# -- resample ------------------------------------------------------------------------
@pytest.mark.parametrize("old, new", [(120.0, 30.0), (100.0, 60.0), (100.0, 250.0), (30.0, 120.0)])
def test_resample_band_limited_signal_matches_analytic(old, new):
    freqs = [0.5, 2.0]
    take = sine_take(freqs, n_frames=int(10 * old), rate=old)
    out = resample(take, new)
    n_expected = int(np.floor((take.n_frames - 1) * new / old + 1e-9)) + 1
    assert out.n_frames == n_expected and out.rate == new
    t = np.arange(out.n_frames) / new
    truth = sine_take(freqs, n_frames=out.n_frames, rate=new).positions
    inner = (t > 1.0) & (t < t[-1] - 1.0)          # away from the filter's end effects
    tol = RESAMPLE_COARSE_MM if new < 4 * max(freqs) * 4 else RESAMPLE_MM
    np.testing.assert_allclose(out.positions[inner], truth[inner], atol=tol, rtol=0)


def test_resample_attenuates_above_new_nyquist():
    take = sine_take([20.0], n_frames=1200, rate=120.0)     # above 15 Hz, Nyquist of 30 Hz
    out = resample(take, 30.0)
    assert np.abs(out.positions[60:-60, 0, :2]).max() < RESAMPLE_ALIAS_REL * 10.0


def test_resample_missing_mask_and_filled_record_by_brute_force():
    take = sine_take([1.0, 3.0], n_frames=300, rate=100.0)
    take = with_gaps(take, [(0, 40, 57), (1, 0, 13), (1, 100, 101), (0, 299, 300)])
    filled = np.zeros((300, 2), np.uint8)
    filled[80:90, 0] = fill_code("spline")
    filled[200:202, 1] = fill_code("rigid")
    take = take.replace(filled=filled)
    for new in (30.0, 70.0, 250.0):
        out = resample(take, new, cutoff_hz=None if new > 100 else 0.4 * new)
        visible = ~take.missing
        for k in range(out.n_frames):
            u = k * 100.0 / new
            lo, hi = int(np.floor(u + 1e-9)), int(np.ceil(u - 1e-9))
            expect_seen = visible[lo] & visible[hi] if lo != hi else visible[lo]
            if lo != hi:
                expect_seen &= visible[lo:hi + 1].all(axis=0)
            np.testing.assert_array_equal(~out.missing[k], expect_seen, err_msg=f"k={k}")
            near, other = (lo, hi) if u - lo <= 0.5 else (hi, lo)
            code = np.where(filled[near] > 0, filled[near], 0 if lo == hi else filled[other])
            np.testing.assert_array_equal(out.filled[k], np.where(expect_seen, code, 0))


def test_resample_leaves_analog_and_caller_take():
    analog = Analog(np.arange(40.0).reshape(20, 2), rate=200.0, labels=("a", "b"), units=("", ""))
    take = sine_take([1.0], n_frames=100).replace(analog=analog)
    before = take.positions.copy()
    out = resample(take, 50.0)
    assert out.analog is analog and out.first_frame == take.first_frame
    np.testing.assert_array_equal(take.positions, before)
    assert take.rate == RATE


@pytest.mark.parametrize("kwargs, match", [
    ({"rate": 0.0}, "rate must be positive"),
    ({"rate": 50.0, "cutoff_hz": 80.0}, "below the Nyquist frequency 50 Hz"),
])
def test_resample_errors(kwargs, match):
    with pytest.raises(InputError, match=match):
        resample(sine_take([1.0], n_frames=50), **kwargs)
