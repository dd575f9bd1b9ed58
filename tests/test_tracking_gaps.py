"""Performances with rows where tracking was lost (Live Link Face ``16:48:52:29.134,0``).

The file is derived from a shared ARKit performance: runs of its rows are
replaced by what a real export writes when the phone loses the face (the
timecode, a BlendShapeCount of 0 and no values; or empty cells). Oracles: the
untouched file itself, the timecodes parsed by hand, numpy's interp.
"""

from __future__ import annotations

import csv
import re
import warnings

import numpy as np
import pytest
from helpers import ICT_LAYOUT_TOML, ICT_MARKERSET_TOML
from tolerances import EXACT_FLOAT64, TIMECODE_S

import mocap
from basis.artist import load_artist_basis
from fit.cli.main import main
from fit.gestures import clip_from_performance, synthesize_gestures
from mocap.errors import FileFormatError, InputError
from mocap.mesh.layout import load_marker_layout
from mocap.synth.capture import simulate_capture
from mocap.synth.performance import (
    Performance,
    performance_weights,
    read_performance,
    resample_performance,
)
from mocap.synth.performance_gaps import fill_tracking_gaps

#: Runs of rows replaced (row indices below the header, stop exclusive) and how:
#: "short" as Live Link Face writes them (timecode, 0), "cells" with every cell empty.
#: 132 rows at ~30 Hz are the 4.4 s of the longest run seen in real exports.
RUNS = ((0, 3, "short"), (1000, 1132, "short"), (2000, 2002, "cells"), (4020, 4030, "short"))
SHAPES = ("jawOpen", "eyeBlink_L", "eyeBlink_R", "mouthSmile_L")


def _rows(path):
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    return rows[0], rows[1:]


@pytest.fixture(scope="module")
def lost_csv(arkit_performance_path, tmp_path_factory):
    header, body = _rows(arkit_performance_path)
    assert len(body) == 4030
    out = []
    lost = np.zeros(len(body), bool)
    for start, stop, form in RUNS:
        lost[start:stop] = True
    for i, row in enumerate(body):
        if not lost[i]:
            out.append(",".join(row))
        elif any(a <= i < b and form == "cells" for a, b, form in RUNS):
            out.append(row[0] + "," + "," * (len(header) - 2))
        else:
            out.append(f"{row[0]},0")
    path = tmp_path_factory.mktemp("lost") / "lost.csv"
    path.write_text(",".join(header) + "\n" + "\n".join(out) + "\n", encoding="utf-8")
    return path, lost


@pytest.fixture(scope="module")
def lost_performance(lost_csv):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_performance(lost_csv[0])


def test_lost_rows_are_gaps_not_a_rejection(lost_csv, arkit_performance_path):
    path, lost = lost_csv
    with pytest.warns(UserWarning) as caught:
        perf = read_performance(path)
    whole = read_performance(arkit_performance_path)
    np.testing.assert_array_equal(perf.lost, lost)
    assert np.isnan(perf.weights[lost]).all()
    np.testing.assert_array_equal(perf.weights[~lost], whole.weights[~lost])
    np.testing.assert_allclose(perf.times, whole.times - whole.times[0] + perf.times[0],
                               atol=EXACT_FLOAT64)
    assert perf.names == whole.names
    # the spans, against the timecodes of the untouched file parsed by hand
    _, body = _rows(arkit_performance_path)
    seconds = np.array([sum(float(x) * f for x, f in zip(row[0].split(":"),
                                                        (3600, 60, 1, 1 / 60))) for row in body])
    seconds -= seconds[3]                               # the first row read is row 0 (lost)
    seconds += perf.times[3] - seconds[3]
    gaps = perf.gaps()
    assert [(g.start, g.stop) for g in gaps] == [(0, 3), (1000, 1132), (2000, 2002), (4020, 4030)]
    for gap in gaps[:-1]:
        assert gap.start_time == pytest.approx(seconds[gap.start] - seconds[0], abs=TIMECODE_S)
        assert gap.end_time == pytest.approx(seconds[gap.stop] - seconds[0], abs=TIMECODE_S)
    assert 4.3 < gaps[1].duration < 4.5
    message = str(caught[0].message)
    assert (f"tracking was lost in 147 of 4030 samples, 4 run(s)" in message
            and f"the longest {gaps[1].duration:.2f} s, samples 1000-1131 (lines 1002-1133, "
                f"from {body[1000][0]} at {gaps[1].start_time:.3f} s)" in message)


def test_resampling_keeps_gaps_and_is_exact_on_tracked_samples(lost_performance):
    perf = lost_performance
    grid = resample_performance(perf, 100.0)
    gap = perf.gaps()[1]
    inside = (grid.times > gap.start_time - perf.times[0]) & (grid.times < gap.end_time)
    inside &= grid.times >= perf.times[gap.start - 1]
    assert np.isnan(grid.weights[inside & (grid.times > perf.times[gap.start - 1])
                                 & (grid.times < perf.times[gap.stop])]).all()
    tracked = ~perf.lost
    seg = (grid.times >= perf.times[gap.stop]) & (grid.times <= perf.times[1999])
    j = perf.names.index("JawOpen")
    np.testing.assert_allclose(grid.weights[seg, j],
                               np.interp(grid.times[seg], perf.times[tracked],
                                         perf.weights[tracked, j]), atol=EXACT_FLOAT64)
    mapped = performance_weights(grid, ("jawOpen", "notAColumn"))
    assert np.isnan(mapped[grid.lost]).all() and not np.isnan(mapped[~grid.lost]).any()


@pytest.mark.parametrize("method", ["linear", "neutral"])
def test_gaps_are_filled_only_when_asked(lost_performance, method):
    perf = lost_performance
    filled = fill_tracking_gaps(perf, method)
    assert not filled.lost.any()
    tracked = ~perf.lost
    np.testing.assert_array_equal(filled.weights[tracked], perf.weights[tracked])
    if method == "neutral":
        assert (filled.weights[perf.lost] == 0).all()
    else:
        for j in (0, perf.names.index("JawOpen")):
            np.testing.assert_allclose(filled.weights[perf.lost, j],
                                       np.interp(perf.times[perf.lost], perf.times[tracked],
                                                 perf.weights[tracked, j]), atol=EXACT_FLOAT64)
    short = fill_tracking_gaps(perf, method, max_duration=1.0)
    np.testing.assert_array_equal(short.lost, perf.lost & (np.arange(perf.n_frames) >= 1000)
                                  & (np.arange(perf.n_frames) < 1132))


@pytest.mark.parametrize("call, match", [
    (lambda p: fill_tracking_gaps(p, "spline"), r"method must be one of \['linear', 'neutral'\]"),
    (lambda p: fill_tracking_gaps(p, "linear", max_duration=0),
     "max_duration must be positive and finite, got 0"),
    (lambda p: fill_tracking_gaps(p.weights, "linear"), "performance must be a Performance"),
    (lambda p: Performance(("a", "b"), [0, 1], [[0.1, np.nan], [0.2, 0.3]], 1.0),
     "weights of sample 0 are partly NaN"),
    (lambda p: Performance(("a",), [0, 1], [[np.nan], [np.nan]], 1.0),
     "every sample of the performance is lost"),
    (lambda p: resample_performance(p, 100.0, start=p.gaps()[1].start_time + 0.5,
                                    duration=2.0), r"tracking is lost over the whole of "
                                                   r"\d+\.\d{3}-\d+\.\d{3} s"),
])
def test_tracking_gap_errors(lost_performance, call, match):
    with pytest.raises(InputError, match=match):
        call(lost_performance)


@pytest.mark.parametrize("text, match", [
    ("Timecode,BlendShapeCount,JawOpen,EyeBlinkLeft\n13:13:04:31.6,2,0.1,0.2\n"
     "13:13:04:33.6,2,,0.3\n", r"line 3: column 'JawOpen': '' is not a finite number"),
    ("Timecode,BlendShapeCount,JawOpen\n13:13:04:31.6,0\n13:13:04:33.6,0\n",
     "tracking was lost in every one of its 2 rows"),
])
def test_a_partly_empty_row_or_no_tracked_row_is_an_error(tmp_path, text, match):
    path = tmp_path / "bad.csv"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(FileFormatError, match=r"bad\.csv.*" + match):
        read_performance(path)


# ---------------------------------------------------------------- the readers of performances

@pytest.fixture(scope="module")
def gap_clip(lost_performance):
    return clip_from_performance(lost_performance, name="lost", rate=30.0)


def test_synth_copes_markers_missing_where_tracking_was_lost(lost_performance, ict_neutral_path,
                                                             ict_expressions_dir, ict_markerset):
    basis = load_artist_basis(ict_neutral_path, ict_expressions_dir, names=SHAPES, units="cm")
    layout = load_marker_layout(ICT_LAYOUT_TOML, basis.neutral)
    gap = lost_performance.gaps()[1]
    options = dict(rate=50.0, start=gap.start_time - 1.0, duration=7.0, seed=3)
    with pytest.warns(UserWarning, match=r"tracking was lost in \d+ of the capture's 351 "
                                         r"frames"):
        sim = simulate_capture(basis, lost_performance, layout, ict_markerset.head, **options)
    lost = np.isnan(sim.truth.weights).any(axis=1)
    times = np.arange(351) / 50.0 + options["start"]
    inside = (times > gap.start_time) & (times < gap.end_time)
    assert lost[inside].all() and lost.sum() <= inside.sum() + 2
    head = [sim.take.index(h) for h in ict_markerset.head]
    face = [j for j in range(sim.take.n_markers) if j not in head]
    assert np.isnan(sim.take.positions[lost][:, face]).all()
    assert not np.isnan(sim.take.positions[:, head]).any()
    np.testing.assert_array_equal(sim.truth.missing[lost][:, face], True)
    # elsewhere the capture is that of the performance with its gaps filled (same seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        full = simulate_capture(basis, fill_tracking_gaps(lost_performance, "linear"), layout,
                                ict_markerset.head, **options)
    np.testing.assert_array_equal(sim.take.positions[~lost], full.take.positions[~lost])


def test_synth_cli_keeps_or_fills_the_gaps(lost_csv, ict_neutral_path, ict_expressions_dir,
                                           tmp_path):
    path = lost_csv[0]
    args = ["synth", "--mesh", str(ict_neutral_path), "--units", "cm",
            "--shapes", str(ict_expressions_dir), "--performance", str(path),
            "--layout", str(ICT_LAYOUT_TOML), "--markerset", str(ICT_MARKERSET_TOML),
            "--rate", "30", "--start", "32", "--duration", "6"]
    with pytest.warns(UserWarning) as caught:
        assert main(args + ["-o", str(tmp_path / "kept.c3d")]) == 0
    said = [str(w.message) for w in caught]
    assert any(re.search(r"lost\.csv: tracking was lost in 147 of 4030", m) for m in said)
    assert any("its face markers are missing there" in m for m in said)
    with pytest.warns(UserWarning) as caught:
        assert main(args + ["-o", str(tmp_path / "filled.c3d"), "--tracking-gaps", "linear"]) == 0
    assert not any("face markers are missing" in str(w.message) for w in caught)
    kept, filled = (mocap.read(tmp_path / f"{n}.c3d") for n in ("kept", "filled"))
    assert kept.missing.all(axis=1).sum() == 0        # head markers seen throughout
    assert kept.missing.any(axis=1).sum() > 100 and not filled.missing.any()


def test_gesture_clip_of_a_performance_with_gaps(lost_performance, gap_clip):
    grid = resample_performance(lost_performance, 30.0)
    np.testing.assert_array_equal(np.isnan(gap_clip.weights).all(axis=1), grid.lost)
    assert np.isnan(gap_clip.intensity[grid.lost]).all()
    assert np.isfinite(gap_clip.intensity[~grid.lost]).mean() > 0.95
    drive = np.nan_to_num(gap_clip.intensity[1200:1500], nan=-60.0)
    syn = synthesize_gestures(drive, [gap_clip], rate=30.0, seed=2)
    assert np.isfinite(syn.weights).all()
    copied = syn.sources["weights"][:, 1]
    assert not grid.lost[copied].any()


def test_synth_cli_refuses_a_performance_never_tracked(tmp_path, ict_neutral_path,
                                                       ict_expressions_dir, capsys):
    path = tmp_path / "never.csv"
    path.write_text("Timecode,BlendShapeCount,JawOpen\n13:13:04:31.6,0\n13:13:04:33.6,0\n",
                    encoding="utf-8")
    code = main(["synth", "--mesh", str(ict_neutral_path), "--units", "cm",
                 "--shapes", str(ict_expressions_dir), "--performance", str(path),
                 "--layout", str(ICT_LAYOUT_TOML), "--markerset", str(ICT_MARKERSET_TOML),
                 "-o", str(tmp_path / "out.c3d")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1
    assert re.fullmatch(r"mocap2mesh synth: error: .*never\.csv: tracking was lost in every "
                        r"one of its 2 rows \(no weights\): nothing to play", err[0])
