"""Gap filling (mocap.clean.fill_gaps) against known trajectories.

Oracles: analytic sinusoids with the cubic-spline error bound, a rigid body in
known motion (rigid fill exact), data of exact low rank (PCA fill exact),
scipy's Rotation.align_vectors for the batched Kabsch fit the rigid fill uses.
"""

import numpy as np
import pandas as pd
import pytest
import threadpoolctl
from scipy.spatial.transform import Rotation
from tolerances import (
    EXACT_FLOAT64,
    EXACT_MM,
    GAPFILL_KABSCH_MM,
    GAPFILL_KABSCH_ROT,
    GAPFILL_LOW_RANK_MM,
    GAPFILL_RIGID_MM,
    GAPFILL_WANDER_REL,
    SPLINE_BOUND_FACTOR,
)

from mocap import InputError, MarkerError, Take
from mocap.clean import FILL_OPTIONS, _pca_fill, fill_gaps
from mocap.clean._rigid_fill import donor_weights
from mocap.clean.gapfill import DEFAULT_MAX_GAP_S
from mocap.rigid import fit_rigid
from mocap.take import fill_code

FILLING = tuple(m for m in FILL_OPTIONS if m != "none")
RATE = 100.0
N_FRAMES = 400
HEAD = [f"root-{i}" for i in range(1, 7)]
CLUSTERS = {"head": HEAD}
#: max_gap of the tests of what a fill is worth: every gap of the take, asked for.
ANY = N_FRAMES


def head_take(n_face=6, seed=0):
    """Six head markers on a rigid body in known smooth motion, plus face markers
    carried by the head with their own smooth local motion. Noise-free."""
    rng = np.random.default_rng(seed)
    t = np.arange(N_FRAMES) / RATE
    body = rng.normal(scale=60.0, size=(6 + n_face, 3))
    local = np.zeros((N_FRAMES, 6 + n_face, 3))
    freq = rng.uniform(0.3, 1.5, size=(n_face, 3))
    phase = rng.uniform(0, 6, (n_face, 3))
    local[:, 6:] = 5.0 * np.sin(2 * np.pi * freq * t[:, None, None] + phase)
    rot = Rotation.from_rotvec(np.column_stack([0.4 * np.sin(2 * t), 0.3 * np.cos(3 * t),
                                                0.2 * np.sin(t)]))
    trans = np.column_stack([100 * np.sin(t), 30 * t, 10 * np.cos(5 * t)])
    pos = np.einsum("tij,tmj->tmi", rot.as_matrix(), body + local) + trans[:, None]
    labels = HEAD + [f"face-{i}" for i in range(n_face)]
    return Take(labels, pos, rate=RATE)


def low_rank_take(n_markers=10, rank=3, seed=1):
    """Positions = mean + rank modes with sinusoidal scores of similar amplitude."""
    rng = np.random.default_rng(seed)
    t = np.arange(N_FRAMES) / RATE
    modes = rng.normal(scale=10.0, size=(rank, n_markers, 3))
    scores = np.sin(2 * np.pi * rng.uniform(0.3, 2.0, rank) * t[:, None] + rng.uniform(0, 6, rank))
    pos = rng.normal(scale=100.0, size=(n_markers, 3)) + np.einsum("tr,rmc->tmc", scores, modes)
    return Take([f"m{i}" for i in range(n_markers)], pos, rate=RATE)


def with_gaps(take, gaps):
    """A copy of `take` with samples removed: gaps = [(label, start, stop), ...]."""
    pos = take.positions.copy()
    for label, start, stop in gaps:
        pos[start:stop, take.index(label)] = np.nan
    return take.replace(positions=pos)


# -- the pieces against their oracles ---------------------------------------------
def test_rigid_fit_recovers_exact_transform_and_matches_scipy():
    rng = np.random.default_rng(3)
    n_fits, n_points = 50, 6
    src = rng.normal(scale=50, size=(n_fits, n_points, 3))
    rot = Rotation.random(n_fits, random_state=4)
    trans = rng.normal(scale=100, size=(n_fits, 3))
    dst = np.einsum("fij,fkj->fki", rot.as_matrix(), src) + trans[:, None]
    weights = np.ones((n_fits, n_points))
    weights[np.arange(n_fits), rng.integers(0, n_points, n_fits)] = 0   # one point unused
    src_nan = np.where(weights[..., None] > 0, src, np.nan)
    fit = fit_rigid(src_nan, dst, weights)
    r, t = fit.rotation, fit.translation
    np.testing.assert_allclose(r, rot.as_matrix(), atol=EXACT_FLOAT64)
    np.testing.assert_allclose(t, trans, atol=EXACT_MM)

    noisy = dst + rng.normal(scale=2.0, size=dst.shape)
    w = weights * rng.uniform(0.5, 2.0, size=weights.shape)
    fit = fit_rigid(src, noisy, w)
    r, t = fit.rotation, fit.translation
    for f in range(n_fits):
        cs = (w[f, :, None] * src[f]).sum(0) / w[f].sum()
        cd = (w[f, :, None] * noisy[f]).sum(0) / w[f].sum()
        ref, _ = Rotation.align_vectors(noisy[f] - cd, src[f] - cs, weights=w[f])
        np.testing.assert_allclose(r[f], ref.as_matrix(), atol=GAPFILL_KABSCH_ROT)
        np.testing.assert_allclose(t[f], cd - ref.as_matrix() @ cs, atol=GAPFILL_KABSCH_MM)


@pytest.mark.parametrize("gap", [5, 20, 40])
def test_spline_fill_of_sinusoid_within_the_cubic_spline_bound(gap):
    t = np.arange(N_FRAMES) / RATE
    amp, omega = 10.0, 2 * np.pi * 1.0
    truth = amp * np.sin(omega * t[:, None] + np.array([0.0, 1.0, 2.0]))
    start = 150
    take = with_gaps(Take(("a",), truth[:, None], rate=RATE), [("a", start, start + gap)])
    got = fill_gaps(take, method="spline", max_gap=ANY).take.positions[start:start + gap, 0]
    err = np.abs(got - truth[start:start + gap]).max()
    h = (gap + 1) / RATE                               # the spline piece spanning the gap
    bound = 5 / 384 * amp * omega ** 4 * h ** 4         # (5/384) h^4 max|f''''|
    linear = amp * omega ** 2 * h ** 2 / 8              # linear interpolation's bound
    assert err <= SPLINE_BOUND_FACTOR * bound
    assert err < linear


def test_rigid_fill_is_exact_on_rigid_data_with_partial_donors():
    truth = head_take()
    take = with_gaps(truth, [("root-3", 100, 180), ("root-5", 120, 140), ("root-1", 170, 200)])
    result = fill_gaps(take, method="rigid", clusters=CLUSTERS, max_gap=ANY)
    np.testing.assert_allclose(result.take.positions[:, :6], truth.positions[:, :6],
                               atol=GAPFILL_RIGID_MM, rtol=0)
    assert result.n_missing == 0
    assert set(result.gaps["method"]) == {"rigid"}


def test_rigid_fill_leaves_frames_without_three_donors():
    truth = head_take(n_face=0).select(HEAD[:4])
    take = with_gaps(truth, [("root-1", 100, 150), ("root-2", 120, 130)])
    result = fill_gaps(take, method="rigid", clusters={"head": HEAD[:4]}, max_gap=ANY)
    row = result.gaps.set_index("marker").loc["root-1"]
    assert row["filled"] == 40
    assert row["reason"].startswith("10 frames left: 3 donors")
    assert np.isnan(result.take.positions[120:130, 0]).all()
    np.testing.assert_allclose(result.take.positions[100:120, 0], truth.positions[100:120, 0],
                               atol=GAPFILL_RIGID_MM, rtol=0)


def _slid(truth, column, offset):
    """`truth` with marker `column` moved by `offset` (n_frames, 3) in the head's body frame."""
    rot = Rotation.from_rotvec(np.column_stack([0.4 * np.sin(2 * truth.times),
                                                0.3 * np.cos(3 * truth.times),
                                                0.2 * np.sin(truth.times)])).as_matrix()
    pos = truth.positions.copy()
    pos[:, column] += np.einsum("tij,tj->ti", rot, offset)
    return truth.replace(positions=pos)


def test_rigid_fill_interpolates_in_the_donors_frame():
    # The target slides at constant velocity on the head (a head band creeping,
    # 2.7 mm over the gap): linear in the body frame, curved in the world.
    slide = np.outer(np.arange(N_FRAMES), [0.02, -0.01, 0.015])
    truth = _slid(head_take(n_face=0), 0, slide)
    start, stop = 150, 250
    result = fill_gaps(with_gaps(truth, [("root-1", start, stop)]), method="rigid",
                       clusters=CLUSTERS, max_gap=ANY)
    np.testing.assert_allclose(result.take.positions[start:stop, 0],
                               truth.positions[start:stop, 0], atol=GAPFILL_RIGID_MM, rtol=0)


def test_rigid_fill_down_weights_a_donor_that_moves_relative_to_the_target():
    # root-6 wanders 4 mm on the head; the others are rigid with the target root-1.
    wander = 4.0 * np.sin(2 * np.pi * 0.7 * np.arange(N_FRAMES)[:, None] / RATE + [0, 1, 2])
    truth = _slid(head_take(n_face=0), 5, wander)
    start, stop = 150, 250
    take = with_gaps(truth, [("root-1", start, stop)])
    got = fill_gaps(take, method="rigid", clusters=CLUSTERS,
                    max_gap=ANY).take.positions[start:stop, 0]
    err = np.linalg.norm(got - truth.positions[start:stop, 0], axis=1)
    # Oracle of an unweighted fill: all donors carried from the frame before the gap.
    pos = truth.positions
    naive = fit_rigid(pos[start - 1, 1:6], pos[start:stop, 1:6])
    naive_err = np.linalg.norm(naive.apply(pos[start - 1, :1])[:, 0] - pos[start:stop, 0], axis=1)
    assert naive_err.max() > 0.3
    assert err.max() < GAPFILL_WANDER_REL * naive_err.max()


def test_donor_weights_are_inverse_distance_variances_near_the_gap():
    rng = np.random.default_rng(5)
    pos = rng.normal(scale=3.0, size=(400, 5, 3)) + rng.normal(scale=80.0, size=(5, 3))
    pos[rng.random((400, 5)) < 0.2] = np.nan
    pos[:, 4] = np.nan                           # never seen: the smallest other weight
    pos[250:300, 0] = np.nan
    donors = np.array([1, 2, 3, 4])
    got = donor_weights(pos, 0, 250, 300, donors)
    near = np.r_[150:250, 300:400]               # RIGIDITY_FRAMES = 100 each side
    expect = [1 / (np.nanvar(np.linalg.norm(pos[near, d] - pos[near, 0], axis=1)) + 0.1 ** 2)
              for d in donors[:3]]
    np.testing.assert_allclose(got, expect + [min(expect)], rtol=EXACT_FLOAT64)


@pytest.mark.parametrize("path", ["complete", "iterative"])
def test_pca_fill_is_exact_on_low_rank_data(path, monkeypatch):
    truth = low_rank_take(n_markers=6)
    gaps = [("m2", 150, 230), ("m4", 300, 320)]
    if path == "iterative":
        # Two donors missing in every 50-frame block outside m2's gap: no frame has
        # m2 and any MIN_DONORS donors all visible, so the iterative PCA is needed.
        pairs = [("m0", "m1"), ("m3", "m5"), ("m1", "m4"), ("m0", "m5"), ("m3", "m4")]
        blocks = [(0, 50), (50, 100), (100, 150), (230, 280), (280, 330), (330, 400)]
        for (start, stop), pair in zip(blocks, pairs + pairs):
            gaps += [(label, start, stop) for label in pair]
    take = with_gaps(truth, gaps)
    calls = []
    original = _pca_fill._components_iterative
    monkeypatch.setattr(_pca_fill, "_components_iterative",
                        lambda *a: calls.append(1) or original(*a))
    result = fill_gaps(take, method="pca", extrapolate=True, max_gap=ANY)
    got = result.take.positions[150:230, 2]
    np.testing.assert_allclose(got, truth.positions[150:230, 2], atol=GAPFILL_LOW_RANK_MM, rtol=0)
    assert bool(calls) == (path == "iterative")


def test_pca_axes_from_the_scaled_scatter_are_the_standardized_rows_svd():
    """The window's principal axes, from the scatter of its centred rows scaled after the
    product, are numpy's SVD of the rows centred, divided by their spread and weighted:
    the same singular values, the same axes up to sign; a column that does not vary keeps
    a scale of 1."""
    rng = np.random.default_rng(4)
    rows = rng.normal(0.0, 1.0, (300, 9)) @ rng.normal(0.0, 1.0, (9, 9)) + 500.0
    rows[:, 4] = 123.0                                       # a marker coordinate that stays
    weight = rng.uniform(0.2, 1.0, 9)
    mean, scale, sv, axes = _pca_fill._standardized_axes(rows.copy(), weight)
    np.testing.assert_allclose(mean, rows.mean(axis=0), rtol=EXACT_FLOAT64)
    spread = rows.std(axis=0)
    assert scale[4] == 1.0
    np.testing.assert_allclose(np.delete(scale, 4), np.delete(spread, 4), rtol=1e-12)
    _, expected_sv, vt = np.linalg.svd((rows - rows.mean(axis=0)) / scale * weight,
                                       full_matrices=False)
    # from the scatter's eigenvalues: their squares are exact to rounding
    np.testing.assert_allclose(sv ** 2, expected_sv ** 2, rtol=0,
                               atol=EXACT_FLOAT64 * expected_sv[0] ** 2)
    kept = expected_sv > 1e-6 * expected_sv[0]
    np.testing.assert_allclose(np.abs(np.sum(axes[:, kept] * vt[kept].T, axis=0)), 1.0,
                               atol=1e-9)


# -- behaviour shared by every method -----------------------------------------------
@pytest.mark.parametrize("method", FILLING)
def test_fill_records_codes_and_keeps_captured_samples(method):
    take = with_gaps(head_take(), [("root-2", 50, 80), ("face-1", 200, 230), ("face-3", 10, 12)])
    before = take.positions.copy()
    result = fill_gaps(take, method=method, clusters=CLUSTERS, max_gap=ANY)
    np.testing.assert_array_equal(take.positions, before)        # caller's take unchanged
    assert not take.filled.any()
    out = result.take
    seen = ~take.missing
    np.testing.assert_array_equal(out.positions[seen], take.positions[seen])
    newly = take.missing & ~out.missing
    assert (out.filled[~newly] == 0).all()
    for row in result.gaps.itertuples():
        codes = out.filled[row.start:row.stop, out.index(row.marker)]
        if row.method == "none":
            assert row.filled == 0 and (codes == 0).all() and row.reason
        else:
            assert (codes == fill_code(row.method)).sum() == row.filled
            assert method in ("auto", row.method)
    assert result.n_filled == int(newly.sum()) == int(result.gaps["filled"].sum())
    assert result.n_missing == int(out.missing.sum())


@pytest.mark.parametrize("method", FILLING)
def test_edge_gaps_need_extrapolate(method):
    truth = head_take()
    take = with_gaps(truth, [("root-4", 0, 15), ("root-6", N_FRAMES - 10, N_FRAMES)])
    kept = fill_gaps(take, method=method, clusters=CLUSTERS, max_gap=ANY)
    assert kept.n_filled == 0
    assert kept.gaps["reason"].str.contains("first or last frame").all()
    extra = fill_gaps(take, method=method, clusters=CLUSTERS, extrapolate=True, max_gap=ANY)
    assert extra.n_missing == 0
    if method in ("rigid", "auto"):
        np.testing.assert_allclose(extra.take.positions, truth.positions,
                                   atol=GAPFILL_RIGID_MM, rtol=0)


@pytest.mark.parametrize("method", FILLING)
@pytest.mark.parametrize("max_gap, filled", [
    (None, {"face-0", "face-1"}), (ANY, {"root-2", "face-0", "face-1"}),
    (10, {"face-0", "face-1"}), (5, {"face-0"}), (0, set())])
def test_max_gap_limits_what_is_filled(method, max_gap, filled):
    """None: the default, 0.1 s (10 frames at 100 Hz); a longer fill must be asked for."""
    take = with_gaps(head_take(), [("root-2", 100, 130), ("face-0", 200, 205),
                                   ("face-1", 300, 310)])
    result = fill_gaps(take, method=method, max_gap=max_gap, clusters=CLUSTERS)
    done = set(result.gaps.loc[result.gaps["filled"] > 0, "marker"])
    if method == "rigid":
        filled = filled - {"face-0", "face-1"}          # not in a cluster
    assert done == filled
    limit = DEFAULT_MAX_GAP_S * RATE if max_gap is None else max_gap
    assert result.max_gap == limit
    longer = result.gaps["length"] > limit
    assert result.gaps.loc[longer, "reason"].str.startswith(f"longer than max_gap={limit:g}").all()
    assert not result.gaps.loc[~longer, "reason"].str.startswith("longer").any()


def test_auto_chooses_rigid_then_pca_then_spline():
    take = with_gaps(head_take(), [("root-2", 100, 130), ("face-0", 200, 240)])
    result = fill_gaps(take, method="auto", clusters=CLUSTERS, max_gap=ANY)
    assert dict(zip(result.gaps["marker"], result.gaps["method"])) == {"root-2": "rigid",
                                                                      "face-0": "pca"}
    few = with_gaps(head_take(n_face=0).select(HEAD[:_pca_fill.MIN_DONORS]),
                    [("root-1", 100, 110)])
    assert fill_gaps(few, method="auto", max_gap=ANY).gaps["method"].tolist() == ["spline"]


def test_method_none_only_reports():
    take = with_gaps(head_take(), [("root-2", 100, 130), ("face-0", 0, 5)])
    result = fill_gaps(take, method="none", clusters=CLUSTERS)
    np.testing.assert_array_equal(result.take.positions, take.positions)
    assert result.gaps[["marker", "start", "stop", "length"]].values.tolist() == [
        ["root-2", 100, 130, 30], ["face-0", 0, 5, 5]]
    assert (result.gaps["reason"] == "method is 'none'").all()


def test_rigid_leaves_markers_outside_clusters_and_keeps_earlier_fill_codes():
    take = with_gaps(head_take(), [("face-2", 100, 130)])
    filled = np.zeros(take.filled.shape, np.uint8)
    filled[5, 7] = fill_code("spline")
    take = take.replace(filled=filled)
    result = fill_gaps(take, method="rigid", clusters=CLUSTERS, max_gap=ANY)
    assert result.gaps["reason"].tolist() == ["not in any rigid cluster"]
    assert result.take.filled[5, 7] == fill_code("spline")


# -- errors: one per message ----------------------------------------------------------
@pytest.mark.parametrize("kwargs, error, match", [
    ({"method": "woltring"}, InputError, r"method must be one of .*'woltring'"),
    ({"max_gap": -1}, InputError, "max_gap must be at least 0, got -1"),
    ({"max_gap": 2.5}, InputError, "max_gap must be an integer"),
    ({"method": "rigid"}, InputError, "method 'rigid' needs clusters"),
    ({"min_visible": 1.5}, InputError, r"min_visible must be in \[0, 1\], got 1.5"),
    ({"min_visible": "half"}, InputError, r"min_visible must be a number in \[0, 1\]"),
    ({"markers": ["root-1", "nose"]}, MarkerError, "'nose': not in the take"),
    ({"clusters": {"head": HEAD + ["nose"]}}, MarkerError, "'nose': not in the take"),
    ({"clusters": HEAD}, InputError, "clusters must be a mapping"),
    ({"clusters": {"head": "root-1"}}, InputError, "must be a list of marker labels"),
    ({"extrapolate": "yes"}, InputError, "extrapolate must be True or False"),
])
def test_fill_gaps_errors(kwargs, error, match):
    with pytest.raises(error, match=match):
        fill_gaps(head_take(), **kwargs)


def test_fill_gaps_rejects_arrays():
    with pytest.raises(InputError, match="take must be a mocap.Take, got ndarray"):
        fill_gaps(np.zeros((3, 1, 3)))


def test_pca_fill_learns_from_frames_near_the_gap_only():
    """Frames farther than WINDOW_FRAMES from a gap cannot change its fill."""
    rng = np.random.default_rng(5)
    n_frames, w = 3 * _pca_fill.WINDOW_FRAMES, _pca_fill.WINDOW_FRAMES
    t = np.arange(n_frames) / 100.0
    modes = np.stack([np.sin(2 * np.pi * f * t) for f in (0.3, 0.7, 1.1)], axis=1)
    pos = (modes @ rng.normal(size=(3, 8 * 3))).reshape(n_frames, 8, 3) * 10
    pos += rng.normal(0, 0.05, pos.shape)
    start, stop = n_frames // 2, n_frames // 2 + 40
    pos[start:stop, 0] = np.nan
    far = pos.copy()
    far[: start - w - 1] += rng.normal(0, 30, far[: start - w - 1].shape)   # wild, far away
    fills = [fill_gaps(Take(tuple("abcdefgh"), p, rate=100), method="pca",
                       max_gap=ANY).take.positions for p in (pos, far)]
    np.testing.assert_array_equal(fills[0][start:stop, 0], fills[1][start:stop, 0])


# -- what a fill may not do: invent markers, fill unasked, carry too few donors -------
@pytest.mark.parametrize("method", FILLING)
def test_three_head_markers_work_for_every_method(method):
    """A 3-marker cluster gives 2 donors, too few for a rigid fit: never an error."""
    take = with_gaps(head_take(), [("root-2", 100, 108), ("face-1", 200, 206)])
    small = {"head": HEAD[:3]}
    result = fill_gaps(take, method=method, clusters=small)
    row = result.gaps.set_index("marker").loc["root-2"]
    if method == "rigid":
        assert row["filled"] == 0 and row["reason"] == (
            "its cluster 'head' has 3 markers: a rigid fill needs 3 donors besides the "
            "missing marker, so at least 4 markers")
    else:
        assert row["filled"] == 8 and row["method"] != "rigid"
    if method != "rigid":       # the small cluster changes nothing: as if there were none
        alone = fill_gaps(take, method=method)
        np.testing.assert_array_equal(result.take.positions, alone.take.positions)


def test_a_small_cluster_beside_a_usable_one():
    take = with_gaps(head_take(), [("root-2", 100, 108), ("face-1", 200, 206)])
    clusters = {"head": HEAD, "nose": ["face-0", "face-1", "face-2"]}
    result = fill_gaps(take, method="rigid", clusters=clusters).gaps.set_index("marker")
    assert result.loc["root-2", "filled"] == 8
    assert result.loc["face-1", "reason"].startswith("its cluster 'nose' has 3 markers")


def test_markers_outside_the_fill_set_are_left_and_never_donate():
    """Oracle: the fill of the listed markers equals the fill of a take without the others."""
    rng = np.random.default_rng(9)
    take = with_gaps(head_take(), [("face-1", 200, 206), ("root-3", 50, 57)])
    ghost = rng.normal(scale=300.0, size=(N_FRAMES, 1, 3))       # wild, visible throughout
    sparse = np.full((N_FRAMES, 1, 3), np.nan)
    sparse[::12] = rng.normal(scale=50.0, size=(len(sparse[::12]), 1, 3))
    extra = take.replace(labels=take.labels + ("ghost", "Unlabeled1"),
                         positions=np.concatenate([take.positions, ghost, sparse], axis=1),
                         filled=np.zeros((N_FRAMES, take.n_markers + 2), np.uint8))
    result = fill_gaps(extra, markers=take.labels, clusters=CLUSTERS)
    np.testing.assert_array_equal(result.take.positions[:, -2:], extra.positions[:, -2:])
    assert (result.take.filled[:, -2:] == 0).all()
    alone = fill_gaps(take, clusters=CLUSTERS)
    np.testing.assert_allclose(result.take.positions[:, :-2], alone.take.positions,
                               rtol=0, atol=EXACT_MM)
    others = result.gaps[result.gaps["marker"] == "Unlabeled1"]
    assert len(others) and (others["reason"] == "not among the markers to fill").all()
    assert result.unfilled_markers == ("ghost", "Unlabeled1")


@pytest.mark.parametrize("n_visible, filled", [(35, False), (199, False), (200, True)])
def test_a_marker_visible_in_under_half_the_take_is_reported_not_filled(n_visible, filled):
    take = head_take()
    pos = take.positions.copy()
    seen = np.zeros(N_FRAMES, bool)
    seen[np.linspace(0, N_FRAMES - 1, n_visible).round().astype(int)] = True   # short gaps
    pos[~seen, take.index("face-2")] = np.nan
    take = take.replace(positions=pos)
    result = fill_gaps(take, clusters=CLUSTERS, max_gap=ANY)
    rows = result.gaps[result.gaps["marker"] == "face-2"]
    assert (rows["filled"] > 0).any() == filled
    if not filled:
        assert (rows["reason"] == f"visible in {n_visible} of {N_FRAMES} frames "
                                  f"({100 * n_visible / N_FRAMES:.1f} %), under "
                                  "min_visible = 0.5").all()
        assert result.unfilled_markers == ("face-2",)
        anyway = fill_gaps(take, clusters=CLUSTERS, max_gap=ANY, min_visible=0)
        assert anyway.gaps.loc[anyway.gaps["marker"] == "face-2", "filled"].sum() > 0


def test_gaps_filled_on_two_threads_as_on_one():
    """The gaps are estimated on the BLAS's threads: with the BLAS on two threads the
    take, the fill codes and the gap table are those of one thread, bit for bit, whatever
    order the gaps finish in (rigid, PCA and spline fills, and gaps left as they are)."""
    take = with_gaps(head_take(n_face=8), [
        ("root-2", 100, 130), ("root-1", 300, 340), ("face-0", 200, 240), ("face-3", 50, 52),
        ("face-5", 250, 330), ("face-7", 0, 10), ("face-1", 150, 155), ("face-2", 150, 160)])
    few = with_gaps(head_take(n_face=0).select(HEAD[:_pca_fill.MIN_DONORS]),
                    [("root-1", 100, 110), ("root-2", 200, 230)])
    methods = []
    for case, clusters in ((take, CLUSTERS), (few, None)):
        results = []
        for threads in (1, 2):
            with threadpoolctl.threadpool_limits(threads, user_api="blas"):
                results.append(fill_gaps(case, method="auto", clusters=clusters, max_gap=60))
        one, two = results
        np.testing.assert_array_equal(two.take.positions, one.take.positions)
        np.testing.assert_array_equal(two.take.filled, one.take.filled)
        pd.testing.assert_frame_equal(two.gaps, one.gaps)
        methods.append(set(one.gaps["method"]))
    assert methods == [{"rigid", "pca", "none"}, {"spline"}]
