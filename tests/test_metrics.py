"""Reconstruction error metrics against brute-force loops and hand computations."""

from __future__ import annotations

import sys

import numpy as np
import pandas as pd
import pytest
from helpers import kernel_or_numpy, numba_cannot_cache
from tolerances import EXACT_FLOAT64

import fit.metrics as metrics_module
from fit.metrics import (
    FRAME_METRICS,
    ReconstructionErrors,
    reconstruction_errors,
    separated_peaks,
    summary_frame,
)
from mocap.errors import InputError, MarkerError


def _data(seed=0, n_frames=40, n_markers=7, missing=True):
    rng = np.random.default_rng(seed)
    neutral = rng.normal(scale=50, size=(n_markers, 3)) + [10, -300, 1000]
    captured = neutral + rng.normal(scale=5, size=(n_frames, n_markers, 3))
    recon = captured + rng.normal(scale=0.5, size=captured.shape)
    if missing:
        captured[3, 2] = np.nan
        captured[5:9, 4] = np.nan
        recon[10, 1] = np.nan
        captured[20] = np.nan                       # a frame with no marker at all
    return captured, recon, neutral


def _brute(captured, recon, neutral, origin):
    """Per-frame α, displacement error and RMS with explicit loops."""
    n_frames, n_markers, _ = captured.shape
    alpha, disp, rms = [], [], []
    for t in range(n_frames):
        num = pos = dsp = 0.0
        count = 0
        for j in range(n_markers):
            if np.isnan(captured[t, j]).any() or np.isnan(recon[t, j]).any():
                continue
            e = captured[t, j] - recon[t, j]
            num += e @ e
            pos += (captured[t, j] - origin) @ (captured[t, j] - origin)
            d = captured[t, j] - neutral[j]
            dsp += d @ d
            count += 1
        alpha.append(100 * np.sqrt(num / pos) if count else np.nan)
        disp.append(100 * np.sqrt(num / dsp) if count else np.nan)
        rms.append(np.sqrt(num / count) if count else np.nan)
    return np.array(alpha), np.array(disp), np.array(rms)


@pytest.fixture(params=["compiled", "numpy"])
def errors_by(request, monkeypatch):
    """The samples' pass by numba's loop (the `speed` extra, in .[test]) or by NumPy's
    blocks of frames."""
    return kernel_or_numpy(request.param, monkeypatch, metrics_module, "_compiled_errors",
                           "_SAMPLES_WORTH_COMPILING")


@pytest.mark.parametrize("origin", [None, np.zeros(3), np.array([100.0, -50.0, 900.0])])
def test_per_frame_metrics_match_loops(origin, errors_by):
    captured, recon, neutral = _data()
    res = reconstruction_errors(captured, recon, neutral, origin=origin)
    used = neutral.mean(axis=0) if origin is None else origin
    np.testing.assert_allclose(res.origin, used)
    alpha, disp, rms = _brute(captured, recon, neutral, used)
    np.testing.assert_allclose(res.alpha, alpha, rtol=EXACT_FLOAT64)
    np.testing.assert_allclose(res.displacement_error, disp, rtol=EXACT_FLOAT64)
    np.testing.assert_allclose(res.rms, rms, rtol=EXACT_FLOAT64)
    assert np.isnan(res.alpha[20]) and res.n_valid[20] == 0


def test_a_take_of_many_blocks_of_frames_matches_the_loops(errors_by):
    """Frames are taken a block at a time: a take of several blocks (and a part one), with
    missing samples in each, gives what the loops give frame by frame and marker by marker."""
    captured, recon, neutral = _data(seed=3, n_frames=2 * 1024 + 517)
    rng = np.random.default_rng(4)
    captured[rng.random(captured.shape[:2]) < 0.03] = np.nan
    recon[rng.random(recon.shape[:2]) < 0.01] = np.nan
    res = reconstruction_errors(captured, recon, neutral)
    alpha, disp, rms = _brute(captured, recon, neutral, res.origin)
    np.testing.assert_allclose(res.alpha, alpha, rtol=EXACT_FLOAT64)
    np.testing.assert_allclose(res.displacement_error, disp, rtol=EXACT_FLOAT64)
    np.testing.assert_allclose(res.rms, rms, rtol=EXACT_FLOAT64)
    err = np.linalg.norm(captured - recon, axis=2)
    np.testing.assert_array_equal(np.isnan(res.errors), np.isnan(err))
    np.testing.assert_allclose(res.max_error, [np.nan if np.isnan(row).all()
                                               else np.nanmax(row) for row in err],
                               rtol=EXACT_FLOAT64)
    for j in range(captured.shape[1]):
        col = err[~np.isnan(err[:, j]), j]
        assert res.marker_mean[j] == pytest.approx(col.mean(), rel=EXACT_FLOAT64)
        assert res.marker_rms[j] == pytest.approx(np.sqrt((col ** 2).mean()), rel=EXACT_FLOAT64)
        assert res.marker_max[j] == col.max()
        assert res.marker_p95[j] == np.percentile(col, 95)
    all_err = err[~np.isnan(err)]
    tot = res.summary()
    assert tot["p95_mm"] == np.percentile(all_err, 95) and tot["max_mm"] == all_err.max()
    assert tot["rms_mm"] == pytest.approx(np.sqrt((all_err ** 2).mean()), rel=EXACT_FLOAT64)
    assert tot["n_samples"] == all_err.size


def test_the_compiled_pass_gives_numpys_errors_and_sums(monkeypatch):
    """The same errors bit for bit, the same sums to rounding (added in another order), on
    a take of several of NumPy's blocks with samples missing from either side."""
    captured, recon, neutral = _data(seed=8, n_frames=2 * 1024 + 300)
    rng = np.random.default_rng(9)
    captured[rng.random(captured.shape[:2]) < 0.03] = np.nan
    recon[rng.random(recon.shape[:2]) < 0.01, rng.integers(3)] = np.nan
    origin = neutral.mean(axis=0)
    monkeypatch.setattr(metrics_module, "_SAMPLES_WORTH_COMPILING", 0)
    compiled = metrics_module._squared_errors(captured, recon, origin, neutral)
    by_blocks = metrics_module._squared_errors_by_blocks(captured, recon, origin, neutral)
    np.testing.assert_array_equal(compiled[0], by_blocks[0])
    for ours, numpys in zip(compiled[1:], by_blocks[1:]):
        np.testing.assert_allclose(ours, numpys, rtol=EXACT_FLOAT64, atol=0)


def test_the_compiled_pass_is_loaded_for_a_take_that_pays_for_it(monkeypatch):
    """Loading numba costs about half a second: a process that has not loaded it takes a
    small take's samples by NumPy, a large one's by the compiled pass."""
    captured, recon, neutral = _data(seed=2)
    used = []
    monkeypatch.setattr(metrics_module, "_compiled_errors",
                        lambda real=metrics_module._compiled_errors: used.append(1) or real())
    monkeypatch.delitem(sys.modules, "numba", raising=False)
    small = reconstruction_errors(captured, recon, neutral)
    assert not used
    monkeypatch.setattr(metrics_module, "_SAMPLES_WORTH_COMPILING", captured[..., 0].size)
    large = reconstruction_errors(captured, recon, neutral)
    assert used == [1]
    np.testing.assert_array_equal(large.errors, small.errors)
    np.testing.assert_allclose(large.rms, small.rms, rtol=EXACT_FLOAT64)


def test_numba_without_a_cache_folder_leaves_the_errors_to_numpy_with_a_warning(monkeypatch):
    """numba raises RuntimeError when it can write its compiled code nowhere (a read-only
    install and home): NumPy's blocks take the samples, with a warning saying so."""
    captured, recon, neutral = _data(seed=5)
    monkeypatch.setattr(metrics_module, "_SAMPLES_WORTH_COMPILING", 0)
    numba_cannot_cache(monkeypatch, "fit._metrics_kernel")
    metrics_module._compiled_errors.cache_clear()
    try:
        with pytest.warns(UserWarning, match="compiled reconstruction-error pass is off .*no loc"):
            got = reconstruction_errors(captured, recon, neutral)
        assert metrics_module._compiled_errors() is None
    finally:
        monkeypatch.undo()
        metrics_module._compiled_errors.cache_clear()
    origin = neutral.mean(axis=0)
    errors, sums, _ = metrics_module._squared_errors_by_blocks(captured, recon, origin, neutral)
    np.testing.assert_array_equal(got.errors, errors)
    np.testing.assert_array_equal(got.rms, np.sqrt(sums[0] / np.maximum(got.n_valid, 1))
                                  * np.where(got.n_valid > 0, 1.0, np.nan))


def test_alpha_depends_on_origin_as_expected():
    captured, recon, neutral = _data(missing=False)
    near = reconstruction_errors(captured, recon, neutral)
    shift = np.array([0.0, 0.0, 5000.0])
    far = reconstruction_errors(captured, recon, neutral, origin=near.origin - shift)
    # Same errors, larger ‖v* − o‖: α shrinks by the ratio of the norms.
    centred = np.sqrt(((captured - near.origin) ** 2).sum(axis=(1, 2)))
    shifted = np.sqrt(((captured - near.origin + shift) ** 2).sum(axis=(1, 2)))
    np.testing.assert_allclose(far.alpha, near.alpha * centred / shifted, rtol=EXACT_FLOAT64)
    assert (far.alpha < near.alpha / 10).all()
    # Origin-free figures are unchanged.
    np.testing.assert_array_equal(far.rms, near.rms)
    np.testing.assert_array_equal(far.displacement_error, near.displacement_error)


def test_alpha_of_a_hand_example():
    neutral = np.array([[1.0, 0, 0], [-1.0, 0, 0]])
    captured = np.array([[[3.0, 0, 0], [-1.0, 0, 0]]])       # marker 0 moved 2 mm
    recon = np.array([[[3.0, 4.0, 0], [-1.0, 0, 0]]])        # 4 mm error on marker 0
    res = reconstruction_errors(captured, recon, neutral)     # origin (0, 0, 0)
    assert res.alpha[0] == pytest.approx(100 * 4 / np.sqrt(9 + 1))
    assert res.displacement_error[0] == pytest.approx(100 * 4 / 2)
    assert res.rms[0] == pytest.approx(np.sqrt(16 / 2))
    assert res.max_error[0] == pytest.approx(4.0)
    np.testing.assert_allclose(res.errors, [[4.0, 0.0]])


def test_per_marker_and_totals_match_loops(errors_by):
    captured, recon, neutral = _data()
    res = reconstruction_errors(captured, recon, neutral, labels=list("abcdefg"))
    err = np.linalg.norm(captured - recon, axis=2)
    for j in range(captured.shape[1]):
        col = err[~np.isnan(err[:, j]), j]
        assert res.marker_mean[j] == pytest.approx(col.mean())
        assert res.marker_p95[j] == pytest.approx(np.percentile(col, 95))
        assert res.marker_rms[j] == pytest.approx(np.sqrt((col ** 2).mean()))
        assert res.marker_max[j] == pytest.approx(col.max())
        assert res.n_missing[j] == captured.shape[0] - len(col)
    assert res.n_missing.tolist() == [1, 2, 2, 1, 5, 1, 1]
    all_err = err[~np.isnan(err)]
    tot = res.summary()
    assert tot["n_samples"] == all_err.size
    assert tot["n_missing"] == err.size - all_err.size
    assert tot["rms_mm"] == pytest.approx(np.sqrt((all_err ** 2).mean()))
    assert tot["p95_mm"] == pytest.approx(np.percentile(all_err, 95))
    ok = ~np.isnan(err)
    num = np.nansum(err ** 2)
    den = (((captured - res.origin) ** 2).sum(axis=2))[ok].sum()
    assert tot["alpha"] == pytest.approx(100 * np.sqrt(num / den))
    assert tot["worst_frame"] == int(np.nanargmax(res.rms))


def test_marker_never_seen_is_nan_and_counted():
    captured, recon, neutral = _data(missing=False)
    captured[:, 3] = np.nan
    res = reconstruction_errors(captured, recon, neutral)
    assert np.isnan(res.marker_mean[3]) and np.isnan(res.marker_p95[3])
    assert res.n_missing[3] == captured.shape[0]
    assert np.isfinite(np.delete(res.marker_p95, 3)).all()


def test_displacement_error_nan_at_the_neutral_pose():
    captured, recon, neutral = _data(missing=False)
    captured[0] = neutral
    res = reconstruction_errors(captured, recon, neutral)
    assert np.isnan(res.displacement_error[0])
    assert np.isfinite(res.alpha[0])


def test_inputs_not_mutated_and_result_read_only():
    captured, recon, neutral = _data()
    before = captured.copy()
    res = reconstruction_errors(captured, recon, neutral)
    np.testing.assert_array_equal(captured, before)
    with pytest.raises(ValueError):
        res.errors[0, 0] = 1.0


@pytest.mark.parametrize("seed", range(40))
def test_separated_peaks_are_those_scipy_find_peaks_keeps(seed):
    """The oracle: scipy.signal.find_peaks(distance=...), its peaks ranked by height; series
    with plateaus, NaN runs, peaks at both ends and (rounded) equal heights."""
    from scipy.signal import find_peaks

    rng = np.random.default_rng(seed)
    series = rng.normal(size=int(rng.integers(1, 400)))
    for start in rng.integers(0, len(series), 8):                   # plateaus, NaN runs
        series[start:start + rng.integers(1, 6)] = series[start] if start % 3 else np.nan
    if seed % 4 == 0:                                               # equal heights
        series = np.round(series, 1)
    if seed % 5 == 0:                                               # never returned
        series[rng.integers(0, len(series))] = np.inf
    n, separation = int(rng.integers(1, 12)), int(rng.integers(1, 30))
    padded = np.concatenate(([-np.inf], np.nan_to_num(series, nan=-np.inf), [-np.inf]))
    peaks = find_peaks(padded, distance=separation, plateau_size=1)[0] - 1
    peaks = peaks[np.isfinite(series[peaks])]
    got = separated_peaks(series, n, separation)
    # of two close peaks of equal height, scipy may keep the other one: compare the heights
    # and, where all peaks' heights are distinct, the frames
    expected = peaks[np.argsort(-series[peaks], kind="stable")][:n]
    np.testing.assert_array_equal(series[got], series[expected])
    every = find_peaks(padded, plateau_size=1)[0] - 1
    if len(np.unique(series[every])) == len(every):
        np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("by", FRAME_METRICS)
def test_worst_frames_are_separated_peaks(by):
    captured, recon, neutral = _data(n_frames=200, missing=False)
    recon = recon.copy()
    for t, amp in ((30, 20.0), (31, 18.0), (120, 10.0), (199, 4.0)):
        recon[t] += amp
    res = reconstruction_errors(captured, recon, neutral)
    assert res.worst_frames(3, by=by, separation=5).tolist() == [30, 120, 199]
    assert res.worst_frames(2, by=by).tolist() == [30, 31]


def test_tables():
    captured, recon, neutral = _data()
    a = reconstruction_errors(captured, recon, neutral, labels=list("abcdefg"), name="QE")
    b = reconstruction_errors(captured, captured, neutral, labels=list("abcdefg"), name="PCA")
    frame = a.to_frame()
    assert isinstance(frame, pd.DataFrame) and len(frame) == captured.shape[0]
    np.testing.assert_array_equal(frame["alpha"], a.alpha)
    markers = a.to_frame("marker")
    assert list(markers.index) == list("abcdefg")
    np.testing.assert_array_equal(markers["p95_mm"], a.marker_p95)
    table = summary_frame([a, b])
    assert list(table.index) == ["QE", "PCA"]
    assert table.loc["PCA", "rms_mm"] == 0.0
    assert table.loc["QE", "alpha"] == a.summary()["alpha"]


def test_errors():
    captured, recon, neutral = _data()
    with pytest.raises(InputError, match="reconstructed must have the shape"):
        reconstruction_errors(captured, recon[:, :3], neutral)
    with pytest.raises(InputError, match="neutral must have shape"):
        reconstruction_errors(captured, recon, neutral[:3])
    bad = neutral.copy()
    bad[2] = np.nan
    with pytest.raises(MarkerError, match="'c': neutral position is NaN"):
        reconstruction_errors(captured, recon, bad, labels=list("abcdefg"))
    with pytest.raises(InputError, match="labels must name the 7 markers"):
        reconstruction_errors(captured, recon, neutral, labels=["a"])
    with pytest.raises(InputError, match="origin contains NaN"):
        reconstruction_errors(captured, recon, neutral, origin=[np.nan, 0, 0])
    res = reconstruction_errors(captured, recon, neutral)
    with pytest.raises(InputError, match="by must be one of"):
        res.worst_frames(3, by="median")
    with pytest.raises(InputError, match="results is empty"):
        summary_frame([])
    assert isinstance(res, ReconstructionErrors)
