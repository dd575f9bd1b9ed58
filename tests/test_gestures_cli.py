"""``mocap2mesh gestures analyze`` and ``synthesize`` end to end: capture -> clip -> glb."""

from __future__ import annotations

import numpy as np
import pygltflib
import pytest
import scipy.io.wavfile
from helpers import (
    FACIAL_SING_MARKERSET_TOML,
    ICT_LAYOUT_TOML,
    ICT_MARKERSET_TOML,
    bind_argv,
    moving_average_oracle,
    read_gltf_accessor,
    rigid_shape_rms,
    synth_argv,
)
from scipy.spatial.transform import Rotation
from tolerances import (
    CLIP_BOUNDS_SLACK,
    FLOAT32_REL,
    GESTURES_CLI_HEAD_DEG,
    GESTURES_CLI_LID_CORRELATION,
    GESTURES_CLI_WEIGHTS,
    GLB_HEAD_MOTION_CM,
    HOLD_NOISE_FACTOR,
    SPEECH_CLI_TONE_DB,
)

from fit.cli.main import main
from fit.gestures import load_clip
from mocap.bind import load_binding
from mocap.mesh.mesh import load_mesh
from mocap.synth.capture import load_capture_truth

SHAPES = ("browInnerUp_L", "browInnerUp_R", "eyeBlink_L", "eyeBlink_R", "jawOpen",
          "mouthSmile_L")
RATE, AMPLITUDE, BURST_HZ = 30.0, 0.3, 0.5
#: Neutral frame (index at 30 Hz) of the simulated take: its smallest total weight.
NEUTRAL = 56


def _speech(path, seconds):
    """Tone bursts: 200 Hz of amplitude 0.3 during the first half of every 2 s."""
    t = np.arange(int(16000 * seconds)) / 16000
    on = (t * BURST_HZ) % 1.0 < 0.5
    scipy.io.wavfile.write(path, 16000, (AMPLITUDE * np.sin(2 * np.pi * 200 * t) * on)
                           .astype(np.float32))
    return path


@pytest.fixture(scope="module")
def bound_capture(ict_neutral_path, ict_expressions_dir, arkit_performance_path, tmp_path_factory):
    """A 6 s capture of the ICT face simulated with head motion, noise and gaps, bound."""
    folder = tmp_path_factory.mktemp("gestures-cli")
    shapes = folder / "shapes"
    shapes.mkdir()
    for name in SHAPES:
        (shapes / f"{name}.obj").symlink_to(ict_expressions_dir / f"{name}.obj")
    mesh = ict_neutral_path
    capture, truth, binding = folder / "cap.c3d", folder / "truth.npz", folder / "binding.json"
    with pytest.warns(UserWarning, match="match no shape"):
        assert main(synth_argv(mesh, shapes, arkit_performance_path, capture, "--truth",
                               str(truth), "--rate", "60", "--start", "20", "--duration", "6",
                               "--gaps", "3", "--noise", "0.1", "--head-motion", "10,20")) == 0
    assert main(bind_argv(capture, mesh, binding, "--stabilize")) == 0
    wav = _speech(folder / "speech.wav", 6.0)
    common = ["--markerset", str(ICT_MARKERSET_TOML), "--binding", str(binding),
              "--mesh", str(mesh), "--shapes", str(shapes), "--units", "cm"]
    return dict(folder=folder, capture=capture, truth=truth, binding=binding, wav=wav,
                mesh=mesh, shapes=shapes, common=common)


def test_analyze_recovers_the_simulated_weights_head_and_speech(bound_capture):
    out = bound_capture["folder"] / "take.npz"
    assert main(["gestures", "analyze", str(bound_capture["capture"]), *bound_capture["common"],
                 "--speech", str(bound_capture["wav"]), "--neutral-frame", str(NEUTRAL),
                 "-o", str(out)]) == 0
    clip, truth = load_clip(out), load_capture_truth(bound_capture["truth"])
    assert (clip.name, clip.rate, clip.names, clip.n_frames) == ("take", RATE, SHAPES, 181)
    assert set(clip.features()) == {"weights", "blinks", "brows", "head", "left_brow",
                                    "right_brow", "left_eye", "right_eye"}
    assert str(bound_capture["wav"]) in clip.intensity_source
    assert "Praat" in clip.intensity_source
    # weights: the 41-frame average of the truth (at 30 Hz) minus the neutral frame's
    at30 = truth.weights[::2][:, [truth.shape_names.index(n) for n in SHAPES]]
    want = np.clip(moving_average_oracle(at30, 41) - at30[NEUTRAL], -0.1, 1.1)
    lids = [SHAPES.index("eyeBlink_L"), SHAPES.index("eyeBlink_R")]
    rest = [i for i in range(len(SHAPES)) if i not in lids]
    np.testing.assert_allclose(clip.weights[:, rest], want[:, rest], atol=GESTURES_CLI_WEIGHTS)
    for i in lids:            # lid markers sit where a 0.3 mm binding error changes the motion
        assert np.corrcoef(clip.weights[:, i], want[:, i])[0, 1] > GESTURES_CLI_LID_CORRELATION
    # head: rotation angle between frames is frame-independent, so compare with the truth's
    turn = Rotation.from_rotvec(np.array(clip.head[:, :3]))
    true = Rotation.from_matrix(truth.rotation[::2])
    np.testing.assert_allclose(np.degrees((turn[0].inv() * turn).magnitude()),
                               np.degrees((true[0].inv() * true).magnitude()),
                               atol=GESTURES_CLI_HEAD_DEG)
    _bursts_are_read(clip)


def _bursts_are_read(clip):
    """S(t) of the tone bursts: a sine's level inside the bursts, silence between. A WAV is
    read by Praat, in dB SPL with the signal as pascals (re 20 µPa); an analog channel by
    the RMS level, dB re its unit."""
    phase = (np.arange(clip.n_frames) / RATE * BURST_HZ) % 1.0
    inside, silent = (phase > 0.05) & (phase < 0.45), (phase > 0.55) & (phase < 0.95)
    reference = 2e-5 if "Praat" in clip.intensity_source else 1.0
    np.testing.assert_allclose(clip.intensity[inside],
                               20 * np.log10(AMPLITUDE / np.sqrt(2) / reference),
                               atol=SPEECH_CLI_TONE_DB)
    assert np.all(clip.intensity[silent] == -100.0)


def test_analyze_reads_speech_from_the_c3d_analog_channel(bound_capture, tmp_path):
    """A microphone recorded as a C3D analog channel at 100 samples per frame."""
    import mocap
    from mocap.take import Analog

    take = mocap.read(bound_capture["capture"])
    rate = 100 * take.rate
    t = np.arange(take.n_frames * 100) / rate
    mic = AMPLITUDE * np.sin(2 * np.pi * 500 * t) * ((t * BURST_HZ) % 1.0 < 0.5)
    noise = np.random.default_rng(0).normal(0, 1, len(t))
    capture = tmp_path / "with-mic.c3d"
    mocap.write(take.replace(analog=Analog(np.column_stack([noise, mic]), rate,
                                           ("FORCE", "MIC"), ("N", "V"))), capture)
    out = tmp_path / "mic.npz"
    assert main(["gestures", "analyze", str(capture), *bound_capture["common"], "--analog", "MIC",
                 "-o", str(out)]) == 0
    clip = load_clip(out)
    assert "analog channel 'MIC'" in clip.intensity_source
    _bursts_are_read(clip)


def _synthesize_and_check_the_glb(clip, bound_capture, out, wav):
    """Synthesize onto the ICT face; the glb's node motion is R~, T~ carried by the binding."""
    out.mkdir()
    assert main(["gestures", "synthesize", str(wav), "--palette", str(clip), "-o", str(out),
                 "--mesh", str(bound_capture["mesh"]), "--shapes", str(bound_capture["shapes"]),
                 "--units", "cm", "--binding", str(bound_capture["binding"]), "--no-lips"]) == 0
    head = np.load(out / "head.npz")
    gltf = pygltflib.GLTF2().load(str(out / "gestures.glb"))
    (anim,) = gltf.animations
    samplers = {c.target.path: anim.samplers[c.sampler] for c in anim.channels}
    assert all(c.target.node == 0 for c in anim.channels) and gltf.nodes[0].mesh == 0
    quat = read_gltf_accessor(gltf, samplers["rotation"].output).astype(float)
    move = read_gltf_accessor(gltf, samplers["translation"].output).astype(float) / 0.01  # m->cm
    times = read_gltf_accessor(gltf, samplers["rotation"].input)[:, 0]
    # keyed on frame numbers from 1, as weights.csv
    np.testing.assert_allclose(times, (1 + np.arange(len(head["rotation"]))) / RATE,
                               rtol=FLOAT32_REL)
    binding = load_binding(bound_capture["binding"])
    points = binding.marker_points(load_mesh(bound_capture["mesh"], units="cm").vertices)
    played = Rotation.from_quat(quat[:, None]).apply(points[None]) + move[:, None]
    in_head = binding.to_capture(points)               # mm, head frame
    moved = np.einsum("tij,mj->tmi", head["rotation"], in_head) + head["translation"][:, None]
    want = binding.to_mesh(moved.reshape(-1, 3)).reshape(moved.shape)
    np.testing.assert_allclose(played, want,
                               atol=GLB_HEAD_MOTION_CM)          # cm, float32 in the file
    assert np.abs(want - points).max() > 0.5                      # the head does move


def test_synthesized_head_motion_plays_in_the_glb(bound_capture):
    clip = bound_capture["folder"] / "for-synthesis.npz"
    assert main(["gestures", "analyze", str(bound_capture["capture"]), *bound_capture["common"],
                 "--speech", str(bound_capture["wav"]), "-o", str(clip)]) == 0
    _synthesize_and_check_the_glb(clip, bound_capture, bound_capture["folder"] / "out",
                                  _speech(bound_capture["folder"] / "drive.wav", 8.0))


def test_facial_sing_analyze_states_its_stand_in_and_synthesizes(facial_sing_path, bound_capture,
                                                                 tmp_path):
    markerset = FACIAL_SING_MARKERSET_TOML
    capture = facial_sing_path
    mesh = bound_capture["mesh"]
    binding = tmp_path / "sing-binding.json"
    with pytest.warns(UserWarning, match="off the expected"):    # head markers off the face
        assert main(bind_argv(capture, mesh, binding, "--stabilize", markerset=markerset)) == 0
    clip = tmp_path / "sing.npz"
    with pytest.warns(UserWarning, match="stand-in .*lip opening section10-2-section13-2"):
        assert main(["gestures", "analyze", str(capture), "--markerset", str(markerset),
                     "--binding", str(binding), "--mesh", str(mesh), "--shapes",
                     str(bound_capture["shapes"]), "--units", "cm", "-o", str(clip)]) == 0
    back = load_clip(clip)
    assert back.n_frames == 900 and back.intensity_source.startswith("stand-in")
    assert np.nanmin(back.weights) >= -0.1 - CLIP_BOUNDS_SLACK \
        and np.nanmax(back.weights) <= 1.1 + CLIP_BOUNDS_SLACK
    assert set(back.details) == {"left_brow", "right_brow", "left_eye", "right_eye"}
    sing = dict(bound_capture, binding=binding)
    _synthesize_and_check_the_glb(clip, sing, tmp_path / "out", bound_capture["wav"])


@pytest.mark.parametrize("extra, code, match", [
    (["--speech", "s.wav", "--analog", "MIC"], 2, "not allowed with argument"),
    (["--opening", "only-one"], 2, "invalid _pair value"),
    (["-o", "{folder}/clip.csv"], 1, "a clip is written as .npz"),
    (["-o", "{capture}"], 1, "a clip is written as .npz"),
    (["--analog", "MIC"], 1, "the take has no analog channels"),
    (["--opening", "nose-tip,nope"], 1, "'nope'"),
    (["--neutral-frame", "5000"], 1, "neutral frame index 5000 is beyond the take's 181 frames"),
])
def test_analyze_errors(bound_capture, capsys, extra, code, match):
    extra = [x.format(**bound_capture) for x in extra]
    out = [] if "-o" in extra else ["-o", str(bound_capture["folder"] / "bad.npz")]
    assert main(["gestures", "analyze", str(bound_capture["capture"]), *bound_capture["common"],
                 *extra, *out]) == code
    assert match in capsys.readouterr().err
    assert not (bound_capture["folder"] / "bad.npz").exists()


def test_analyze_never_overwrites_an_input(bound_capture, capsys):
    take = bound_capture["folder"] / "take-input.npz"
    assert main(["ingest", str(bound_capture["capture"]), "-o", str(take)]) == 0
    before = take.read_bytes()
    assert main(["gestures", "analyze", str(take), *bound_capture["common"], "-o", str(take)]) == 1
    assert "refusing to overwrite an input file" in capsys.readouterr().err
    assert take.read_bytes() == before


def test_gestures_needs_an_action(capsys):
    assert main(["gestures"]) == 2
    assert "required: ACTION" in capsys.readouterr().err


def test_analyze_takes_the_neutral_from_a_hold(bound_capture, capsys):
    """``--neutral-frame hold`` (bind's parser takes it) picks a frame instead of failing."""
    out = bound_capture["folder"] / "hold.npz"
    assert main(["gestures", "analyze", str(bound_capture["capture"]), *bound_capture["common"],
                 "--speech", str(bound_capture["wav"]), "--neutral-frame", "hold",
                 "-o", str(out)]) == 0, capsys.readouterr().err
    assert load_clip(out).n_frames == 181


def test_clip_from_capture_keeps_every_ingest_option(bound_capture, ict_markerset, monkeypatch):
    """The caller's IngestOptions reach ingest whole; only the rate and stabilization are set."""
    import mocap
    from basis.artist import load_artist_basis
    from fit.gestures import reference
    from mocap.clean.ingest import IngestOptions

    seen = []

    def recording(take, *, markerset, options):
        seen.append(options)
        return ingest(take, markerset=markerset, options=options)

    ingest = reference.ingest
    monkeypatch.setattr(reference, "ingest", recording)
    given = IngestOptions(fix_swaps=True, reject_implausible=True, fill="spline", max_gap=40,
                          lowpass_hz=8.0)
    reference.clip_from_capture(
        mocap.read(bound_capture["capture"]), ict_markerset,
        load_binding(bound_capture["binding"]),
        load_artist_basis(bound_capture["mesh"], bound_capture["shapes"], units="cm"), name="x",
        wav=bound_capture["wav"], options=given, neutral_frame=NEUTRAL)
    assert seen == [IngestOptions(fix_swaps=True, reject_implausible=True, fill="spline",
                                  max_gap=40, lowpass_hz=8.0, resample_hz=RATE, stabilize=True)]


def test_synthesize_with_an_unreadable_binding_writes_nothing(bound_capture, tmp_path, capsys):
    """The binding is read with the other inputs: a bad one fails before any output."""
    clip = tmp_path / "clip.npz"
    assert main(["gestures", "analyze", str(bound_capture["capture"]), *bound_capture["common"],
                 "--speech", str(bound_capture["wav"]), "-o", str(clip)]) == 0
    bad, out = tmp_path / "binding.json", tmp_path / "out"
    bad.write_text("{not json", encoding="utf-8")
    out.mkdir()
    assert main(["gestures", "synthesize", str(bound_capture["wav"]), "--palette", str(clip),
                 "-o", str(out), "--mesh", str(bound_capture["mesh"]), "--shapes",
                 str(bound_capture["shapes"]), "--units", "cm", "--binding", str(bad)]) == 1
    err = capsys.readouterr().err
    assert "binding.json" in err and err.count("\n") == 1, err
    assert list(out.iterdir()) == []


def test_clip_from_capture_takes_n_as_the_mean_of_the_hold(bound_capture, ict_markerset,
                                                           arkit_performance):
    """``neutral_frame="hold"``: N is the hold window's mean pose, with 1/sqrt(window) the noise.

    Oracle: the simulation's noise-free head-frame markers during the hold,
    up to the rigid motion between the two head frames.
    """
    from basis.artist import load_artist_basis
    from fit.gestures.reference import clip_from_capture
    from mocap.mesh.layout import load_marker_layout
    from mocap.neutral import hold_window
    from mocap.synth.capture import simulate_capture

    basis = load_artist_basis(bound_capture["mesh"], bound_capture["shapes"], units="cm")
    markerset = ict_markerset
    noise, rate = 0.2, 30.0
    with pytest.warns(UserWarning, match="match no shape"):
        sim = simulate_capture(basis, arkit_performance,
                               load_marker_layout(ICT_LAYOUT_TOML, basis.neutral),
                               markerset.head, rate=rate, start=20.0, duration=2.0,
                               noise_mm=noise, n_gaps=0, neutral_lead_s=1.5, seed=3,
                               head_rotation_deg=10.0, head_translation_mm=20.0)
    with pytest.warns(UserWarning, match="stand-in"):
        made = clip_from_capture(sim.take, markerset, load_binding(bound_capture["binding"]),
                                 basis, name="held", rate=rate, neutral_frame="hold")
    window = hold_window(rate)
    assert window // 2 <= made.neutral_frame < 45 - window // 2      # inside the 1.5 s hold
    neutral = made.analysis.neutral
    exact = sim.truth.markers_head[made.neutral_frame,
                                   [sim.truth.labels.index(x) for x in made.analysis.labels]]
    shape_rms = rigid_shape_rms(neutral, exact)
    assert shape_rms < HOLD_NOISE_FACTOR * noise * np.sqrt(3 / window) \
        < 0.5 * noise * np.sqrt(3), shape_rms
