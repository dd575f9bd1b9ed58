"""Facial gestures: decomposition of takes, the MRF synthesis, timelines and the CLI."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.io.wavfile
import scipy.stats
from helpers import moving_average_oracle
from scipy.interpolate import BSpline
from scipy.spatial.distance import cdist
from scipy.spatial.transform import Rotation
from tolerances import (
    CHI_SQUARE_PVALUE,
    EXACT_FLOAT64,
    EXACT_MM,
    FLOAT32_FACE_CM,
    FLOAT32_REL,
    GESTURES_AT_BOUND,
    GESTURES_CLI_VS_API,
    GESTURES_NOISE_FREE,
    LOOP_ORACLE,
    MESH_EXACT,
)

from fit.cli.main import main
from fit.gestures import (
    ESTIMATORS,
    FEATURES,
    GestureClip,
    analyze_gestures,
    candidate_distances,
    clip_from_analysis,
    load_clip,
    parse_timeline,
    pick_candidate,
    save_clip,
    synthesize_gestures,
    wav_intensity,
    weight_columns,
)
from fit.gestures.transfer import SUPPORT_SPACINGS, build_detail_transfer
from fit.solve.marker_basis import marker_basis
from mocap.bind import Binding
from mocap.errors import FileFormatError, InputError, MarkerError
from mocap.mesh.mesh import Mesh
from mocap.stabilize import stabilize
from mocap.take import Take

REGIONS = {"upper_lip": ["UL1", "UL2"], "lower_lip": ["LL1", "LL2"],
           "left_brow": ["LB1", "LB2"], "right_brow": ["RB1", "RB2"],
           "left_eye": ["LE1"], "right_eye": ["RE1"], "other": ["C1", "C2"]}
FACE = [x for members in REGIONS.values() for x in members]
HEAD = ["H1", "H2", "H3", "H4"]
N_FRAMES, N_SHAPES, RATE = 120, 4, 30.0


def _smooth(rng, n, d, lo=0.0, hi=1.0):
    """Smooth random curves (n, d) in [lo, hi]."""
    t = np.arange(n)[:, None]
    phase, freq = rng.uniform(0, 6, (1, d)), rng.uniform(0.02, 0.08, (1, d))
    return lo + (hi - lo) * 0.5 * (1 + np.sin(freq * t + phase))


@pytest.fixture(scope="module")
def capture():
    """A rigidly moving head with face markers = N + Σ c B (+ detail motion), and the truth."""
    rng = np.random.default_rng(7)
    head = np.array([[0.0, 0, 0], [120, 0, 0], [0, 100, 0], [0, 0, 90]])
    neutral = rng.uniform(-60, 60, (len(FACE), 3))
    basis = rng.normal(0, 8, (N_SHAPES, len(FACE), 3))
    c = _smooth(rng, N_FRAMES, N_SHAPES, 0.05, 0.95)
    face = neutral + np.tensordot(c, basis, axes=1)
    rot = Rotation.from_rotvec(rng.normal(0, 0.1, (N_FRAMES, 3)))
    rot = Rotation.concatenate([Rotation.identity(), rot[1:]]).as_matrix()
    trans = rng.normal(0, 20, (N_FRAMES, 3))
    trans[0] = 0
    local = np.concatenate([np.broadcast_to(head, (N_FRAMES, 4, 3)), face], axis=1)
    world = np.einsum("tij,tmj->tmi", rot, local) + trans[:, None]
    take = Take(tuple(HEAD + FACE), world, rate=RATE)
    stab = stabilize(take, HEAD, reference="frame", reference_frame=0, robust=False)
    return stab, neutral, basis, c, face


@pytest.mark.parametrize("window", [1, 5, 41])
def test_exact_analysis_recovers_the_averaged_weights(capture, window):
    stab, neutral, basis, c, _ = capture
    result = analyze_gestures(stab, neutral, basis, REGIONS, labels=FACE, window=window)
    np.testing.assert_allclose(result.weights, moving_average_oracle(c, window),
                               atol=GESTURES_NOISE_FREE)
    np.testing.assert_allclose(result.rotation, stab.rotation)
    if window == 1:
        np.testing.assert_allclose(result.residual(), 0.0, atol=GESTURES_NOISE_FREE)


@pytest.mark.parametrize("estimator", ESTIMATORS)
def test_weights_respect_the_bounds(capture, estimator):
    stab, neutral, basis, _, _ = capture
    eps = 0.05
    result = analyze_gestures(stab, neutral, 0.4 * basis, REGIONS, labels=FACE, epsilon=eps,
                              estimator=estimator, window=1, n_samples=300, n_neighbors=20)
    assert np.all(result.weights >= -eps - EXACT_FLOAT64) \
        and np.all(result.weights <= 1 + eps + EXACT_FLOAT64)
    assert np.any(result.weights >= 1 + eps - GESTURES_AT_BOUND) == (estimator == "exact")


def test_groups_are_disjoint_and_sum_to_the_stabilized_markers(capture):
    stab, neutral, basis, _, _ = capture
    moved = stab.take.positions.copy()
    moved[:, stab.take.indices(["LB1", "RE1"])] += np.random.default_rng(1).normal(
        0, 2, (N_FRAMES, 2, 3))
    result = analyze_gestures(_restabilized(stab, moved), neutral, basis, REGIONS, labels=FACE)
    members = [set(v) for v in result.groups.values()]
    assert sum(map(len, members)) == len(set().union(*members)) == len(FACE)
    assert set(result.groups) == {"lips", "rest", "left_brow", "right_brow", "left_eye",
                                  "right_eye"}
    assert result.groups["lips"] == ("UL1", "UL2", "LL1", "LL2")
    total = neutral + result.blend() + result.residual()
    np.testing.assert_allclose(total, moved[:, len(HEAD):], atol=EXACT_MM)
    assert np.abs(result.details["left_brow"]).max() > 1.0


def _restabilized(stab, moved):
    return dataclasses.replace(stab, take=stab.take.replace(positions=moved))


def test_overlapping_groups_are_rejected(capture):
    stab, neutral, basis, _, _ = capture
    regions = dict(REGIONS, left_eye=["LE1", "LB1"])
    with pytest.raises(MarkerError, match="'LB1'.*both 'left_brow' and 'left_eye'"):
        analyze_gestures(stab, neutral, basis, regions, labels=FACE)


def test_group_marker_outside_the_basis_is_rejected(capture):
    stab, neutral, basis, _, _ = capture
    with pytest.raises(MarkerError, match="'XX'.*not among the markers of the basis"):
        analyze_gestures(stab, neutral, basis, dict(REGIONS, right_eye=["XX"]), labels=FACE)


# --- the Markov random field ----------------------------------------------------------


def _clip(name, n=300, d=3, seed=0, with_head=False):
    rng = np.random.default_rng(seed)
    s = np.cumsum(rng.normal(0, 1, n))
    head = rng.normal(0, 1, (n, 6)).cumsum(axis=0) * 0.01 if with_head else None
    return GestureClip(name, RATE, s, _smooth(rng, n, d) + rng.normal(0, 0.02, (n, d)),
                       tuple(f"s{i}" for i in range(d)), head=head)


def test_candidate_distances_match_a_brute_force_loop():
    rng = np.random.default_rng(2)
    h, d, n = 6, 3, 80
    s_ref, f_ref = rng.normal(size=n), rng.normal(size=(n, d))
    s_hist, f_hist = rng.normal(size=h), rng.normal(size=(h, d))
    f_ref[40] = np.nan
    alpha = 0.7
    got = candidate_distances(s_hist, f_hist, s_ref, f_ref, alpha=alpha)
    want = np.full(n, np.inf)
    for t in range(h, n):
        if np.isnan(f_ref[t - h:t + 1]).any():
            continue
        speech = sum((s_hist[h - 1 - j] - s_ref[t - j]) ** 2 for j in range(h))
        feature = sum(np.sum((f_hist[h - j] - f_ref[t - j]) ** 2) for j in range(1, h + 1))
        want[t] = alpha * speech + feature
    np.testing.assert_allclose(got, want, rtol=LOOP_ORACLE, atol=LOOP_ORACLE)


@pytest.mark.parametrize("run", [1, 4])
def test_own_intensity_with_sigma_zero_reproduces_the_reference(run):
    clip = _clip("ref")
    syn = synthesize_gestures(clip.intensity, [clip], rate=RATE, history=30, sigma=0.0, run=run)
    np.testing.assert_array_equal(syn.sources["weights"][:, 1], np.arange(clip.n_frames))
    np.testing.assert_array_equal(syn.weights, clip.weights)
    assert syn.transitions["weights"] == 0


def _chain_oracle(drive, clip, h, time_warps):
    """Sources of the nearest-candidate chain (sigma = 0, run 1), one frame at a time by loops."""
    def z(x):
        return (x - x.mean()) / x.std()
    s_out, s_ref = z(drive), z(clip.intensity)
    c = clip.weights / np.sqrt(clip.weights.var(axis=0).sum())
    n = len(s_ref)
    start = [sum((s_out[j] - s_ref[u + j]) ** 2 for j in range(h)) for u in range(n - h + 1)]
    src = list(range(int(np.argmin(start)), int(np.argmin(start)) + h))
    for t in range(h, len(drive)):
        dist = np.full(n + 1, np.inf)
        for u in range(h, n):
            dist[u] = (sum((s_out[t - j] - s_ref[u - j]) ** 2 for j in range(h))
                       + sum(np.sum((c[src[t - j]] - c[u - j]) ** 2) for j in range(1, h + 1)))
        pool = [u for u in range(h, n) if dist[u] <= dist[u - 1] and dist[u] <= dist[u + 1]]
        nxt = src[-1] + 1
        if not time_warps:
            pool = [u for u in pool if abs(u - nxt) >= h] + ([nxt] if nxt < n else [])
        src.append(min(pool, key=lambda u: dist[u]))
    return np.array(src)


@pytest.mark.parametrize("time_warps", [True, False])
def test_nearest_candidate_chain_matches_a_loop_oracle(time_warps):
    clip = _clip("ref", n=90, seed=4)
    drive = np.random.default_rng(8).normal(size=70).cumsum()
    syn = synthesize_gestures(drive, [clip], rate=RATE, history=5, sigma=0.0, blend=0,
                              time_warps=time_warps)
    want = _chain_oracle(drive, clip, 5, time_warps)
    np.testing.assert_array_equal(syn.sources["weights"][:, 1], want)
    np.testing.assert_array_equal(syn.weights, clip.weights[want])
    step = np.diff(want) - 1
    assert syn.warps["weights"] == np.count_nonzero((step != 0) & (np.abs(step) < 5))
    assert syn.transitions["weights"] == np.count_nonzero(step)


def test_a_held_drive_stalls_a_smooth_reference_unless_time_warps_are_off():
    rng = np.random.default_rng(3)
    n = 400
    clip = GestureClip("smooth", RATE, np.cumsum(rng.normal(0, 1, n)), _smooth(rng, n, 3),
                       ("s0", "s1", "s2"))
    drive = np.repeat(rng.normal(size=12), 25)          # loudness held for 25 frames at a time
    warped = synthesize_gestures(drive, [clip], rate=RATE, seed=1)
    kept = synthesize_gestures(drive, [clip], rate=RATE, seed=1, time_warps=False)
    src = warped.sources["weights"][:, 1]
    stalls = np.count_nonzero(src[1:] == src[:-1])
    assert stalls > len(drive) // 3 and warped.warps["weights"] >= stalls
    step = np.diff(kept.sources["weights"][:, 1]) - 1
    assert kept.warps["weights"] == 0 and np.all((step == 0) | (np.abs(step) >= 10))


def test_time_warps_must_be_a_bool():
    clip = _clip("ref")
    with pytest.raises(InputError, match="time_warps must be True or False"):
        synthesize_gestures(clip.intensity, [clip], rate=RATE, time_warps="no")


def test_synthesis_is_deterministic_for_a_seed():
    clips = [_clip("a", seed=1, with_head=True), _clip("b", seed=2, with_head=True)]
    drive = np.random.default_rng(5).normal(size=200).cumsum()
    one = synthesize_gestures(drive, clips, rate=RATE, seed=11)
    two = synthesize_gestures(drive, clips, rate=RATE, seed=11)
    other = synthesize_gestures(drive, clips, rate=RATE, seed=12, sigma=10.0)
    for feature in ("weights", "head"):
        np.testing.assert_array_equal(one.sources[feature], two.sources[feature])
    np.testing.assert_array_equal(one.head_rotation, two.head_rotation)
    assert not np.array_equal(one.sources["weights"], other.sources["weights"])
    np.testing.assert_allclose(np.einsum("tij,tkj->tik", one.head_rotation, one.head_rotation),
                               np.broadcast_to(np.eye(3), (200, 3, 3)), atol=EXACT_FLOAT64)


def test_choice_among_the_best_k_follows_exp_minus_dist_over_sigma():
    dist = np.full(50, 10.0)
    minima = {5: 0.0, 15: 0.05, 25: 0.1, 35: 0.3, 45: 0.5}
    for i, v in minima.items():
        dist[i] = v
    sigma, draws = 0.05, 6000
    rng = np.random.default_rng(0)
    picks = np.array([pick_candidate(dist, n_candidates=3, sigma=sigma, rng=rng)
                      for _ in range(draws)])
    assert set(np.unique(picks)) <= {5, 15, 25}
    counts = np.array([(picks == i).sum() for i in (5, 15, 25)])
    p = np.exp(-np.array([0.0, 0.05, 0.1]) / sigma)
    assert scipy.stats.chisquare(counts, draws * p / p.sum()).pvalue > CHI_SQUARE_PVALUE
    assert pick_candidate(dist, n_candidates=3, sigma=0.0) == 5


def test_timeline_assigns_clips_per_feature_and_segment():
    clips = [_clip("calm", seed=1, with_head=True), _clip("lively", seed=2, with_head=True)]
    timeline = parse_timeline({"default": "calm", "segment": [
        {"start": 2.0, "end": 4.0, "style": "lively", "head": "calm"}]})
    syn = synthesize_gestures(np.random.default_rng(3).normal(size=180), clips, rate=RATE,
                              timeline=timeline, run=3)
    w, head = syn.sources["weights"][:, 0], syn.sources["head"][:, 0]
    assert np.all(w[60:120] == 1) and np.all(w[10:60] == 0) and np.all(w[120:] == 0)
    assert np.all(head == 0)


def test_clip_roundtrip(tmp_path, capture):
    stab, neutral, basis, _, _ = capture
    clip = clip_from_analysis(analyze_gestures(stab, neutral, basis, REGIONS, labels=FACE),
                              np.linspace(-30, -10, N_FRAMES), name="take1")
    save_clip(tmp_path / "c.npz", clip)
    back = load_clip(tmp_path / "c.npz")
    assert back.name == "take1" and back.detail_labels == clip.detail_labels
    for key, value in clip.features().items():
        np.testing.assert_array_equal(back.features()[key], value)
    # head-frame motion about the mean pose: R_mean (exp(r) x + tau) + T_mean = R x + T
    mean_rot = Rotation.from_matrix(stab.rotation).mean().as_matrix()
    turn = Rotation.from_rotvec(np.array(clip.head[:, :3])).as_matrix()
    moved = np.einsum("tij,mj->tmi", turn, neutral) + clip.head[:, None, 3:]
    world = np.einsum("ij,tmj->tmi", mean_rot, moved) + stab.translation.mean(axis=0)
    want = np.einsum("tij,mj->tmi", stab.rotation, neutral) + stab.translation[:, None]
    np.testing.assert_allclose(world, want, atol=EXACT_MM)


@pytest.mark.parametrize("doc, match", [
    ({"segments": []}, r"unknown keys \['segments'\]"),
    ({"segment": [{"end": 1.0, "style": "a"}]}, "segment 1 has no 'start' time"),
    ({"segment": [{"start": 2.0, "end": 1.0, "style": "a"}]}, "ends at 1 s, not after"),
    ({"segment": [{"start": -1, "end": 1.0, "style": "a"}]}, "start must be a time"),
    ({"segment": [{"start": 0, "end": 1.0}]}, "names no style"),
    ({"segment": [{"start": 0, "end": 1.0, "nose": "a"}]}, r"unknown keys \['nose'\]"),
    ({"segment": [{"start": 0, "end": 1.0, "head": 3}]}, "head must be a clip name"),
    ({"segment": [{"start": 0, "end": 2.0, "style": "a"}, {"start": 1, "end": 3,
                                                           "style": "b"}]}, "overlap"),
    ({"default": ""}, "default must be a clip name"),
])
def test_timeline_errors(doc, match):
    with pytest.raises(FileFormatError, match=match):
        parse_timeline(doc)


def test_unknown_timeline_style_is_rejected():
    with pytest.raises(InputError, match=r"styles \['nope'\] are not clips"):
        synthesize_gestures(np.zeros(50), [_clip("a")], rate=RATE,
                            timeline=parse_timeline({"default": "nope"}))


def test_palette_at_another_rate_is_rejected():
    with pytest.raises(InputError, match="resample the clip first"):
        synthesize_gestures(np.zeros(50), [_clip("a")], rate=60.0)


ARKIT = ("BrowDownLeft", "EyeBlinkLeft", "JawOpen", "BrowInnerUp", "EyeBlinkRight")
ICT = ("browDown_L", "eyeBlink_L", "jawOpen", "eyeBlink_R", "browInnerUp_R")


@pytest.mark.parametrize("names", [ARKIT, ICT])
def test_blink_and_brow_shapes_are_their_own_features_by_name(names):
    cols = weight_columns(names)
    assert {f: [names[i] for i in c] for f, c in cols.items()} == {
        "weights": [n for n in names if n.lower().startswith("jaw")],
        "blinks": [n for n in names if "blink" in n.lower()],
        "brows": [n for n in names if n.lower().startswith("brow")]}
    assert list(weight_columns(names, {})) == ["weights"]
    assert set(FEATURES) >= set(cols) and FEATURES.index("head") > FEATURES.index("brows")


@pytest.mark.parametrize("groups, match", [
    ({"nose": ["JawOpen"]}, "unknown weight feature 'nose'"),
    ({"blinks": ["EyeWide"]}, "no shape 'EyeWide'"),
    ({"blinks": ["JawOpen"], "brows": ["JawOpen"]}, "'JawOpen' is in both 'blinks' and 'brows'"),
])
def test_weight_group_errors(groups, match):
    with pytest.raises(InputError, match=match):
        weight_columns(ARKIT, groups)


def _face_clip(name="face", n=400, seed=0):
    """A clip with expression, blink and brow columns of distinct curves."""
    rng = np.random.default_rng(seed)
    weights = _smooth(rng, n, len(ARKIT)) + rng.normal(0, 0.02, (n, len(ARKIT)))
    return GestureClip(name, RATE, np.cumsum(rng.normal(0, 1, n)), weights, ARKIT)


def test_blinks_and_brows_follow_their_own_chains():
    clip = _face_clip()
    drive = np.random.default_rng(4).normal(size=300).cumsum()
    syn = synthesize_gestures(drive, [clip], rate=RATE, sigma=1.0, blend=0, seed=3)
    assert set(syn.sources) == {"weights", "blinks", "brows"}
    assert not np.array_equal(syn.sources["blinks"], syn.sources["weights"])
    for feature, cols in weight_columns(ARKIT).items():   # each column copies its own source
        np.testing.assert_array_equal(syn.weights[:, cols],
                                      clip.weights[syn.sources[feature][:, 1]][:, cols])
    one = synthesize_gestures(drive, [clip], rate=RATE, sigma=1.0, blend=0, seed=3,
                              weight_groups={})
    assert set(one.sources) == {"weights"}
    np.testing.assert_array_equal(one.weights, clip.weights[one.sources["weights"][:, 1]])


def test_each_feature_draws_from_its_own_stream():
    clip = _face_clip()
    drive = np.random.default_rng(6).normal(size=200).cumsum()
    every = synthesize_gestures(drive, [clip], rate=RATE, sigma=1.0, seed=9)
    alone = synthesize_gestures(drive, [clip], rate=RATE, sigma=1.0, seed=9,
                                features=["blinks"])
    np.testing.assert_array_equal(alone.sources["blinks"], every.sources["blinks"])
    cols = weight_columns(ARKIT)
    assert np.all(alone.weights[:, cols["weights"]] == 0)


@pytest.mark.parametrize("blend", [1, 4])
def test_a_jump_fades_from_the_old_continuation_over_blend_frames(blend):
    clip = _face_clip()
    drive = np.random.default_rng(7).normal(size=200).cumsum()
    raw = synthesize_gestures(drive, [clip], rate=RATE, sigma=1.0, seed=2, blend=0)
    syn = synthesize_gestures(drive, [clip], rate=RATE, sigma=1.0, seed=2, blend=blend)
    src = syn.sources["weights"][:, 1]
    np.testing.assert_array_equal(src, raw.sources["weights"][:, 1])
    cols = weight_columns(ARKIT)["weights"]
    want = raw.weights[:, cols].copy()
    ref = clip.weights[:, cols]
    for t in np.flatnonzero(src[1:] != src[:-1] + 1) + 1:      # loop oracle, jump by jump
        offset = ref[min(src[t - 1] + 1, len(ref) - 1)] - ref[src[t]]
        for j in range(blend):
            if t + j < len(want):
                want[t + j] += (1 - j / blend) * offset
    want = np.clip(want, ref.min(axis=0), ref.max(axis=0))
    np.testing.assert_allclose(syn.weights[:, cols], want, atol=EXACT_FLOAT64)


def test_timeline_paints_blinks_apart_from_the_weights():
    clips = [_face_clip("calm", seed=1), _face_clip("lively", seed=2)]
    timeline = parse_timeline({"default": "calm", "segment": [
        {"start": 0.0, "end": 5.0, "blinks": "lively"}]})
    syn = synthesize_gestures(np.random.default_rng(3).normal(size=150), clips, rate=RATE,
                              timeline=timeline, run=3)
    assert np.all(syn.sources["blinks"][:, 0] == 1)
    assert np.all(syn.sources["weights"][:, 0] == 0) and np.all(syn.sources["brows"][:, 0] == 0)


# --- the command line -----------------------------------------------------------------


@pytest.fixture()
def cli_files(tmp_path):
    wav = tmp_path / "speech.wav"
    t = np.arange(16000 * 4) / 16000
    scipy.io.wavfile.write(wav, 16000, (0.3 * np.sin(2 * np.pi * 200 * t)
                                        * (np.sin(2 * np.pi * 0.7 * t) > 0)).astype(np.float32))
    clip = tmp_path / "calm.npz"
    save_clip(clip, _clip("calm", with_head=True))
    out = tmp_path / "out"
    out.mkdir()
    return wav, clip, out


@pytest.mark.parametrize("flags", [[], ["--no-time-warps", "--intensity", "rms"]])
def test_cli_writes_weights_and_head_motion(cli_files, flags):
    """S(t) is Praat's intensity by default, the RMS level on request."""
    from fit.gestures.prosody import speech_prosody

    wav, clip, out = cli_files
    assert main(["gestures", "synthesize", str(wav), "--palette", str(clip), "-o",
                 str(out), "--no-lips", *flags]) == 0
    import pandas as pd
    table = pd.read_csv(out / "weights.csv")
    assert len(table) == 120 and list(table.columns[2:]) == ["s0", "s1", "s2"]
    drive = wav_intensity(wav, frame_rate=RATE) if flags else \
        speech_prosody(wav, frame_rate=RATE, method="praat").intensity
    want = synthesize_gestures(drive, [load_clip(clip)], rate=RATE, time_warps=not flags)
    np.testing.assert_allclose(table.to_numpy()[:, 2:], want.weights, atol=GESTURES_CLI_VS_API)
    head = np.load(out / "head.npz")
    assert head["rotation"].shape == (120, 3, 3)



def test_cli_one_chain_keeps_blinks_and_brows_in_the_weights_chain(cli_files):
    """``--one-chain`` is ``weight_groups={}``; without it the blink and brow shapes (by name)
    follow chains of their own, which choose other frames."""
    import pandas as pd
    wav, _, out = cli_files
    clip = dataclasses.replace(_clip("calm", seed=4),
                               names=("jawOpen", "eyeBlink_L", "browInnerUp_L"))
    path = out.parent / "named.npz"
    save_clip(path, clip)
    got = {}
    for flags in ([], ["--one-chain"]):
        folder = out / ("one" if flags else "own")
        folder.mkdir()
        assert main(["gestures", "synthesize", str(wav), "--palette", str(path), "-o",
                     str(folder), "--no-lips", "--intensity", "rms", *flags]) == 0
        got[bool(flags)] = pd.read_csv(folder / "weights.csv").to_numpy()[:, 2:]
    intensity = wav_intensity(wav, frame_rate=RATE)
    for one_chain, groups in ((True, {}), (False, None)):
        want = synthesize_gestures(intensity, [load_clip(path)], rate=RATE,
                                   weight_groups=groups)
        assert set(want.sources) == ({"weights"} if one_chain
                                     else {"weights", "blinks", "brows"})
        np.testing.assert_allclose(got[one_chain], want.weights, atol=GESTURES_CLI_VS_API)
    assert np.abs(got[True] - got[False]).max() > 0.01

@pytest.mark.parametrize("args, match", [
    (["--palette", "{clip}", "-o", "{out}/missing"], "output directory does not exist"),
    (["--palette", "{wav}", "-o", "{out}"], "a palette clip is a .npz clip"),
    (["--palette", "{clip}", "-o", "{out}", "--mesh", "{clip}"], "--mesh and --shapes go"),
    (["--palette", "{clip}", "-o", "{out}", "--timeline", "{out}/none.toml"],
     "cannot read timeline"),
])
def test_cli_error_paths_exit_1(cli_files, capsys, args, match):
    wav, clip, out = cli_files
    args = [a.format(clip=clip, out=out, wav=wav) for a in args]
    assert main(["gestures", "synthesize", str(wav), *args]) == 1
    assert match in capsys.readouterr().err


def test_cli_missing_speech_exits_1(cli_files, capsys):
    wav, clip, out = cli_files
    assert main(["gestures", "synthesize", str(out / "none.wav"), "--palette", str(clip),
                 "-o", str(out)]) == 1
    assert "no such file" in capsys.readouterr().err


# --- detail transfer: compact B-spline RBFs onto a mesh --------------------------------

_CUBIC = BSpline.basis_element([-2.0, -1.0, 0.0, 1.0, 2.0], extrapolate=False)


def _bell(r):
    """Oracle kernel: scipy's cubic B-spline basis element at 2r, scaled to 1 at 0."""
    return np.nan_to_num(1.5 * _CUBIC(2.0 * np.asarray(r)))


def _grid_mesh(n=31, step=0.2):
    """A flat n × n vertex grid in the z = 0 plane (cm), two triangles per cell."""
    x, y = np.meshgrid(np.arange(n) * step, np.arange(n) * step, indexing="ij")
    vertices = np.column_stack([x.ravel(), y.ravel(), np.zeros(n * n)])
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    faces = np.concatenate([np.column_stack([a, a + n, a + 1]),
                            np.column_stack([a + 1, a + n, a + n + 1])])
    return Mesh(vertices, faces)


def _binding(mesh, face_ids, bary, scale=0.1, seed=0):
    m = len(face_ids)
    rot = Rotation.random(random_state=seed).as_matrix()
    return Binding(labels=tuple(f"m{i}" for i in range(m)), scale=scale, rotation=rot,
                   translation=np.zeros(3), face_ids=np.asarray(face_ids),
                   vertex_ids=mesh.faces[face_ids], barycentric=np.asarray(bary, float),
                   distances=np.zeros(m), rms=0.0, skin_offset=0.0, n_landmarks=0,
                   n_iterations=0, converged=True, message="test")


def _detail_setup(cluster_gap=False):
    """Five markers (two groups) on a grid mesh; with `cluster_gap`, m0-m1 far from m2-m4."""
    mesh = _grid_mesh()
    rng = np.random.default_rng(4)
    cells = [(3, 4), (6, 5), (22, 24), (25, 21), (24, 26)] if cluster_gap else \
        [(10, 10), (13, 12), (11, 15), (16, 14), (14, 17)]
    face_ids = [i * 30 + j for i, j in cells]
    bary = rng.dirichlet(np.ones(3), len(face_ids))
    groups = {"left_brow": ("m0", "m1"), "left_eye": ("m2", "m3", "m4")}
    return mesh, _binding(mesh, face_ids, bary), groups


def _mesh_motion(transfer, details):
    """Vertex displacements (T, N, 3) of the details through the transfer's shapes."""
    fields, _ = transfer.shapes()
    return np.tensordot(transfer.weights(details), fields, axes=1)


def test_detail_transfer_matches_a_dense_bspline_interpolant():
    mesh, binding, groups = _detail_setup()
    transfer = build_detail_transfer(binding, mesh, groups, support=1.2)
    centers = binding.marker_points(mesh.vertices)
    z = np.linalg.solve(_bell(cdist(centers, centers) / 1.2), np.eye(5))
    w = _bell(cdist(mesh.vertices, centers) / 1.2) @ z           # (N, 5) per coordinate
    details = {"left_brow": np.random.default_rng(1).normal(0, 2, (3, 2, 3)),
               "left_eye": np.random.default_rng(2).normal(0, 2, (3, 3, 3))}
    marker_mm = np.concatenate([details["left_brow"], details["left_eye"]], axis=1)
    want = np.einsum("vm,tma->tva", w, binding.scale * marker_mm @ binding.rotation.T)
    np.testing.assert_allclose(_mesh_motion(transfer, details), want, atol=EXACT_FLOAT64)
    _, names = transfer.shapes()
    assert names[:4] == ("left_brow:m0:x", "left_brow:m0:y", "left_brow:m0:z", "left_brow:m1:x")


def test_markers_at_vertices_are_interpolated_exactly():
    mesh, _, groups = _detail_setup()
    corner = np.array([[1.0, 0, 0]] * 5)
    binding = _binding(mesh, [300, 345, 420, 480, 520], corner, scale=0.1, seed=3)
    transfer = build_detail_transfer(binding, mesh, groups)
    details = {g: np.random.default_rng(5).normal(0, 3, (2, len(m), 3)) for g, m in
               groups.items()}
    moved = _mesh_motion(transfer, details)[:, binding.vertex_ids[:, 0]]
    marker_mm = np.concatenate([details[g] for g in groups], axis=1)
    np.testing.assert_allclose(moved, 0.1 * marker_mm @ binding.rotation.T, atol=MESH_EXACT)


def test_a_marker_moves_only_vertices_within_the_support_of_its_cluster():
    mesh, binding, groups = _detail_setup(cluster_gap=True)
    support = 1.5
    transfer = build_detail_transfer(binding, mesh, groups, support=support)
    centers = binding.marker_points(mesh.vertices)
    details = {"left_brow": np.zeros((1, 2, 3)), "left_eye": np.zeros((1, 3, 3))}
    details["left_brow"][0, 0] = [2.0, -1.0, 0.5]
    moved = np.linalg.norm(_mesh_motion(transfer, details)[0], axis=1)
    near = cdist(mesh.vertices, centers[:2]).min(axis=1)
    assert cdist(centers[:2], centers[2:]).min() > 2 * support
    assert np.all(moved[near >= support] == 0.0)
    close = np.linalg.norm(mesh.vertices - centers[0], axis=1) < 0.3 * support
    assert close.any() and np.all(moved[close] > 0.0)


def test_transfer_is_linear_in_the_details():
    mesh, binding, groups = _detail_setup()
    transfer = build_detail_transfer(binding, mesh, groups)
    rng = np.random.default_rng(6)
    a, b = ({g: rng.normal(0, 2, (4, len(m), 3)) for g, m in groups.items()} for _ in "ab")
    mix = {g: 2.0 * a[g] - 0.5 * b[g] for g in groups}
    np.testing.assert_allclose(_mesh_motion(transfer, mix),
                               2.0 * _mesh_motion(transfer, a) - 0.5 * _mesh_motion(transfer, b),
                               atol=EXACT_FLOAT64)


def test_default_support_is_a_multiple_of_the_median_marker_spacing():
    mesh, binding, groups = _detail_setup()
    centers = binding.marker_points(mesh.vertices)
    dist = cdist(centers, centers) + np.diag(np.full(5, np.inf))
    transfer = build_detail_transfer(binding, mesh, groups)
    assert transfer.support == pytest.approx(SUPPORT_SPACINGS * np.median(dist.min(axis=1)))


@pytest.mark.parametrize("groups, support, error, match", [
    ({"left_brow": ("m0", "nope")}, None, MarkerError, "'nope'.*not in the binding"),
    ({"left_brow": ()}, None, InputError, "no detail markers"),
    ({"left_brow": ("m0",)}, None, InputError, "give the support radius"),
    ({"left_brow": ("m0", "m1")}, -1.0, InputError, "support"),
])
def test_detail_transfer_errors(groups, support, error, match):
    mesh, binding, _ = _detail_setup()
    with pytest.raises(error, match=match):
        build_detail_transfer(binding, mesh, groups, support=support)


def test_weights_need_every_group():
    mesh, binding, groups = _detail_setup()
    transfer = build_detail_transfer(binding, mesh, groups)
    with pytest.raises(InputError, match=r"details lack the groups \['left_eye'\]"):
        transfer.weights({"left_brow": np.zeros((1, 2, 3))})


def test_cli_transfers_details_onto_the_ict_face(ict_mesh, ict_layout, ict_neutral_path,
                                                  ict_expressions_dir, cli_files, tmp_path):
    """``gestures --mesh --shapes --binding``: details as extra shapes of the real ICT face."""
    from fit.exports import read_mesh_sequence
    from mocap.retarget.rbf import build_rbf_operator

    wav, _, out = cli_files
    neutral = ict_mesh
    layout = ict_layout
    binding = Binding(labels=layout.labels, scale=0.1, rotation=np.eye(3),
                      translation=np.zeros(3), face_ids=layout.face_ids,
                      vertex_ids=layout.vertex_ids, barycentric=layout.weights,
                      distances=np.zeros(len(layout.labels)), rms=0.0, skin_offset=0.0,
                      n_landmarks=0, n_iterations=0, converged=True, message="layout")
    binding.save(tmp_path / "binding.json")
    shapes = tmp_path / "shapes"
    shapes.mkdir()
    for name in ("eyeBlink_L", "jawOpen"):
        (shapes / f"{name}.obj").symlink_to(ict_expressions_dir / f"{name}.obj")
    rng = np.random.default_rng(8)
    groups = {"left_brow": ("brow-L1", "brow-L2", "brow-L3"), "left_eye": ("eye-L-upper",)}
    clip = GestureClip("ict", RATE, np.cumsum(rng.normal(0, 1, 200)),
                       _smooth(rng, 200, 2), ("jawOpen", "eyeBlink_L"),
                       details={g: rng.normal(0, 1.5, (200, len(m), 3)) for g, m in
                                groups.items()}, detail_labels=groups)
    save_clip(tmp_path / "ict.npz", clip)
    assert main(["gestures", "synthesize", str(wav), "--palette", str(tmp_path / "ict.npz"),
                 "-o", str(out),
                 "--mesh", str(ict_neutral_path), "--shapes", str(shapes),
                 "--units", "cm", "--binding", str(tmp_path / "binding.json"),
                 "--no-lips"]) == 0
    seq = read_mesh_sequence(out / "mesh.npz")
    assert seq.names[:2] == ("eyeBlink_L", "jawOpen") and len(seq.names) == 2 + 3 * 4
    details = np.load(out / "details.npz")
    labels = groups["left_brow"] + groups["left_eye"]
    marker_mm = np.concatenate([details[f"details.{g}"] for g in groups], axis=1)
    centers = layout.positions(neutral.vertices, offset=False)[[layout.index(x) for x in labels]]
    spacing = np.sort(cdist(centers, centers), axis=1)[:, 1]
    support = SUPPORT_SPACINGS * np.median(spacing)
    op = build_rbf_operator(centers, neutral.vertices, kernel="bspline_bell",
                            epsilon=1.0 / support)
    matrix = op.matrix if isinstance(op.matrix, np.ndarray) else op.matrix.toarray()
    want_details = np.einsum("vm,tma->tva", matrix, 0.1 * marker_mm)
    blend = np.tensordot(seq.weights[:, :2], seq.displacements[:2], axes=1)
    total = np.tensordot(seq.weights, seq.displacements, axes=1)
    np.testing.assert_allclose(total - blend, want_details, atol=FLOAT32_FACE_CM)
    far = cdist(neutral.vertices, centers).min(axis=1) >= support
    # far from the markers the details are exact zeros: the blend alone, but for the
    # order the BLAS sums the shapes in
    assert far.sum() > 0.5 * len(far)
    np.testing.assert_allclose(total[:, far], blend[:, far], rtol=0,
                               atol=FLOAT32_REL * np.abs(blend).max())
    assert (out / "gestures.glb").stat().st_size > 0


def test_marker_basis_is_the_shape_motion_of_the_bound_points_in_capture_mm():
    mesh, binding, _ = _detail_setup()
    binding = dataclasses.replace(binding, translation=np.array([1.0, -2.0, 0.5]))
    shapes = np.random.default_rng(9).normal(0, 0.3, (2,) + mesh.vertices.shape)
    labels = ("m3", "m0")
    got = marker_basis(binding, shapes, labels, units="mm")
    rows = [binding.labels.index(x) for x in labels]
    for i, shape in enumerate(shapes):           # through the affine map, shape by shape
        moved = binding.to_capture(binding.marker_points(mesh.vertices + shape)[rows])
        rest = binding.to_capture(binding.marker_points(mesh.vertices)[rows])
        np.testing.assert_allclose(got[i], moved - rest, atol=EXACT_MM)
    with pytest.raises(MarkerError, match="'nope'.*is not in the binding"):
        marker_basis(binding, shapes, ("nope",))
