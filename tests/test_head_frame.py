"""The head frame for every kind of capture: head markers, auto (stabilization markers), none;
the guard of the robust fit."""

import warnings

import numpy as np
import pytest
from foreign_captures import head_frame_error, ict_capture
from scipy.spatial.transform import Rotation
from tolerances import AUTO_HEAD_DEG, AUTO_HEAD_MM, EXACT_MM, LOOP_ORACLE

from mocap import InputError, MarkerError, Take
from mocap.clean.ingest import IngestOptions, ingest
from mocap.head_frame import (
    NONE_MAX_DEG,
    STABILIZATIONS,
    as_stabilization,
    face_motion,
    find_head_frame,
    stabilization_candidates,
)
from mocap.markerset import MarkerSet
from mocap.stabilize import ROBUST_GUARD_DEG, stabilize
from mocap.stable_markers import distance_variation, find_stable_markers

BONE = [f"bone{i}" for i in range(6)]
SOFT = [f"soft{i}" for i in range(8)]


def skull_take(n_frames=600, seed=0, head_deg=4.0):
    """6 markers on bone, 8 on skin that moves by up to 6 mm, a turning head.

    Returns the take and the true rotation (T, 3, 3) and translation (T, 3), mm.
    """
    rng = np.random.default_rng(seed)
    bone = np.array([[60, 40, 0], [-60, 40, 0], [0, 70, 20], [45, -5, 30], [-45, -5, 30],
                     [0, 20, 55]], float)
    soft = rng.uniform([-50, -90, 10], [50, -20, 60], (len(SOFT), 3))
    t = np.arange(n_frames) / 100.0
    wobble = 6 * np.sin(2 * np.pi * rng.uniform(0.2, 1.0, (1, len(SOFT), 3)) * t[:, None, None]
                        + rng.uniform(0, 6, (1, len(SOFT), 3)))
    local = np.concatenate([np.broadcast_to(bone, (n_frames, 6, 3)), soft + wobble], axis=1)
    angles = head_deg * np.sin(2 * np.pi * np.array([0.3, 0.2, 0.5]) * t[:, None] + [0, 1, 2])
    rot = Rotation.from_euler("xyz", angles, degrees=True).as_matrix()
    trans = 10 * np.sin(2 * np.pi * np.array([0.1, 0.3, 0.2]) * t[:, None]) + [0, 0, 1500]
    world = np.einsum("tij,tmj->tmi", rot, local) + trans[:, None]
    world += 0.1 * rng.standard_normal(world.shape)
    return Take(tuple(BONE + SOFT), world, 100.0), rot, trans


# ---------------------------------------------------------------- stabilization markers

def test_distance_variation_matches_a_loop_over_pairs():
    rng = np.random.default_rng(3)
    pos = rng.normal(size=(50, 4, 3)) * 10
    pos[rng.random((50, 4)) < 0.2] = np.nan
    mean, std, count = distance_variation(pos, block_frames=7)
    for i in range(4):
        for j in range(4):
            if i == j:
                continue
            d = np.linalg.norm(pos[:, i] - pos[:, j], axis=1)
            d = d[~np.isnan(d)]
            assert count[i, j] == len(d)
            assert mean[i, j] == pytest.approx(d.mean(), abs=LOOP_ORACLE)
            assert std[i, j] == pytest.approx(d.std(), abs=LOOP_ORACLE)


def test_stable_markers_are_the_ones_on_bone():
    take, _, _ = skull_take()
    chosen = find_stable_markers(take)
    assert set(chosen.labels) <= set(BONE) and len(chosen.labels) >= 5
    assert chosen.marker_variation.max() < 0.5                  # noise only (0.1 mm a coordinate)
    assert "hold their distances best" in chosen.message


def test_auto_head_frame_follows_the_true_head_motion():
    take, rot, trans = skull_take()
    head = find_head_frame(take, method="auto")
    centre = np.nanmedian(head.take.positions, axis=(0, 1))
    deg, mm = head_frame_error(head.stabilization.rotation, head.stabilization.translation,
                               rot, trans, centre)
    assert deg < 0.1 and mm < 0.2
    assert head.method == "auto" and set(head.markers) == set(head.stable.labels)
    assert any("bone0" in line for line in head.report())


def test_stable_markers_refuse_too_few_candidates():
    take, _, _ = skull_take(n_frames=20)
    with pytest.raises(InputError, match="candidate markers; choosing stabilization markers"):
        find_stable_markers(take, BONE[:2])


def test_stable_markers_leave_out_rare_markers_and_refuse_when_too_few_remain():
    take, _, _ = skull_take(n_frames=40)
    pos = np.array(take.positions)
    pos[:30, :4] = np.nan                                       # seen in a quarter of the take
    rare = take.replace(positions=pos)
    chosen = find_stable_markers(rare, BONE + SOFT[:2])
    assert {label for label, _ in chosen.excluded} == set(BONE[:4])
    with pytest.raises(MarkerError, match="is visible in 25 % of the frames"):
        find_stable_markers(rare, BONE[:5])


def test_stable_markers_refuse_collinear_candidates():
    line = np.zeros((10, 3, 3))
    line[:, :, 0] = [0.0, 10.0, 20.0]
    with pytest.raises(InputError, match="collinear or never visible together"):
        find_stable_markers(Take(("a", "b", "c"), line, 100.0))


# ---------------------------------------------------------------- head, auto, none

def test_head_needs_head_markers():
    take, _, _ = skull_take(n_frames=20)
    no_head = MarkerSet("x", (), {"other": tuple(BONE + SOFT)})
    with pytest.raises(InputError, match="names no head markers: use stabilize = 'auto'"):
        find_head_frame(take, no_head, method="head")
    with pytest.raises(InputError, match="stabilize = 'head' needs a marker set naming"):
        ingest(take, markerset=no_head, options=IngestOptions(fill="none", stabilize="head"))


def test_three_head_markers_are_enough():
    take, rot, trans = skull_take(n_frames=200)
    three = MarkerSet("x", tuple(BONE[:3]), {"other": tuple(BONE[3:] + SOFT)})
    head = find_head_frame(take, three, method="head")
    centre = np.nanmedian(head.take.positions, axis=(0, 1))
    deg, mm = head_frame_error(head.stabilization.rotation, head.stabilization.translation,
                               rot, trans, centre)
    assert head.markers == tuple(BONE[:3]) and deg < 0.2 and mm < 0.3


def test_auto_uses_the_marker_sets_stabilization_list():
    take, _, _ = skull_take(n_frames=100)
    listed = MarkerSet("x", (), {"other": tuple(BONE + SOFT)}, stabilization=tuple(BONE[:4]))
    head = find_head_frame(take, listed, method="auto")
    assert head.markers == tuple(BONE[:4])


def test_auto_candidates_leave_out_the_regions_the_jaw_moves():
    ms = MarkerSet("x", (), {"upper_lip": ("u1",), "chin": ("c1", "c2"), "jaw": ("j1",),
                             "nose": ("n1", "n2"), "left_eye": ("e1",)})
    assert stabilization_candidates(ms) == ("n1", "n2", "e1")


def test_none_keeps_the_take_and_is_silent_when_it_is_in_the_head_frame():
    take, rot, trans = skull_take()
    in_head = stabilize(take, BONE).take
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        head = find_head_frame(in_head, method="none")
    assert head.markers == () and not head.motion.moves
    np.testing.assert_allclose(head.take.positions, in_head.positions, atol=EXACT_MM)


def test_none_warns_naming_the_evidence_when_the_head_moves():
    take, _, _ = skull_take()
    with pytest.warns(UserWarning, match="stabilize = 'none' takes .* but the 6 markers that "
                                         "hold their shape best .* turn by"):
        head = find_head_frame(take, method="none")
    assert head.motion.median_angle > NONE_MAX_DEG
    assert face_motion(take).moves


def test_stabilization_options_keep_the_old_spelling():
    assert as_stabilization(True) == "head" and as_stabilization(False) is None
    assert IngestOptions(stabilize=True) == IngestOptions(stabilize="head")
    assert set(STABILIZATIONS) == {"head", "auto", "none"}
    with pytest.raises(InputError, match="stabilize must be one of"):
        IngestOptions(stabilize="headband")
    with pytest.raises(InputError, match="robust_stabilization must be true or false"):
        IngestOptions(robust_stabilization="yes")


def test_ingest_reports_how_the_head_frame_was_found():
    take, _, _ = skull_take(n_frames=300)
    ms = MarkerSet("x", (), {"other": tuple(BONE + SOFT)})
    result = ingest(take, markerset=ms, options=IngestOptions(fill="none", stabilize="auto"))
    assert result.head_frame.method == "auto" and result.stabilization is not None
    assert set(result.stabilization.head_markers) <= set(BONE)


# ---------------------------------------------------------------- the robust fit's guard

def slip_take(n_frames=400):
    """Four markers 20 mm apart, one slipping 12 mm in frames 150-249: the plain fit turns
    with it by several degrees, the robust one discounts it."""
    head = np.array([[10.0, 0, 0], [-10, 0, 0], [0, 12, 5], [0, -8, 12]])
    pos = np.broadcast_to(head, (n_frames, 4, 3)).copy()
    pos[150:250, 3, 0] += 12.0
    pos = pos + 0.05 * np.random.default_rng(0).standard_normal(pos.shape)
    return Take(("a", "b", "c", "d"), pos, 100.0)


def test_robust_fit_that_disagrees_with_the_plain_fit_is_reported():
    take = slip_take()
    with pytest.warns(UserWarning, match=f"disagree by more than {ROBUST_GUARD_DEG:g} deg in "
                                         r"\d+ frames"):
        st = stabilize(take, take.labels)
    assert st.disagreements
    run = st.disagreements[0]
    assert 140 <= run.start and run.stop <= 260 and run.max_angle > ROBUST_GUARD_DEG


def test_robust_fit_of_a_rigid_head_is_not_reported():
    take, _, _ = skull_take(n_frames=200)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        st = stabilize(take, BONE)
    assert st.disagreements == () and st.robust
    assert stabilize(take, BONE, robust=False).disagreements == ()


def test_guard_angle_must_be_positive():
    take, _, _ = skull_take(n_frames=20)
    with pytest.raises(InputError, match="guard_deg must be"):
        stabilize(take, BONE, guard_deg=-1.0)


# ---------------------------------------------------------------- a simulated ICT capture

@pytest.fixture(scope="module")
def ict_without_head(ict_basis, arkit_performance, ict_layout, ict_markerset):
    """A 30 s ICT capture at 60 Hz, head turning up to 3 deg and shifting 10 mm, no head markers."""
    return ict_capture(ict_basis, arkit_performance, ict_layout, ict_markerset, keep_head=False)


def test_auto_meets_the_aim_on_a_simulated_capture(ict_without_head):
    """The issue's aim: median rotation error <= 0.3 deg, translation <= 0.5 mm."""
    face = {}
    for label, region in ict_without_head.regions.items():
        face.setdefault(region, []).append(label)
    ms = MarkerSet("ict", (), {region: tuple(labels) for region, labels in face.items()})
    with warnings.catch_warnings():      # the guard names a few frames of extreme expressions
        warnings.filterwarnings("ignore", "the robust and the plain rigid fits", UserWarning)
        head = find_head_frame(ict_without_head.take, ms, method="auto")
    centre = np.nanmedian(head.take.positions, axis=(0, 1))
    deg, mm = head_frame_error(head.stabilization.rotation, head.stabilization.translation,
                               ict_without_head.rotation, ict_without_head.translation, centre)
    print(f"auto on {', '.join(head.markers)}: {deg:.3f} deg, {mm:.3f} mm")
    assert deg <= AUTO_HEAD_DEG and mm <= AUTO_HEAD_MM


def test_stand_in_head_of_stiff_face_markers_is_reported(facial_sing_take):
    """The issue's case: five stiff upper-face markers as a head; the robust fit turned 9 deg
    where the plain fit turned 2.3: the frames are named, neither fit trusted silently."""
    stand_in = ["section7-1", "section3-2", "section4-2", "section1-1", "section2-1"]
    with pytest.warns(UserWarning, match="do not move as one rigid body"):
        st = stabilize(facial_sing_take, stand_in)
    assert max(run.max_angle for run in st.disagreements) > 2 * ROBUST_GUARD_DEG


@pytest.mark.parametrize(("call", "error", "match"), [
    (lambda take: find_stable_markers(take, ["bone0", "bone0", "bone1"]), InputError,
     "labels must be a sequence of distinct marker labels"),
    (lambda take: find_stable_markers(take, min_presence=1.5), InputError,
     r"min_presence must be in \[0, 1\]"),
    (lambda take: find_head_frame(take, "markerset.toml", method="auto"), InputError,
     "markerset must be a MarkerSet, got str"),
    (lambda take: find_head_frame(take, method="head"), InputError,
     "needs head markers, but no marker set"),
    (lambda take: find_head_frame(take, method="skull"), InputError,
     "stabilize must be one of"),
])
def test_head_frame_errors(call, error, match):
    take, _, _ = skull_take(n_frames=20)
    with pytest.raises(error, match=match):
        call(take)
