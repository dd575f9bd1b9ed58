"""Tests of mocap.clean.swaps: label swaps found exactly and undone."""

from __future__ import annotations

import numpy as np
import pytest
from tolerances import SWAP_RESIDUAL_FRACTION

from mocap.clean.swaps import LabelSwap, find_label_swaps, fix_label_swaps
from mocap.errors import InputError, MarkerError
from mocap.stabilize import stabilize
from mocap.take import Take

N_FRAMES = 400
LABELS = ("m0", "m1", "m2", "m3", "m4", "m5")


def smooth_take(seed: int = 0) -> Take:
    """Six markers 15 mm apart on a moving head, with fast genuine motion.

    The head sways +-50 mm (up to 1.6 mm/frame); m4 "blinks" 10 mm towards m1
    in 2 frames and back (5 mm/frame); m5 and m2 (lips) close to 2 mm apart
    and open again, 8 mm/frame at the fastest.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(N_FRAMES) / 100.0
    base = np.array([[0, 0, 0], [15, 0, 0], [30, 0, 0],
                     [0, 15, 0], [15, 15, 0], [30, 15, 0]], float)
    pos = np.repeat(base[None], N_FRAMES, axis=0)
    pos += (50 * np.sin(2 * np.pi * 0.5 * t))[:, None, None] * np.array([1.0, 0.3, 0.2])
    blink = np.zeros(N_FRAMES)
    blink[200:205] = [5, 10, 10, 5, 0]
    pos[:, 4, 1] -= blink
    lips = 6.5 * (1 - np.cos(np.clip((t - 1.2) * 2 * np.pi * 4, 0, 2 * np.pi)))
    pos[:, 5, 1] -= lips
    pos += rng.normal(scale=0.05, size=pos.shape)
    return Take(LABELS, pos, rate=100.0)


def inject(take: Take, swaps) -> Take:
    """Exchange columns by a plain loop over frames: the oracle of fix_label_swaps."""
    pos = take.positions.copy()
    filled = take.filled.copy()
    for a, b, start, stop in swaps:
        i, j = take.index(a), take.index(b)
        for f in range(start, stop):
            pos[f, i], pos[f, j] = pos[f, j].copy(), pos[f, i].copy()
            filled[f, i], filled[f, j] = filled[f, j], filled[f, i]
    return take.replace(positions=pos, filled=filled)


def with_gap(take: Take, label: str, start: int, stop: int) -> Take:
    pos = take.positions.copy()
    pos[start:stop, take.index(label)] = np.nan
    return take.replace(positions=pos)


def found(swaps) -> list:
    return [(s.marker_a, s.marker_b, s.start, s.stop) for s in swaps]


def test_smooth_take_with_fast_motion_has_no_swap():
    take = smooth_take()
    step = np.linalg.norm(np.diff(take.positions, axis=0), axis=2)
    assert step.max() > 5.0  # the blink and the lips really are fast
    assert find_label_swaps(take) == ()


CASES = {
    "one frame": ([("m0", "m1", 100, 101)], None),
    "five frames": ([("m1", "m4", 150, 155)], None),
    "long": ([("m3", "m4", 50, 250)], None),
    "to the end": ([("m0", "m3", 330, N_FRAMES)], None),
    "two pairs": ([("m0", "m1", 60, 90), ("m4", "m5", 120, 140)], None),
    "after a gap": ([("m1", "m2", 210, 240)], ("m2", 200, 210)),
    "gap inside": ([("m0", "m1", 100, 160)], ("m1", 120, 130)),
    "to a long gap": ([("m2", "m5", 100, 150)], ("m5", 150, 220)),
}


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("head_frame", [False, True])
def test_injected_swaps_found_exactly_and_repaired(case, head_frame):
    swaps, gap = CASES[case]
    clean = smooth_take()
    if gap is not None:
        clean = with_gap(clean, *gap)
    if head_frame:  # what stabilization would give: the sway (m0 and m3 follow it) removed
        sway = clean.positions[:, [0, 3]].mean(axis=1, keepdims=True)
        clean = clean.replace(positions=clean.positions - sway)
    dirty = inject(clean, swaps)
    result = find_label_swaps(dirty)
    want = [(a, b, start, stop) for a, b, start, stop in swaps]
    if case == "to a long gap":  # the labels still differ in the gap: undone too
        want = [("m2", "m5", 100, 150)]
    assert found(result) == sorted(want, key=lambda s: (s[2], s[0], s[1]))
    for swap in result:
        assert swap.residual_mm < SWAP_RESIDUAL_FRACTION * swap.jump_mm
        assert swap.score > 10
    repaired = fix_label_swaps(dirty, result)
    np.testing.assert_array_equal(repaired.positions, clean.positions)
    np.testing.assert_array_equal(repaired.filled, clean.filled)


def test_fix_matches_a_frame_loop_and_moves_filled_codes():
    rng = np.random.default_rng(3)
    take = smooth_take()
    filled = rng.integers(0, 4, size=(N_FRAMES, len(LABELS)))
    take = with_gap(take.replace(filled=filled), "m1", 40, 60)
    swaps = [("m0", "m1", 30, 80), ("m1", "m2", 70, 120), ("m5", "m0", 390, 400)]
    records = [LabelSwap(a, b, s, e, 0.0, 0.0, 0.0) for a, b, s, e in swaps]
    got = fix_label_swaps(take, records)
    want = inject(take, swaps)
    np.testing.assert_array_equal(got.positions, want.positions)
    np.testing.assert_array_equal(got.filled, want.filled)
    assert got.labels == take.labels and got.rate == take.rate


def test_inputs_not_mutated():
    dirty = inject(smooth_take(), [("m0", "m1", 100, 120)])
    before = dirty.positions.copy(), dirty.filled.copy()
    swaps = find_label_swaps(dirty)
    out = fix_label_swaps(dirty, swaps)
    np.testing.assert_array_equal(dirty.positions, before[0])
    np.testing.assert_array_equal(dirty.filled, before[1])
    assert out is not dirty and not np.shares_memory(out.positions, dirty.positions)
    with pytest.raises(Exception):
        swaps[0].start = 3  # frozen record


@pytest.mark.parametrize("kwargs, match", [
    ({"neighbours": 0}, "neighbours must be at least 1"),
    ({"threshold": -1.0}, "threshold must be positive"),
    ({"max_ratio": 1.5}, "max_ratio must be below 1"),
    ({"max_gap": -2}, "max_gap must be at least 0"),
])
def test_find_rejects_bad_options(kwargs, match):
    with pytest.raises(InputError, match=match):
        find_label_swaps(smooth_take(), **kwargs)


def test_find_rejects_a_non_take():
    with pytest.raises(InputError, match="take must be a mocap.Take"):
        find_label_swaps(np.zeros((10, 2, 3)))


def test_fix_rejects_a_non_take():
    with pytest.raises(InputError, match="take must be a mocap.Take"):
        fix_label_swaps(np.zeros((10, 2, 3)), ())


@pytest.mark.parametrize("swap, error, match", [
    (("m0", "m1", 0, 1), InputError, "swaps must hold LabelSwap records"),
    (LabelSwap("m0", "zz", 0, 5, 0, 0, 0), MarkerError, "'zz': not in the take"),
    (LabelSwap("m0", "m0", 0, 5, 0, 0, 0), MarkerError, "two different markers"),
    (LabelSwap("m0", "m1", 5, 5, 0, 0, 0), InputError, r"covers frames 5:5"),
    (LabelSwap("m0", "m1", 0, N_FRAMES + 1, 0, 0, 0), InputError, r"stop <= 400"),
])
def test_fix_rejects_bad_swaps(swap, error, match):
    with pytest.raises(error, match=match):
        fix_label_swaps(smooth_take(), [swap])


# -- real data ------------------------------------------------------------------

@pytest.fixture(scope="module")
def facial_sing_frames(facial_sing_take, facial_sing_markerset):
    """facial-sing.c3d in the capture frame and in the head frame (stabilized)."""
    take = facial_sing_take
    return take, stabilize(take, facial_sing_markerset.head).take


@pytest.mark.parametrize("frame", ["capture", "head"])
def test_facial_sing_has_no_pairwise_swap(facial_sing_frames, frame):
    """The frames 819-863 event is a four-label mislabel (section3-1/3-2 labels on
    section4-1/4-2's markers, with interpolated ghost samples between), not a swap of
    two labels: at no frame do two labels each land where the other was."""
    take = facial_sing_frames[frame == "head"]
    a, b = take.index("section3-1"), take.index("section3-2")
    step = np.linalg.norm(np.diff(take.positions[:, [a, b]], axis=0), axis=2)
    assert np.nanmax(step) > 60  # the event is there
    assert find_label_swaps(take) == ()


@pytest.mark.parametrize("frame", ["capture", "head"])
@pytest.mark.parametrize("pair, start, stop", [
    (("section10-1", "section10-2"), 1500, 1540),
    (("section1-1", "section1-2"), 2500, 2501),
    (("section13-2", "section13-3"), 2900, 3000),
])
def test_swap_injected_in_facial_sing_found_and_repaired(facial_sing_frames, frame, pair, start,
                                                         stop):
    take = facial_sing_frames[frame == "head"]
    dirty = inject(take, [(*pair, start, stop)])
    cols = take.indices(pair)
    assert not np.isnan(take.positions[start - 1:start + 1, cols]).any()
    result = find_label_swaps(dirty)
    assert found(result) == [(*pair, start, stop)]
    repaired = fix_label_swaps(dirty, result)
    np.testing.assert_array_equal(repaired.positions, take.positions)


def test_vicon_body_capture_has_no_swap(vicon_nexus_take):
    take = vicon_nexus_take
    assert find_label_swaps(take) == ()
