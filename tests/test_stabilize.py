"""Head stabilization: invariance to rigid motion, scipy oracle, GPA, slips, gaps, errors."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from tolerances import (
    EXACT_FLOAT64,
    EXACT_MM,
    GPA_MEAN_MM,
    RIGID_VS_ORACLE,
    RIGID_VS_ORACLE_MM,
    STABILIZE_CONVERGED_NOISE,
    STABILIZE_GAP_DEG,
    STABILIZE_INVARIANCE,
    STABILIZE_ON_HEAD_MM,
    STABILIZE_REAL_RESIDUAL_MM,
    STABILIZE_SLIP_DEG,
    STABILIZE_SLIP_FACTOR,
    STABILIZE_START_WEIGHTS,
)

from mocap import InputError, MarkerError, Take
from mocap.stabilize import INVALID_POLICIES, REFERENCES, stabilize

HEAD = ["root-1", "root-2", "root-3", "root-4", "root-5", "root-6"]
#: A head-marker layout like the one of facial-sing.c3d, mm.
SHAPE = np.array([[120, 25, 12], [-116, 17, 7], [33, -32, 64],
                  [-42, -14, 65], [75, 4, -74], [-70, 0, -73]], float)


def make_take(n_frames=300, noise=0.05, seed=0, n_face=5):
    """Smooth known head motion; returns take, true R (T, 3, 3), true t (T, 3)."""
    rng = np.random.default_rng(seed)
    time = np.arange(n_frames) / 100.0
    angles = 25 * np.sin(2 * np.pi * np.array([0.3, 0.2, 0.4]) * time[:, None] + [0, 1, 2])
    rot = Rotation.from_euler("xyz", angles, degrees=True).as_matrix()
    trans = 150 * np.sin(2 * np.pi * np.array([0.1, 0.25, 0.15]) * time[:, None] + [2, 0, 1])
    face = rng.normal(size=(n_face, 3)) * 40 + [0, 90, -30]
    local = np.broadcast_to(np.vstack([SHAPE, face]), (n_frames, 6 + n_face, 3)).copy()
    local[:, 6:] += rng.normal(size=(n_frames, n_face, 3))      # expressions
    world = np.einsum("tij,tmj->tmi", rot, local) + trans[:, None]
    world += rng.normal(size=world.shape) * noise
    labels = HEAD + [f"face-{i}" for i in range(n_face)]
    return Take(labels, world, rate=100.0), rot, trans


def move(take, rng):
    """The take under a random rigid motion per frame: (moved take, G rotations, g translations)."""
    g_rot = Rotation.random(take.n_frames, random_state=rng).as_matrix()
    g_trans = rng.normal(size=(take.n_frames, 3)) * 1000
    moved = np.einsum("tij,tmj->tmi", g_rot, take.positions) + g_trans[:, None]
    return take.replace(positions=moved), g_rot, g_trans


def rotation_error_deg(a, b):
    return np.degrees(Rotation.from_matrix(np.swapaxes(a, -1, -2) @ b).magnitude())


@pytest.mark.parametrize("robust", [True, False])
@pytest.mark.parametrize("reference", REFERENCES)
def test_rigid_motion_leaves_stabilized_take_unchanged(reference, robust):
    take, _, _ = make_take(noise=0.2)
    moved, g_rot, g_trans = move(take, np.random.default_rng(1))
    kw = dict(reference=reference, reference_frame=7, robust=robust)
    a = stabilize(take, HEAD, **kw)
    b = stabilize(moved, HEAD, **kw)
    # The head frame is the world frame at the reference frame, so the moved
    # take's head frame is the original one moved by G(7).
    expect = a.take.positions @ g_rot[7].T + g_trans[7]
    np.testing.assert_allclose(b.take.positions, expect, atol=STABILIZE_INVARIANCE)
    np.testing.assert_allclose(b.head_residuals, a.head_residuals, atol=STABILIZE_INVARIANCE)
    np.testing.assert_allclose(b.weights, a.weights, atol=STABILIZE_INVARIANCE)


def test_transform_equals_scipy_align_vectors_with_the_reported_weights():
    take, _, _ = make_take(noise=0.3)
    st = stabilize(take, HEAD)
    head = take.positions[:, :6]
    for t in (0, 57, 123, 299):
        w = st.weights[t]
        cy = w @ head[t] / w.sum()
        cx = w @ st.reference_shape / w.sum()
        rot, _ = Rotation.align_vectors(head[t] - cy, st.reference_shape - cx, weights=w)
        np.testing.assert_allclose(st.rotation[t], rot.as_matrix(), atol=RIGID_VS_ORACLE)
        np.testing.assert_allclose(st.translation[t], cy - rot.apply(cx), atol=RIGID_VS_ORACLE_MM)
    np.testing.assert_allclose(np.linalg.det(st.rotation), 1.0, atol=EXACT_FLOAT64)


def test_frame_reference_equals_align_vectors_on_that_frame():
    take, _, _ = make_take(noise=0.3)
    st = stabilize(take, HEAD, reference="frame", reference_frame=40, robust=False)
    head = take.positions[:, :6]
    np.testing.assert_allclose(st.reference_shape, head[40])
    np.testing.assert_allclose(st.rotation[40], np.eye(3), atol=EXACT_FLOAT64)
    for t in (3, 200):
        rot, _ = Rotation.align_vectors(head[t] - head[t].mean(0), head[40] - head[40].mean(0))
        np.testing.assert_allclose(st.rotation[t], rot.as_matrix(), atol=RIGID_VS_ORACLE)


def test_gpa_mean_shape_is_the_true_shape_and_invariant_to_rigid_motion():
    take, rot, trans = make_take(noise=0.0)
    st = stabilize(take, HEAD)
    moved = stabilize(move(take, np.random.default_rng(2))[0], HEAD)

    def distances(shape):
        return np.linalg.norm(shape[:, None] - shape[None], axis=-1)

    np.testing.assert_allclose(distances(st.reference_shape), distances(SHAPE), atol=EXACT_MM)
    np.testing.assert_allclose(distances(moved.reference_shape), distances(SHAPE), atol=EXACT_MM)
    # Exact data: the head frame is the world at the first frame.
    np.testing.assert_allclose(st.reference_shape, SHAPE @ rot[0].T + trans[0], atol=EXACT_MM)
    assert st.converged and st.valid.all() and st.slips == ()


def test_gpa_mean_is_the_average_of_the_aligned_frames():
    take, _, _ = make_take(noise=0.5)
    st = stabilize(take, HEAD, robust=False)
    aligned = st.to_head(take.positions[:, :6])
    np.testing.assert_allclose(aligned.mean(axis=0), st.reference_shape, atol=GPA_MEAN_MM)


def test_slipping_marker_is_detected_and_down_weighted():
    take, rot, trans = make_take(n_frames=400, noise=0.1)
    pos = take.positions.copy()
    pos[150:250, 2] += rot[150:250] @ np.array([3.0, 0.0, 4.0])     # 5 mm on the head
    take = take.replace(positions=pos)
    st = stabilize(take, HEAD)
    assert [(s.marker, s.start, s.stop) for s in st.slips] == [("root-3", 150, 250)]
    assert 4.5 < st.slips[0].max_residual < 5.5
    assert st.weights[150:250, 2].max() < 0.01
    assert st.weights[:150, 2].min() > 0.5
    error = rotation_error_deg(st.rotation, rot @ rot[0].T)   # head frame: world at frame 0
    outside = np.r_[error[:150], error[250:]]
    assert np.median(error) < STABILIZE_SLIP_DEG
    # the slip costs nothing
    assert np.median(error[150:250]) < STABILIZE_SLIP_FACTOR * np.median(outside)
    plain = stabilize(take, HEAD, robust=False)
    assert [s.marker for s in plain.slips].count("root-3") >= 1
    err_plain = rotation_error_deg(plain.rotation[150:250], st.rotation[150:250])
    assert np.median(err_plain) > 0.2                    # the slip biases a plain fit


def slipped_take(n_frames=400):
    """make_take with root-3 slipping 5 mm on the head in frames 150-249."""
    take, rot, trans = make_take(n_frames=n_frames, noise=0.2)
    pos = take.positions.copy()
    pos[150:250, 2] += rot[150:250] @ np.array([3.0, 0.0, 4.0])
    return take.replace(positions=pos), rot, trans


@pytest.mark.parametrize("robust", [True, False])
def test_mean_shape_is_the_weighted_average_of_the_aligned_frames(robust):
    # The fixed point of generalized Procrustes with the final weights, robust or not.
    take, _, _ = slipped_take()
    st = stabilize(take, HEAD, robust=robust)
    aligned = st.to_head(take.positions[:, :6])
    mean = (st.weights[..., None] * aligned).sum(axis=0) / st.weights.sum(axis=0)[:, None]
    np.testing.assert_allclose(mean, st.reference_shape, atol=STABILIZE_CONVERGED_NOISE * st.noise)
    assert st.converged


def test_subsampled_start_reaches_the_same_solution(monkeypatch):
    take, _, _ = slipped_take(n_frames=1500)
    fast = stabilize(take, HEAD, reference_frame=700)
    monkeypatch.setattr("mocap._stabilize._START_FRAMES", 10 ** 9)   # start from every frame
    full = stabilize(take, HEAD, reference_frame=700)
    np.testing.assert_allclose(fast.take.positions, full.take.positions,
                               atol=STABILIZE_CONVERGED_NOISE * full.noise)
    np.testing.assert_allclose(fast.weights, full.weights, atol=STABILIZE_START_WEIGHTS)


def test_frames_with_fewer_than_three_head_markers_are_flagged():
    take, rot, _ = make_take()
    pos = take.positions.copy()
    pos[100:110, 1:5] = np.nan                           # two head markers left
    take = take.replace(positions=pos)
    st = stabilize(take, HEAD)
    assert (~st.valid).nonzero()[0].tolist() == list(range(100, 110))
    assert np.isnan(st.rotation[100:110]).all() and np.isnan(st.take.positions[100:110]).all()
    assert not st.interpolated.any()
    filled = stabilize(take, HEAD, invalid="interpolate")
    assert filled.interpolated[100:110].all() and not filled.valid[100:110].any()
    truth = rot @ rot[0].T
    assert rotation_error_deg(filled.rotation[100:110], truth[100:110]).max() < STABILIZE_GAP_DEG
    np.testing.assert_array_equal(filled.rotation[filled.valid], st.rotation[st.valid])
    with pytest.raises(MarkerError, match=r"'root-2': is missing in frames 101-110 "
                                          r"\(indices 100-109\): a rigid fit needs 3 visible"):
        stabilize(take, HEAD, invalid="raise")


def test_stabilized_take_keeps_labels_nan_and_filled_and_round_trips():
    take, _, _ = make_take()
    pos = take.positions.copy()
    pos[5:9, 7] = np.nan
    filled = np.zeros(take.positions.shape[:2], np.uint8)
    filled[20:30, 8] = 1
    take = take.replace(positions=pos, filled=filled)
    before = take.positions.copy()
    st = stabilize(take, HEAD)
    assert st.take.labels == take.labels and st.take.rate == take.rate
    np.testing.assert_array_equal(st.take.filled, filled)
    np.testing.assert_array_equal(np.isnan(st.take.positions), np.isnan(pos))
    np.testing.assert_allclose(st.to_world(st.take.positions), pos, atol=EXACT_MM)
    np.testing.assert_array_equal(take.positions, before)
    on_head = st.to_world(st.reference_shape)
    assert np.nanmax(np.abs(on_head - pos[:, :6])) < STABILIZE_ON_HEAD_MM


def test_per_marker_weights_change_the_fit_as_scipy_says():
    take, _, _ = make_take(noise=0.5)
    w = np.array([1.0, 2.0, 0.5, 1.0, 3.0, 1.0])
    st = stabilize(take, HEAD, reference="frame", reference_frame=0, weights=w, robust=False)
    head = take.positions[:, :6]
    cy = w @ head[77] / w.sum()
    cx = w @ head[0] / w.sum()
    rot, _ = Rotation.align_vectors(head[77] - cy, head[0] - cx, weights=w)
    np.testing.assert_allclose(st.rotation[77], rot.as_matrix(), atol=RIGID_VS_ORACLE)


@pytest.mark.parametrize("invalid", INVALID_POLICIES)
def test_all_policies_agree_on_complete_data(invalid):
    take, _, _ = make_take()
    st = stabilize(take, HEAD, invalid=invalid)
    assert st.valid.all() and not st.interpolated.any()


def _take_missing(frames, markers):
    take, _, _ = make_take(n_frames=50)
    pos = take.positions.copy()
    pos[frames, markers] = np.nan
    return take.replace(positions=pos)


@pytest.mark.parametrize("take, args, kwargs, error, match", [
    (None, (["root-1", "root-2"],), {}, InputError, "at least 3 markers"),
    (None, ("root-1",), {}, InputError, "not one string"),
    (None, (["root-1", "root-1", "root-2"],), {}, InputError, "lists a marker twice"),
    (None, (["root-1", "root-2", "nose"],), {}, MarkerError, "'nose': not in the take"),
    (None, (HEAD,), {"reference": "median"}, InputError, "reference must be one of"),
    (None, (HEAD,), {"invalid": "skip"}, InputError, "invalid must be one of"),
    (None, (HEAD,), {"reference": "frame"}, InputError, "needs reference_frame"),
    (None, (HEAD,), {"reference_frame": 50}, InputError, "below the take's 50 frames"),
    (None, (HEAD,), {"weights": np.ones(5)}, InputError, r"weights must have shape \(6,\)"),
    (None, (HEAD,), {"weights": -np.ones(6)}, InputError, "non-negative"),
    (None, (HEAD,), {"slip_threshold": 0}, InputError, "slip_threshold must be positive"),
    (None, (HEAD,), {"max_iter": 0}, InputError, "max_iter must be at least 1"),
    (None, (HEAD,), {"robust": "yes"}, InputError, "robust must be True or False"),
    ((slice(None), slice(0, 4)), (HEAD,), {}, MarkerError,
     r"'root-1': is missing in frames 1-50 \(indices 0-49\): a rigid fit needs 3 visible"),
    ((slice(None), 3), (HEAD,), {"reference": "frame", "reference_frame": 2}, MarkerError,
     r"'root-4': is missing in the reference frame 3 \(index 2\): the reference shape"),
    ((slice(3, 5), slice(0, 5)), (HEAD,), {"reference_frame": 4}, MarkerError,
     r"'root-1': is missing in the reference frame 5 \(index 4\): a rigid fit needs 3"),
])
def test_errors(take, args, kwargs, error, match):
    take = make_take(n_frames=50)[0] if take is None else _take_missing(*take)
    with pytest.raises(error, match=match):
        stabilize(take, *args, **kwargs)


def test_marker_never_seen_with_two_others_is_an_error():
    take = _take_missing(slice(None), 5)
    with pytest.raises(MarkerError, match="'root-6': is never visible together with 2 other"):
        stabilize(take, HEAD)


def test_take_must_be_a_take_and_points_must_fit():
    with pytest.raises(InputError, match="take must be a mocap.Take"):
        stabilize(np.zeros((3, 6, 3)), HEAD)
    st = stabilize(make_take(n_frames=20)[0], HEAD)
    with pytest.raises(InputError, match=r"points must have shape \(20, K, 3\) or \(K, 3\)"):
        st.to_world(np.zeros((19, 2, 3)))


def test_real_capture_head_residuals(facial_sing_take):
    take = facial_sing_take
    st = stabilize(take, HEAD)
    assert st.valid.all() and st.converged
    assert np.nanmedian(st.head_residuals) < STABILIZE_REAL_RESIDUAL_MM  # head markers ~ rigid
    assert np.ptp(st.translation, axis=0).max() > 100        # the head does move
    face = st.take.positions[:, 6:]
    # Stabilized face markers move much less than the raw ones.
    assert np.nanmedian(np.nanstd(face, axis=0)) < np.nanmedian(
        np.nanstd(take.positions[:, 6:], axis=0)) / 5
