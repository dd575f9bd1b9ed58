"""Weight performances (mocap.synth.performance): reading, name matching, resampling."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from scipy.interpolate import interp1d
from tolerances import EXACT_FLOAT64, PERFORMANCE_RATE_REL, TIMECODE_S

from mocap.errors import FileFormatError, InputError
from mocap.synth.performance import (
    NON_WEIGHT_COLUMNS,
    TIME_COLUMNS,
    Performance,
    match_shape_names,
    performance_weights,
    read_performance,
    resample_performance,
)

ICT_SHAPES = [
    "browDown_L", "browDown_R", "browInnerUp_L", "browInnerUp_R", "browOuterUp_L",
    "browOuterUp_R", "cheekPuff_L", "cheekPuff_R", "cheekSquint_L", "cheekSquint_R",
    "eyeBlink_L", "eyeBlink_R", "eyeLookDown_L", "eyeLookDown_R", "eyeLookIn_L", "eyeLookIn_R",
    "eyeLookOut_L", "eyeLookOut_R", "eyeLookUp_L", "eyeLookUp_R", "eyeSquint_L", "eyeSquint_R",
    "eyeWide_L", "eyeWide_R", "jawForward", "jawLeft", "jawOpen", "jawRight", "mouthClose",
    "mouthDimple_L", "mouthDimple_R", "mouthFrown_L", "mouthFrown_R", "mouthFunnel",
    "mouthLeft", "mouthLowerDown_L", "mouthLowerDown_R", "mouthPress_L", "mouthPress_R",
    "mouthPucker", "mouthRight", "mouthRollLower", "mouthRollUpper", "mouthShrugLower",
    "mouthShrugUpper", "mouthSmile_L", "mouthSmile_R", "mouthStretch_L", "mouthStretch_R",
    "mouthUpperUp_L", "mouthUpperUp_R", "noseSneer_L", "noseSneer_R"]


def _write(path, text):
    path.write_text(text, encoding="utf-8")
    return path


# ---------------------------------------------------------------- reading

def test_timecodes_by_hand(tmp_path):
    # 60 fps base; frame fields carry a fraction; 04:58 -> 05:00 crosses a second,
    # 05:02 -> 05:06 drops a frame, 59:58 -> 00:00 crosses a minute and an hour.
    path = _write(tmp_path / "p.csv",
                  "Timecode,BlendShapeCount,JawOpen,EyeBlinkLeft,HeadYaw\n"
                  "13:13:04:58.000,61,0.0,1.0,0\n"
                  "13:13:05:00.000,61,0.5,0.9,0\n"
                  "13:13:05:02.500,61,1.08,0.8,0\n"
                  "13:13:05:06.500,61,0.25,0.7,0\n")
    perf = read_performance(path)
    expected = np.array([0.0, 2 / 60, 4.5 / 60, 8.5 / 60])
    np.testing.assert_allclose(perf.times, expected, atol=EXACT_FLOAT64)
    assert perf.names == ("JawOpen", "EyeBlinkLeft")
    assert perf.ignored == ("BlendShapeCount", "HeadYaw")
    np.testing.assert_array_equal(perf.weights, [[0, 1], [0.5, 0.9], [1.08, 0.8], [0.25, 0.7]])
    assert perf.rate == pytest.approx(1 / (2.5 / 60))      # median step 2.5 frames
    wrap = _write(tmp_path / "w.csv", "Timecode,JawOpen\n00:59:59:58,0\n01:00:00:00,1\n")
    np.testing.assert_allclose(read_performance(wrap).times, [0, 2 / 60], atol=EXACT_FLOAT64)
    wrap30 = _write(tmp_path / "w30.csv", "Timecode,JawOpen\n00:59:59:28,0\n01:00:00:00,1\n")
    assert read_performance(wrap30, timecode_rate=30.0).duration == pytest.approx(2 / 30)


def test_live_link_face_file_against_a_hand_parse(arkit_performance_path):
    path = arkit_performance_path
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    header, body = rows[0], rows[1:]
    seconds = []
    for row in body:                                  # the oracle: plain string arithmetic
        hh, mm, ss, ff = row[0].split(":")
        seconds.append(int(hh) * 3600 + int(mm) * 60 + int(ss) + float(ff) / 60)
    seconds = np.array(seconds) - seconds[0]
    perf = read_performance(path)
    assert perf.n_frames == len(body)
    np.testing.assert_allclose(perf.times, seconds, atol=TIMECODE_S)
    steps = np.round(np.diff(seconds) * 60, 1)
    assert set(steps) == {2.0, 4.0}                   # 30 Hz with dropped frames
    assert np.count_nonzero(steps == 4.0) >= 1
    assert perf.rate == pytest.approx(30, rel=PERFORMANCE_RATE_REL)
    weight_cols = [c for c in header[1:] if c.lower() not in NON_WEIGHT_COLUMNS]
    assert perf.names == tuple(weight_cols) and len(perf.names) == 52
    for i in (0, 1, len(body) // 2, len(body) - 1):
        expected = [float(body[i][header.index(c)]) for c in weight_cols]
        np.testing.assert_array_equal(perf.weights[i], expected)


def test_seconds_column(tmp_path):
    path = _write(tmp_path / "s.csv", "time,jawOpen\n10.0,0.1\n10.5,0.2\n12.0,0.3\n")
    perf = read_performance(path)
    np.testing.assert_allclose(perf.times, [0, 0.5, 2.0])
    assert set(TIME_COLUMNS.values()) == {"timecode", "seconds"}


@pytest.mark.parametrize("text, message", [
    ("Timecode,JawOpen\n13:13:04:31.6,0\n13:13:04:xx,0\n", r"line 3: timecode '13:13:04:xx'"),
    ("Timecode,JawOpen\n13:13:04:61,0\n", r"line 2: .*not below the 60 fps base"),
    ("Timecode,JawOpen\n13:13:04:31,0\n13:13:04:29,0\n", r"line 3: .*times must increase"),
    ("JawOpen,EyeBlinkLeft\n0,0\n", r"needs exactly one time column"),
    ("time,Time,JawOpen\n0,0,0\n", r"needs exactly one time column"),
    ("time,JawOpen\n0,0.1\n1,oops\n", r"line 3: column 'JawOpen': 'oops'"),
    ("time,BlendShapeCount\n0,61\n", r"no weight column besides"),
    ("time,JawOpen\n", r"no samples below the header"),
    ("", r"cannot read performance CSV"),
])
def test_read_errors_name_the_file_and_line(tmp_path, text, message):
    path = _write(tmp_path / "bad.csv", text)
    with pytest.raises(FileFormatError, match=r"bad\.csv.*" + message):
        read_performance(path)


def test_missing_file(tmp_path):
    with pytest.raises(FileFormatError, match=r"nope\.csv: no such file"):
        read_performance(tmp_path / "nope.csv")


# ---------------------------------------------------------------- name matching

@pytest.mark.parametrize("column, shapes", [
    ("EyeBlinkLeft", ["eyeBlink_L"]),
    ("EyeBlinkRight", ["eyeBlink_R"]),
    ("JawOpen", ["jawOpen"]),
    ("MouthLeft", ["mouthLeft"]),           # a direction, not a side: no split
    ("MouthFunnel", ["mouthFunnel"]),
    ("MouthRollUpper", ["mouthRollUpper"]),
    ("BrowInnerUp", ["browInnerUp_L", "browInnerUp_R"]),
    ("CheekPuff", ["cheekPuff_L", "cheekPuff_R"]),
    ("TongueOut", []),
])
def test_arkit_columns_drive_ict_shapes(column, shapes):
    matched = match_shape_names([column], ICT_SHAPES)
    assert sorted(matched) == sorted(shapes)
    assert all(j == 0 for j in matched.values())


def test_an_unsided_shape_wins_over_a_split():
    assert match_shape_names(["BrowInnerUp"], ["browInnerUp", "browInnerUp_L"]) == \
        {"browInnerUp": 0}


def test_all_ict_shapes_are_driven_by_a_live_link_file(shared_data):
    perf = read_performance(shared_data / "arkit-performances" / "alex_rom_4.csv")
    matched = match_shape_names(perf.names, ICT_SHAPES)
    assert set(matched) == set(ICT_SHAPES)
    driving = {perf.names[j] for j in matched.values()}
    assert set(perf.names) - driving == {"TongueOut"}


def test_performance_weights_map_and_warn():
    perf = Performance(("BrowInnerUp", "JawOpen", "TongueOut"), [0.0, 0.1],
                       [[0.3, 0.5, 0.9], [0.4, 1.02, 0.1]], rate=10.0)
    shapes = ["jawOpen", "browInnerUp_R", "eyeBlink_L", "browInnerUp_L"]
    with pytest.warns(UserWarning) as record:
        weights = performance_weights(perf, shapes)
    messages = [str(w.message) for w in record]
    assert any("1 weight columns match no shape of the basis: TongueOut" in m
               for m in messages)
    assert any("1 shapes of the basis have no weight column (held at 0): eyeBlink_L" in m
               for m in messages)
    np.testing.assert_array_equal(weights, [[0.5, 0.3, 0, 0.3], [1.02, 0.4, 0, 0.4]])


def test_no_matching_name_is_an_error():
    perf = Performance(("Foo", "Bar"), [0.0], [[1.0, 2.0]], rate=1.0, path="perf.csv")
    with pytest.raises(InputError, match=r"perf\.csv: none of its weight columns \(Foo, Bar\)"):
        performance_weights(perf, ["jawOpen"])


# ---------------------------------------------------------------- resampling

def _irregular(rng, n=200, rate=30.0):
    """Times of a 30 Hz recording with about one frame in ten dropped."""
    kept = np.sort(rng.choice(int(n * 1.1), n, replace=False))
    return 7.0 + kept / rate                  # not from 0: the grid counts from the first sample


def test_resampling_reproduces_a_linear_function_exactly():
    rng = np.random.default_rng(0)
    times = _irregular(rng)
    slopes, offsets = rng.normal(size=3), rng.normal(size=3)
    perf = Performance(("a", "b", "c"), times, offsets + np.outer(times, slopes), rate=30.0)
    out = resample_performance(perf, 120.0)
    grid = np.arange(len(out.times)) / 120.0
    np.testing.assert_allclose(out.times, grid, atol=EXACT_FLOAT64)
    assert grid[-1] <= times[-1] - times[0] < grid[-1] + 1 / 120
    np.testing.assert_allclose(out.weights, offsets + np.outer(grid + times[0], slopes),
                               atol=EXACT_FLOAT64)
    assert out.rate == 120.0 and out.names == perf.names


@pytest.mark.parametrize("rate", [24.0, 100.0])
def test_resampling_matches_scipy_interp1d(rate):
    rng = np.random.default_rng(1)
    times = _irregular(rng)
    values = rng.uniform(0, 1, (len(times), 5))
    perf = Performance(tuple("abcde"), times, values, rate=30.0)
    out = resample_performance(perf, rate, start=0.5, duration=3.0)
    grid = 0.5 + np.arange(int(3.0 * rate) + 1) / rate
    oracle = interp1d(times - times[0], values, axis=0)(grid)
    np.testing.assert_allclose(out.times, grid - 0.5, atol=EXACT_FLOAT64)
    np.testing.assert_allclose(out.weights, oracle, atol=EXACT_FLOAT64)


def test_resampling_a_sine_is_accurate_to_the_interpolation_bound():
    rng = np.random.default_rng(2)
    times = _irregular(rng, n=600)
    omega = 2 * np.pi * 1.5
    perf = Performance(("s",), times, np.sin(omega * times)[:, None], rate=30.0)
    out = resample_performance(perf, 100.0)
    truth = np.sin(omega * (out.times + times[0]))
    step = np.diff(times).max()
    assert np.abs(out.weights[:, 0] - truth).max() <= step ** 2 / 8 * omega ** 2


def test_resampling_errors():
    perf = Performance(("a",), [0.0, 1.0], [[0.0], [1.0]], rate=1.0)
    with pytest.raises(InputError, match=r"start must be within the performance's 0-1\.000 s"):
        resample_performance(perf, 10.0, start=2.0)
    with pytest.raises(InputError, match=r"rate must be positive"):
        resample_performance(perf, 0.0)
    with pytest.raises(InputError, match=r"duration must be positive"):
        resample_performance(perf, 10.0, duration=-1.0)
    with pytest.raises(InputError, match=r"times must be strictly increasing"):
        Performance(("a",), [0.0, 0.0], [[0.0], [1.0]], rate=1.0)
