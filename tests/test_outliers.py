"""Tests of mocap.clean.outliers: implausible samples found exactly, then refilled."""

from __future__ import annotations

import numpy as np
import pytest
from tolerances import OUTLIER_REFILL_MM, REPAIRED_STEP_MM

from mocap.clean import fill_gaps
from mocap.clean.outliers import (
    REASONS,
    ImplausibleSamples,
    find_implausible_samples,
    remove_implausible_samples,
)
from mocap.errors import InputError, MarkerError
from mocap.take import Take

N_FRAMES = 400
#: A 4 x 3 grid of markers 15 mm apart, so that every marker has neighbours to refill it.
GRID = np.array([[x, y, 0.0] for y in (0, 15, 30) for x in (0, 15, 30, 45)])
LABELS = tuple(f"m{i}" for i in range(len(GRID)))


def smooth_take(seed: int = 0) -> Take:
    """A face-like grid with genuine fast motion and no implausible sample.

    The whole grid sways +-3 mm; m5 "blinks" 10 mm in 2 frames and back
    (5 mm/frame); m9 and m10 (lips) open 13 mm and close at up to 8 mm/frame,
    accelerating as skin does; 0.05 mm noise.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(N_FRAMES) / 100.0
    pos = np.repeat(GRID[None], N_FRAMES, axis=0)
    pos += (3 * np.sin(2 * np.pi * 0.5 * t))[:, None, None] * np.array([1.0, 0.3, 0.2])
    pos[200:205, 5, 1] -= [5, 10, 10, 5, 0]
    lips = 6.5 * (1 - np.cos(np.clip((t - 1.2) * 2 * np.pi * 4, 0, 2 * np.pi)))
    pos[:, 9, 1] -= lips
    pos[:, 10, 1] -= lips
    pos += rng.normal(scale=0.05, size=pos.shape)
    return Take(LABELS, pos, rate=100.0)


def truth_mask(runs) -> np.ndarray:
    """(N_FRAMES, M) bool of the injected runs (label, start, stop)."""
    mask = np.zeros((N_FRAMES, len(LABELS)), bool)
    for label, start, stop in runs:
        mask[start:stop, LABELS.index(label)] = True
    return mask


def with_positions(take: Take, edits) -> Take:
    pos = take.positions.copy()
    for label, frames, value in edits:
        pos[frames, take.index(label)] = value
    return take.replace(positions=pos)


def duplicate(take: Take) -> tuple[Take, list]:
    """m0 takes m11's marker (45 mm away) for 20 frames."""
    src = take.positions[150:170, take.index("m11")]
    return with_positions(take, [("m0", slice(150, 170), src)]), [("m0", 150, 170)]


def teleport(take: Take) -> tuple[Take, list]:
    """m6 jumps 80 mm out of the face (over 25 times its spread) for 30 frames, then back."""
    moved = take.positions[100:130, take.index("m6")] + [0.0, 0.0, 80.0]
    return with_positions(take, [("m6", slice(100, 130), moved)]), [("m6", 100, 130)]


def ghost_slide(take: Take) -> tuple[Take, list]:
    """m2 slides in a straight line at constant speed 80 mm away, stays, and slides back.

    The capture software's interpolated ghost: 12 frames out, 20 frames away, 12 back.
    """
    i = take.index("m2")
    a, b = take.positions[249, i], take.positions[294, i]
    away = GRID[2] + [0.0, 0.0, 80.0]
    out = a + np.linspace(0, 1, 14)[1:-1, None] * (away - a)
    back = away + np.linspace(0, 1, 14)[1:-1, None] * (b - away)
    hold = away + np.random.default_rng(1).normal(scale=0.05, size=(20, 3))
    edits = [("m2", slice(250, 262), out), ("m2", slice(262, 282), hold),
             ("m2", slice(282, 294), back)]
    return with_positions(take, edits), [("m2", 250, 294)]


INJECTIONS = {"duplicate": duplicate, "teleport": teleport, "ghost-slide": ghost_slide}


def test_smooth_take_with_fast_motion_is_all_plausible():
    take = smooth_take()
    step = np.linalg.norm(np.diff(take.positions, axis=0), axis=2)
    assert step.max() > 4.9  # the blink and the lips really are fast
    found = find_implausible_samples(take)
    assert found.n_flagged == 0 and found.runs == ()
    assert found.message.startswith("0 implausible samples")


@pytest.mark.parametrize("kind", sorted(INJECTIONS))
def test_injected_samples_are_found_exactly(kind):
    dirty, runs = INJECTIONS[kind](smooth_take())
    found = find_implausible_samples(dirty)
    np.testing.assert_array_equal(found.mask, truth_mask(runs))
    assert {r.marker for r in found.runs} == {runs[0][0]}
    assert all(r.reason in REASONS for r in found.runs)
    assert kind in {r.reason for r in found.runs}
    assert found.n_flagged == sum(stop - start for _, start, stop in runs)


def test_all_kinds_at_once_across_a_gap():
    take = smooth_take()
    runs = []
    for inject in INJECTIONS.values():
        take, more = inject(take)
        runs += more
    take = with_positions(take, [("m7", slice(60, 70), np.nan)])  # a gap is never flagged
    found = find_implausible_samples(take)
    np.testing.assert_array_equal(found.mask, truth_mask(runs))
    starts = [r.start for r in found.runs]
    assert starts == sorted(starts)


def test_head_frame_separates_a_head_turn_from_a_teleport():
    """A 90-degree head turn moves face markers by up to 50 mm: implausible in the
    capture frame for a marker's rest region, plausible in the head frame."""
    take = smooth_take()
    angle = np.deg2rad(90.0) * np.clip((np.arange(N_FRAMES) - 100) / 100.0, 0, 1)
    c, s = np.cos(angle), np.sin(angle)
    rot = np.zeros((N_FRAMES, 3, 3))
    rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1], rot[:, 2, 2] = c, -s, s, c, 1
    head_points = np.array([[0.0, 60, 20], [45, 60, 20], [22, 80, 30], [22, 50, 50]])
    pos = np.concatenate([take.positions, np.repeat(head_points[None], N_FRAMES, 0)], axis=1)
    turned = Take(LABELS + ("h0", "h1", "h2", "h3"), np.einsum("tij,tmj->tmi", rot, pos),
                  rate=100.0)
    dirty, runs = teleport(turned)
    found = find_implausible_samples(dirty, head=("h0", "h1", "h2", "h3"))
    want = np.zeros((N_FRAMES, len(dirty.labels)), bool)
    want[100:130, dirty.index("m6")] = True
    np.testing.assert_array_equal(found.mask, want)
    assert found.message.endswith("head frame")
    assert find_implausible_samples(dirty).n_flagged > 30  # off rest in the capture frame


def test_removed_samples_are_refilled_near_the_truth():
    clean = smooth_take()
    dirty, runs = teleport(clean)
    found = find_implausible_samples(dirty)
    removed = remove_implausible_samples(dirty, found)
    assert np.isnan(removed.positions[found.mask]).all()
    np.testing.assert_array_equal(removed.positions[~found.mask], dirty.positions[~found.mask])
    assert (removed.filled[found.mask] == 0).all()
    refilled = fill_gaps(removed, method="auto", max_gap=N_FRAMES).take   # long runs: asked
    err = np.linalg.norm(refilled.positions - clean.positions, axis=2)[found.mask]
    raw = np.linalg.norm(dirty.positions - clean.positions, axis=2)[found.mask]
    assert raw.min() > 79 and err.max() < OUTLIER_REFILL_MM


def test_inputs_not_mutated_and_results_read_only():
    dirty, _ = duplicate(smooth_take())
    before = dirty.positions.copy()
    found = find_implausible_samples(dirty)
    out = remove_implausible_samples(dirty, found)
    np.testing.assert_array_equal(dirty.positions, before)
    assert not np.shares_memory(out.positions, dirty.positions)
    with pytest.raises(ValueError):
        found.mask[0, 0] = True


@pytest.mark.parametrize("kwargs, match", [
    ({"off_rest": 0.0}, "off_rest must be positive"),
    ({"teleport": -1.0}, "teleport must be positive"),
    ({"duplicate_mm": 5.0, "duplicate_apart_mm": 4.0}, r"duplicate_apart_mm \(4.0\) must exceed"),
    ({"min_slide": 2}, "min_slide must be at least 3"),
    ({"max_gap": -1}, "max_gap must be at least 0"),
    ({"head": "m0"}, "head must be a sequence of marker labels"),
])
def test_find_rejects_bad_options(kwargs, match):
    with pytest.raises(InputError, match=match):
        find_implausible_samples(smooth_take(), **kwargs)


def test_find_rejects_a_missing_head_marker_and_a_non_take():
    with pytest.raises(MarkerError, match="nose"):
        find_implausible_samples(smooth_take(), head=("m0", "m3", "nose"))
    with pytest.raises(InputError, match="take must be a mocap.Take"):
        find_implausible_samples(np.zeros((10, 2, 3)))


def test_remove_rejects_a_result_of_another_take():
    found = find_implausible_samples(smooth_take())
    short = Take(LABELS, smooth_take().positions[:100], rate=100.0)
    with pytest.raises(InputError, match="made for a take of 400 frames"):
        remove_implausible_samples(short, found)
    with pytest.raises(InputError, match="found must be an ImplausibleSamples"):
        remove_implausible_samples(short, found.mask)
    assert isinstance(found, ImplausibleSamples)


# -- real data ------------------------------------------------------------------

def test_facial_sing_mislabel_is_the_only_implausible_event(facial_sing_take,
                                                            facial_sing_markerset):
    """facial-sing frames 819-863: the section3-1/3-2 labels leave their markers
    (jumps of ~70 mm, ghost samples interpolated between). Everything else in the
    3000 frames, slips of the head markers included, is plausible."""
    take = facial_sing_take
    head = facial_sing_markerset.head
    found = find_implausible_samples(take, head=head)
    frames = np.flatnonzero(found.mask.any(axis=1))
    assert frames.min() >= 819 and frames.max() <= 863
    assert {r.marker for r in found.runs} == {"section3-1", "section3-2"}
    i = take.index("section3-1")
    jump = np.linalg.norm(np.diff(take.positions[815:870, i], axis=0), axis=1)
    assert np.nanmax(jump) > 60  # the event is in the file
    cleaned = fill_gaps(remove_implausible_samples(take, found), method="auto",
                        max_gap=100).take                  # the 45-frame run: asked for
    after = np.linalg.norm(np.diff(cleaned.positions[815:870, i], axis=0), axis=1)
    assert np.nanmax(after) < REPAIRED_STEP_MM
