"""Facial gestures: decomposition of takes, the MRF synthesis, timelines and the CLI."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.io.wavfile
import scipy.stats
from scipy.spatial.transform import Rotation

from fit.cli import main
from fit.gestures import (ESTIMATORS, FEATURES, GestureClip, analyze_gestures,
                          candidate_distances, clip_from_analysis, load_clip, parse_timeline,
                          pick_candidate, save_clip, synthesize_gestures)
from mocap.errors import FileFormatError, InputError, MarkerError
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


def _moving_average_oracle(x, window):
    """Centred mean over the frames inside the take (explicit loop)."""
    k = window // 2
    return np.array([x[max(0, t - k):t + k + 1].mean(axis=0) for t in range(len(x))])


@pytest.mark.parametrize("window", [1, 5, 41])
def test_exact_analysis_recovers_the_averaged_weights(capture, window):
    stab, neutral, basis, c, _ = capture
    result = analyze_gestures(stab, neutral, basis, REGIONS, labels=FACE, window=window)
    np.testing.assert_allclose(result.weights, _moving_average_oracle(c, window), atol=1e-8)
    np.testing.assert_allclose(result.rotation, stab.rotation)
    if window == 1:
        np.testing.assert_allclose(result.residual(), 0.0, atol=1e-8)


@pytest.mark.parametrize("estimator", ESTIMATORS)
def test_weights_respect_the_bounds(capture, estimator):
    stab, neutral, basis, _, _ = capture
    eps = 0.05
    result = analyze_gestures(stab, neutral, 0.4 * basis, REGIONS, labels=FACE, epsilon=eps,
                              estimator=estimator, window=1, n_samples=300, n_neighbors=20)
    assert np.all(result.weights >= -eps - 1e-12) and np.all(result.weights <= 1 + eps + 1e-12)
    assert np.any(result.weights >= 1 + eps - 1e-9) == (estimator == "exact")


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
    np.testing.assert_allclose(total, moved[:, len(HEAD):], atol=1e-9)
    assert np.abs(result.details["left_brow"]).max() > 1.0


def _restabilized(stab, moved):
    import dataclasses
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
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("run", [1, 4])
def test_own_intensity_with_sigma_zero_reproduces_the_reference(run):
    clip = _clip("ref")
    syn = synthesize_gestures(clip.intensity, [clip], rate=RATE, history=30, sigma=0.0, run=run)
    np.testing.assert_array_equal(syn.sources["weights"][:, 1], np.arange(clip.n_frames))
    np.testing.assert_array_equal(syn.weights, clip.weights)
    assert syn.transitions["weights"] == 0


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
                               np.broadcast_to(np.eye(3), (200, 3, 3)), atol=1e-12)


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
    assert scipy.stats.chisquare(counts, draws * p / p.sum()).pvalue > 1e-3
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
    np.testing.assert_allclose(np.linalg.norm(clip.head[:, :3], axis=1).max(),
                               Rotation.from_matrix(stab.rotation).magnitude().max(), rtol=0.5)


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


def test_features_are_the_timeline_features():
    assert FEATURES[:2] == ("weights", "head")


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


def test_cli_writes_weights_and_head_motion(cli_files):
    wav, clip, out = cli_files
    assert main(["gestures", str(wav), "--palette", str(clip), "-o", str(out)]) == 0
    import pandas as pd
    table = pd.read_csv(out / "weights.csv")
    assert len(table) == 120 and list(table.columns[2:]) == ["s0", "s1", "s2"]
    head = np.load(out / "head.npz")
    assert head["rotation"].shape == (120, 3, 3)


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
    assert main(["gestures", str(wav), *args]) == 1
    assert match in capsys.readouterr().err


def test_cli_missing_speech_exits_1(cli_files, capsys):
    wav, clip, out = cli_files
    assert main(["gestures", str(out / "none.wav"), "--palette", str(clip), "-o", str(out)]) == 1
    assert "no such file" in capsys.readouterr().err
