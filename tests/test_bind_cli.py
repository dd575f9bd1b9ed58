"""``mocap2mesh synth`` and ``mocap2mesh bind``: simulated and real captures, error paths."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from helpers import FACIAL_SING_MARKERSET_TOML, bind_argv, rigid_shape_rms, synth_argv
from tolerances import (
    BIND_CLI_NEUTRAL_WEIGHT,
    BIND_CLI_SIM_MAX_MM,
    BIND_CLI_SIM_MEAN_MM,
    BIND_CLI_SKIN_OFFSET_MM,
    BIND_REAL_MEDIAN_MM,
    BIND_SCALE_REL,
    EXACT_MM,
    HOLD_NOISE_FACTOR,
    PERFORMANCE_CSV_WEIGHT,
    SYNTH_CLI_NOISE_STD_REL,
)

import mocap
from fit.cli.main import main
from mocap.bind import load_binding
from mocap.errors import MarkerError
from mocap.synth.capture import load_capture_truth

MM_PER_CM = 10.0
NEUTRAL_S = 3.0        # the simulated performance rests this long, then makes faces


def _performance_csv(path: Path) -> Path:
    """4 s at 30 Hz: rest for NEUTRAL_S, then jaw, blink, brows and smile (one frame dropped)."""
    t = np.delete(np.arange(121) / 30.0, 70)
    ramp = np.clip((t - NEUTRAL_S) / 0.3, 0, 1)
    rows = ["time,JawOpen,EyeBlinkLeft,BrowInnerUp,MouthSmileLeft,BlendShapeCount"]
    rows += [f"{ti:.6f},{0.8 * r:.6f},{r:.6f},{0.6 * r:.6f},{0.5 * r:.6f},61"
             for ti, r in zip(t, ramp)]
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


def _synth_args(ict_dir, performance, output, *extra):
    return synth_argv(ict_dir / "generic_neutral_mesh.obj", ict_dir / "expressions", performance,
                      output, *extra)


def _bind_args(ict_dir, capture, output, *extra, **files):
    return bind_argv(capture, ict_dir / "generic_neutral_mesh.obj", output, *extra, **files)


@pytest.fixture(scope="module", params=[".c3d", ".csv"])
def simulated_capture(request, ict_dir, tmp_path_factory):
    """A simulated capture (noise 0.2 mm, gaps, head motion) and its truth file."""
    folder = tmp_path_factory.mktemp("sim")
    capture, truth = folder / f"capture{request.param}", folder / "truth.npz"
    performance = _performance_csv(folder / "performance.csv")
    with pytest.warns(UserWarning, match=r"48 shapes of .*expressions have no weight column"):
        code = main(_synth_args(ict_dir, performance, capture, "--truth", str(truth), "--gaps",
                                "8", "--noise", "0.2", "--seed", "4", "--head-motion", "15,30"))
    assert code == 0
    return capture, truth


def test_synth_writes_the_capture_and_its_truth(simulated_capture, ict_markerset):
    capture, truth_path = simulated_capture
    take, truth = mocap.read(capture), load_capture_truth(truth_path)
    assert take.n_frames == truth.n_frames == 401 and take.rate == truth.rate == 100.0
    assert take.labels == truth.labels
    assert set(take.labels) == set(ict_markerset.markers)
    np.testing.assert_array_equal(take.missing, truth.missing)
    assert truth.missing.any()
    error = (take.positions - truth.markers_world)[~truth.missing]
    assert error.std() == pytest.approx(0.2, rel=SYNTH_CLI_NOISE_STD_REL)
    jaw = truth.shape_names.index("jawOpen")
    t = np.arange(truth.n_frames) / truth.rate
    np.testing.assert_allclose(truth.weights[:, jaw], 0.8 * np.clip((t - NEUTRAL_S) / 0.3, 0, 1),
                               atol=PERFORMANCE_CSV_WEIGHT)  # the CSV holds 6 decimals


@pytest.mark.parametrize("stabilize", [False, True])
def test_bind_recovers_the_layout_of_a_simulated_capture(simulated_capture, ict_dir, ict_mesh,
                                                         ict_layout, tmp_path, capsys, stabilize):
    capture, truth_path = simulated_capture
    output = tmp_path / "binding.json"
    extra = ["--skin-offset", "2", "-v"] + (["--stabilize"] if stabilize else [])
    assert main(_bind_args(ict_dir, capture, output, *extra)) == 0
    frame = int(re.search(r"^frame\s+(\d+)", capsys.readouterr().out, re.M).group(1))
    truth = load_capture_truth(truth_path)
    # at rest, or where the ramp is still below the noise (0.2 mm)
    assert truth.weights[frame].max() < BIND_CLI_NEUTRAL_WEIGHT and not truth.missing[frame].any()
    binding = load_binding(output)
    expected = ict_layout.positions(ict_mesh.vertices, offset=False)[[ict_layout.index(x)
                                                                      for x in binding.labels]]
    error = MM_PER_CM * np.linalg.norm(binding.marker_points(ict_mesh.vertices) - expected, axis=1)
    print(f"simulated {capture.suffix} stabilize={stabilize}: frame {frame}, bound points vs "
          f"layout mean {error.mean():.3f} mm, max {error.max():.3f} mm "
          f"({binding.labels[int(np.argmax(error))]}); scale x 10 = {binding.scale * 10:.4f}")
    assert error.mean() < BIND_CLI_SIM_MEAN_MM and error.max() < BIND_CLI_SIM_MAX_MM
    assert binding.scale * MM_PER_CM == pytest.approx(1, abs=BIND_SCALE_REL)
    assert np.abs(binding.distances - 2.0).max() < BIND_CLI_SKIN_OFFSET_MM
    doc = json.loads(output.read_text())
    assert len(doc["distances_mm"]) == len(doc["labels"]) == 66


def test_synth_neutral_lead_and_bind_hold(ict_dir, tmp_path, capsys):
    """A capture that starts with a neutral hold: `bind --frame hold` binds a frame in it."""
    capture, truth_path = tmp_path / "led.c3d", tmp_path / "led.npz"
    performance = _performance_csv(tmp_path / "performance.csv")
    with pytest.warns(UserWarning, match=r"48 shapes of .*expressions have no weight column"):
        assert main(_synth_args(ict_dir, performance, capture, "--truth", str(truth_path),
                                "--neutral-lead", "0.6", "--noise", "0.2")) == 0
    truth = load_capture_truth(truth_path)
    assert truth.n_frames == 401 + 60 and not truth.weights[:30].any()
    assert main(_bind_args(ict_dir, capture, tmp_path / "b.json", "--frame", "hold",
                           "--skin-offset", "2", "-v")) == 0
    frame = int(re.search(r"^frame\s+(\d+)", capsys.readouterr().out, re.M).group(1))
    assert frame < 30 and not truth.weights[frame].any()


def test_bind_facial_sing(facial_sing_path, facial_sing_markerset, ict_dir, tmp_path, capsys):
    capture = facial_sing_path
    output = tmp_path / "sing.json"
    with pytest.warns(UserWarning, match=r"markers are more than 3.0 mm off .*root-"):
        assert main(_bind_args(ict_dir, capture, output, "-v",
                               markerset=FACIAL_SING_MARKERSET_TOML)) == 0
    report = capsys.readouterr().out
    print(report)
    binding = load_binding(output)
    markerset = facial_sing_markerset
    assert binding.labels == markerset.markers                 # Unlabeled1 left out
    face = np.isin(binding.labels, markerset.face_markers)
    assert np.median(binding.distances[face]) < BIND_REAL_MEDIAN_MM
    assert binding.converged and binding.n_landmarks == len(markerset.landmarks)
    # a face of real size: ICT is in cm, so ~0.1 cm per capture mm
    assert 0.07 < binding.scale < 0.13
    for label, dist in zip(binding.labels, binding.distances):
        assert re.search(rf"^\s+{re.escape(label)}\s+{dist:.3f}$", report, re.M)


def test_bind_a_given_frame_without_icp(facial_sing_path, ict_dir, tmp_path):
    capture = facial_sing_path
    output = tmp_path / "sing0.json"
    with pytest.warns(UserWarning):
        assert main(_bind_args(ict_dir, capture, output, "--frame", "1", "--no-icp",
                               markerset=FACIAL_SING_MARKERSET_TOML)) == 0
    binding = load_binding(output)
    assert binding.n_iterations == 0 and "no ICP" in binding.message


# ---------------------------------------------------------------- error paths

def _fails(argv, capsys, *patterns):
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    for pattern in patterns:
        assert re.search(pattern, err), err


def test_synth_performance_naming_no_shape(ict_dir, tmp_path, capsys):
    perf = tmp_path / "strange.csv"
    perf.write_text("time,Foo,Bar\n0,0,0\n1,1,1\n", encoding="utf-8")
    _fails(_synth_args(ict_dir, perf, tmp_path / "x.c3d"), capsys,
           r"strange\.csv: none of its weight columns \(Foo, Bar\)")
    assert not (tmp_path / "x.c3d").exists()


def test_synth_layout_of_another_mesh(ict_dir, tmp_path, capsys):
    layout = tmp_path / "small.toml"
    layout.write_text('n_vertices = 100\n[markers]\na = { vertex = 1 }\n', encoding="utf-8")
    args = _synth_args(ict_dir, _performance_csv(tmp_path / "p.csv"), tmp_path / "x.c3d")
    args[args.index("--layout") + 1] = str(layout)
    _fails(args, capsys, r"small\.toml: written for a mesh of 100 vertices, but the mesh has "
                         r"9409")


def test_synth_rejects_an_output_it_cannot_write(ict_dir, tmp_path, capsys):
    _fails(_synth_args(ict_dir, _performance_csv(tmp_path / "p.csv"), tmp_path / "x.npz"), capsys,
           r"x\.npz: the capture must be \.c3d or \.csv")


def test_synth_bad_head_motion_is_a_usage_error(ict_dir, tmp_path, capsys):
    args = _synth_args(ict_dir, tmp_path / "p.csv", tmp_path / "x.c3d", "--head-motion", "15")
    assert main(args) == 2
    assert "expected DEG,MM" in capsys.readouterr().err


def test_bind_landmarks_of_another_mesh(simulated_capture, ict_dir, tmp_path, capsys):
    landmarks = tmp_path / "marks.toml"
    landmarks.write_text("n_vertices = 100\n[landmarks]\nnose_tip = 4\n", encoding="utf-8")
    _fails(_bind_args(ict_dir, simulated_capture[0], tmp_path / "b.json", landmarks=landmarks),
           capsys, r"marks\.toml: written for a mesh of 100 vertices, but the mesh has 9409")


def test_bind_missing_landmarks_file(simulated_capture, ict_dir, tmp_path, capsys):
    _fails(_bind_args(ict_dir, simulated_capture[0], tmp_path / "b.json",
                      landmarks=tmp_path / "no.toml"),
           capsys, r"no\.toml: cannot read mesh landmarks")
    assert not (tmp_path / "b.json").exists()


def test_bind_markerset_of_another_capture(simulated_capture, ict_dir, tmp_path, capsys):
    _fails(_bind_args(ict_dir, simulated_capture[0], tmp_path / "b.json",
                      markerset=FACIAL_SING_MARKERSET_TOML),
           capsys, r"marker 'root-1': marker set 'facial-sing' names it but .*capture\.")


def test_bind_frame_beyond_the_take(simulated_capture, ict_dir, tmp_path, capsys):
    """--frame is the capture's frame number (1..401 here): 402 and the old index 0 are refused."""
    for frame in ("402", "0"):
        _fails(_bind_args(ict_dir, simulated_capture[0], tmp_path / "b.json", "--frame", frame),
               capsys, rf"--frame {frame} is not a frame of the take: its frames are numbered "
                       r"1\.\.401 \(the capture's own numbers\)")


def test_bind_refuses_to_overwrite_its_input(simulated_capture, ict_dir, capsys):
    _fails(_bind_args(ict_dir, simulated_capture[0], simulated_capture[0]), capsys,
           r"refusing to overwrite an input file")


def test_synth_negative_neutral_lead(ict_dir, tmp_path, capsys):
    with pytest.warns(UserWarning, match="no weight column"):
        _fails(_synth_args(ict_dir, _performance_csv(tmp_path / "p.csv"), tmp_path / "x.c3d",
                           "--neutral-lead", "-1"), capsys,
               r"neutral_lead_s must be >= 0, got -1\.0")
    assert not (tmp_path / "x.c3d").exists()


def test_bind_hold_of_a_take_shorter_than_a_hold(ict_dir, tmp_path, capsys):
    """A 0.4 s take cannot hold the 0.5 s window a neutral hold is found with."""
    capture = tmp_path / "short.c3d"
    with pytest.warns(UserWarning, match="no weight column"):
        assert main(_synth_args(ict_dir, _performance_csv(tmp_path / "p.csv"), capture,
                                "--duration", "0.4")) == 0
    _fails(_bind_args(ict_dir, capture, tmp_path / "b.json", "--frame", "hold"), capsys,
           r"a neutral hold is 0\.5 s \(51 frames\); the take has only 41")
    assert not (tmp_path / "b.json").exists()


def test_bind_frame_that_is_no_option_is_a_usage_error(simulated_capture, ict_dir, tmp_path,
                                                       capsys):
    assert main(_bind_args(ict_dir, simulated_capture[0], tmp_path / "b.json", "--frame",
                           "still")) == 2
    assert "expected a frame number, 'auto' or 'hold', got 'still'" in capsys.readouterr().err


def test_bind_hold_binds_the_mean_pose_of_the_hold(ict_dir, ict_markerset, tmp_path):
    """`--frame hold` binds the hold window's mean shape, averaged in the head frame.

    Oracle: the simulation's noise-free markers at the window's centre, up to
    a rigid motion (a binding fits its own placement). The mean of the
    window's N frames has the noise of one frame divided by sqrt(N).
    """
    from mocap.neutral import find_neutral, hold_window
    from mocap.rigid import apply_transform
    from mocap.stabilize import stabilize

    capture, truth_path = tmp_path / "led.c3d", tmp_path / "led.npz"
    performance = _performance_csv(tmp_path / "performance.csv")
    noise = 0.2
    with pytest.warns(UserWarning, match=r"48 shapes of .*expressions have no weight column"):
        assert main(_synth_args(ict_dir, performance, capture, "--truth", str(truth_path),
                                "--neutral-lead", "1", "--noise", str(noise), "--gaps", "0",
                                "--head-motion", "15,30")) == 0
    truth = load_capture_truth(truth_path)
    markerset = ict_markerset
    take = mocap.read(capture).select(markerset.markers)
    head = stabilize(take, markerset.head)
    window = hold_window(take.rate)
    frame = window                                   # inside the 1 s hold, away from its ends
    exact = truth.markers_world[frame, [truth.labels.index(x) for x in take.labels]]
    expected = noise * np.sqrt(3 / window)
    in_head = find_neutral(head.take, frame, window=window).pose
    pose = apply_transform(head.rotation[frame], head.translation[frame], in_head)
    assert rigid_shape_rms(pose, exact) < HOLD_NOISE_FACTOR * expected \
        < 0.3 * rigid_shape_rms(take.positions[frame], exact)
    # carried to the capture frame by the centre frame's head pose
    np.testing.assert_allclose(head.to_head(np.broadcast_to(pose, take.positions.shape))[frame],
                               in_head, atol=EXACT_MM)
    # a marker missing in one frame of the window: named, with the window's frame
    positions = take.positions.copy()
    positions[frame + 3, take.labels.index("chin")] = np.nan
    holed = take.replace(positions=positions)
    with pytest.raises(MarkerError, match=rf"'chin'.*missing in the {window} frames around the "
                                          rf"neutral frame {take.first_frame + frame} "
                                          rf"\(index {frame}\) of .*led.c3d"):
        find_neutral(stabilize(holed, markerset.head).take, frame, window=window)


@pytest.mark.parametrize("frame", ["auto", 40])
def test_bind_take_reads_the_markers_where_the_take_has_them(simulated_capture, ict_markerset,
                                                             ict_mesh, ict_landmarks, frame):
    """A take whose markers come in another order, among markers of no set (wild, often
    missing), binds as the take of the set's markers in the set's order does."""
    from mocap.bind import bind_take
    from mocap.take import Take

    capture, _ = simulated_capture
    take = mocap.read(capture).select(ict_markerset.markers)
    rng = np.random.default_rng(2)
    order = rng.permutation(take.n_markers)
    strangers = rng.normal(0.0, 300.0, (take.n_frames, 4, 3))
    strangers[rng.random((take.n_frames, 4)) < 0.5] = np.nan
    foreign = Take(tuple(take.labels[i] for i in order) + ("x1", "x2", "x3", "x4"),
                   np.concatenate([take.positions[:, order], strangers], axis=1), take.rate,
                   first_frame=take.first_frame)
    bound = [bind_take(t, ict_markerset, ict_mesh, ict_landmarks, frame=frame,
                       skin_offset=2.0) for t in (take, foreign)]
    assert (bound[1].frame, bound[1].window) == (bound[0].frame, bound[0].window)
    ours, theirs = (b.binding for b in bound)
    assert ours.labels == theirs.labels == tuple(ict_markerset.markers)
    np.testing.assert_array_equal(theirs.face_ids, ours.face_ids)
    np.testing.assert_array_equal(theirs.barycentric, ours.barycentric)
    np.testing.assert_array_equal(theirs.rotation, ours.rotation)
    assert theirs.scale == ours.scale
