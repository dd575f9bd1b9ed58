"""Capture simulation (mocap.synth.capture): against the dense mesh, stabilize, ezc3d."""

from __future__ import annotations

import ezc3d
import numpy as np
import pytest
from helpers import ICT_LAYOUT_TOML, jaw_open_peak_time
from scipy.spatial.transform import Rotation
from tolerances import (
    CAPTURE_FILE_MM,
    EXACT_FLOAT64,
    EXACT_MM,
    FLOAT32_REL,
    SYNTH_HEAD_EXACT,
    SYNTH_NOISE_MEAN_MM,
    SYNTH_NOISE_STD_REL,
    SYNTH_VS_DENSE_MM,
)

import mocap
from basis.artist import load_artist_basis
from mocap.errors import FileFormatError, InputError, MarkerError
from mocap.gaps import find_gaps
from mocap.mesh.layout import load_marker_layout, make_layout
from mocap.mesh.mesh import Mesh
from mocap.stabilize import stabilize
from mocap.synth.capture import CaptureTruth, load_capture_truth, simulate_capture
from mocap.synth.performance import Performance

SHAPES = ["browInnerUp_L", "browInnerUp_R", "cheekPuff_L", "cheekPuff_R", "eyeBlink_L",
          "eyeBlink_R", "jawOpen", "mouthSmile_L"]
COLUMNS = ["BrowInnerUp", "CheekPuff", "EyeBlinkLeft", "EyeBlinkRight", "JawOpen",
           "MouthSmileLeft"]
MM_PER_CM = 10.0


@pytest.fixture(scope="module")
def synth_basis(ict_neutral_path, ict_expressions_dir):
    """The ArtistBasis of the ICT expressions in SHAPES (cm)."""
    return load_artist_basis(ict_neutral_path, ict_expressions_dir, names=SHAPES, units="cm")


@pytest.fixture(scope="module")
def head(ict_markerset):
    return ict_markerset.head


@pytest.fixture(scope="module")
def performance(arkit_performance) -> Performance:
    """The columns of a real performance that drive SHAPES, 2 s around its widest jaw opening."""
    full = arkit_performance
    cols = [full.names.index(c) for c in COLUMNS]
    peak = jaw_open_peak_time(full)
    keep = np.abs(full.times - peak) <= 1.0
    return Performance(tuple(COLUMNS), full.times[keep], full.weights[keep][:, cols],
                       full.rate, path=full.path)


def _simulate(basis, performance, layout, head, **options):
    kwargs = dict(rate=100.0, noise_mm=0.0, n_gaps=0, head_rotation_deg=0.0,
                  head_translation_mm=0.0, seed=0)
    kwargs.update(options)
    return simulate_capture(basis, performance, layout, head, **kwargs)


def test_still_capture_equals_the_layout_on_the_dense_mesh(synth_basis, performance, ict_layout,
                                                           head):
    sim = _simulate(synth_basis, performance, ict_layout, head)
    truth = sim.truth
    assert truth.weights[:, SHAPES.index("jawOpen")].max() > 0.5       # a real expression
    np.testing.assert_array_equal(truth.weights[:, SHAPES.index("browInnerUp_L")],
                                  truth.weights[:, SHAPES.index("browInnerUp_R")])
    dense = ict_layout.positions(synth_basis.evaluate(truth.weights))    # (T, M, 3) cm
    rigid = [ict_layout.index(h) for h in head]
    dense[:, rigid] = ict_layout.positions(synth_basis.neutral.vertices)[rigid]
    np.testing.assert_allclose(truth.markers_head, MM_PER_CM * dense, rtol=0,
                               atol=SYNTH_VS_DENSE_MM)
    # without motion the world pose is the constant home pose
    np.testing.assert_allclose(truth.rotation, np.broadcast_to(truth.rotation[0], (len(dense),
                                                                                   3, 3)))
    world = np.einsum("ij,tmj->tmi", truth.rotation[0], truth.markers_head) + \
        truth.translation[0]
    np.testing.assert_allclose(sim.take.positions, world, atol=EXACT_MM)
    np.testing.assert_array_equal(sim.take.positions, truth.markers_world)
    assert sim.take.labels == ict_layout.labels and sim.take.rate == 100.0
    assert not sim.take.missing.any()


def test_face_markers_move_and_head_markers_do_not(synth_basis, performance, ict_layout, head):
    truth = _simulate(synth_basis, performance, ict_layout, head).truth
    travel = np.ptp(truth.markers_head, axis=0).max(axis=1)              # (M,) mm
    rigid = np.isin(ict_layout.labels, head)
    assert travel[rigid].max() == 0.0
    assert travel[ict_layout.index("chin")] > 5.0                        # the jaw opened


@pytest.mark.parametrize("seed", [0, 7])
def test_head_motion_is_rigid_and_recovered_by_stabilize(synth_basis, performance, ict_layout,
                                                         head, seed):
    deg, mm = 18.0, 40.0
    sim = _simulate(synth_basis, performance, ict_layout, head, head_rotation_deg=deg,
                    head_translation_mm=mm, head_cutoff_hz=2.0, seed=seed)
    rot, trans = sim.truth.rotation, sim.truth.translation
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=EXACT_FLOAT64)
    np.testing.assert_allclose(rot @ rot.transpose(0, 2, 1), np.broadcast_to(np.eye(3),
                                                                               rot.shape),
                               atol=EXACT_FLOAT64)
    angle = np.rad2deg(Rotation.from_matrix(rot[0].T @ rot).magnitude())
    assert deg / 4 < angle.max() <= 2 * np.sqrt(3) * deg          # moves, within its peaks
    travel = np.ptp(trans, axis=0)
    assert mm <= travel.max() and travel.max() <= 2 * mm + EXACT_MM
    st = stabilize(sim.take, head, reference="frame", reference_frame=0, robust=False)
    expected_r = rot @ rot[0].T                    # the stabilized head frame is frame 0's
    expected_t = trans - np.einsum("tij,j->ti", expected_r, trans[0])
    np.testing.assert_allclose(st.rotation, expected_r, atol=SYNTH_HEAD_EXACT)
    np.testing.assert_allclose(st.translation, expected_t, atol=SYNTH_HEAD_EXACT)
    back = np.einsum("tji,tmj->tmi", rot, sim.take.positions - trans[:, None])
    np.testing.assert_allclose(back, sim.truth.markers_head, atol=SYNTH_HEAD_EXACT)


def test_gaps_are_nan_and_noise_has_its_level(synth_basis, performance, ict_layout, head):
    n_gaps, max_frames = 150, 20
    sim = _simulate(synth_basis, performance, ict_layout, head, noise_mm=0.5, n_gaps=n_gaps,
                    seed=3, max_gap_s=max_frames / 100, head_rotation_deg=10.0,
                    head_translation_mm=20.0)
    take, truth = sim.take, sim.truth
    np.testing.assert_array_equal(take.missing, truth.missing)
    assert np.isnan(take.positions[truth.missing]).all()
    lengths = find_gaps(truth.missing).length                   # overlapping gaps merge
    assert len(lengths) <= n_gaps and truth.missing.sum() <= n_gaps * max_frames
    assert len(lengths) > n_gaps / 2 and np.median(lengths) < max_frames / 2   # mostly short
    rigid = np.isin(ict_layout.labels, head)
    assert truth.missing[:, rigid].sum(axis=1).max() <= 1                 # >= 5 head markers seen
    assert truth.missing[:, rigid].mean() < truth.missing[:, ~rigid].mean()
    error = (take.positions - truth.markers_world)[~truth.missing]
    assert error.std() == pytest.approx(0.5, rel=SYNTH_NOISE_STD_REL)
    assert abs(error.mean()) < SYNTH_NOISE_MEAN_MM


def test_seeded_and_deterministic(synth_basis, performance, ict_layout, head):
    options = dict(noise_mm=0.3, n_gaps=40, head_rotation_deg=15.0, head_translation_mm=30.0)
    a = _simulate(synth_basis, performance, ict_layout, head, seed=5, **options)
    b = _simulate(synth_basis, performance, ict_layout, head, seed=5, **options)
    c = _simulate(synth_basis, performance, ict_layout, head, seed=6, **options)
    np.testing.assert_array_equal(a.take.positions, b.take.positions)
    assert not np.array_equal(a.truth.rotation, c.truth.rotation)
    assert not np.array_equal(a.truth.missing, c.truth.missing)
    # the noise level does not change the motion or the gaps (independent streams)
    d = _simulate(synth_basis, performance, ict_layout, head, seed=5, **{**options,
                                                                         "noise_mm": 0.0})
    np.testing.assert_array_equal(a.truth.rotation, d.truth.rotation)
    np.testing.assert_array_equal(a.truth.missing, d.truth.missing)


def test_truth_round_trip(synth_basis, performance, ict_layout, head, tmp_path):
    truth = _simulate(synth_basis, performance, ict_layout, head, noise_mm=0.2, n_gaps=20,
                      head_rotation_deg=5.0, duration=0.5).truth
    truth.save(tmp_path / "truth.npz")
    back = load_capture_truth(tmp_path / "truth.npz")
    for name in ("labels", "head_markers", "shape_names", "rate", "mm_per_unit", "noise_mm",
                 "seed", "layout_name", "mesh"):
        assert getattr(back, name) == getattr(truth, name), name
    for name in ("weights", "rotation", "translation", "markers_world", "markers_head",
                 "missing"):
        np.testing.assert_array_equal(getattr(back, name), getattr(truth, name))
    assert back.n_frames == 51 and back.shape_names == tuple(SHAPES)
    assert back.mm_per_unit == MM_PER_CM and back.mesh.endswith("generic_neutral_mesh.obj")


def test_truth_file_errors(tmp_path):
    mocap.write(mocap.Take(("a",), np.zeros((2, 1, 3)), rate=10.0), tmp_path / "take.npz")
    with pytest.raises(FileFormatError, match=r"take\.npz: not a capture-truth archive"):
        load_capture_truth(tmp_path / "take.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(FileFormatError, match=r"junk\.npz: cannot read capture-truth archive"):
        load_capture_truth(tmp_path / "junk.npz")


@pytest.mark.parametrize("ext", [".c3d", ".csv"])
def test_written_capture_reads_back_with_the_same_gaps(synth_basis, performance, ict_layout, head,
                                                       tmp_path, ext):
    take = _simulate(synth_basis, performance, ict_layout, head, noise_mm=0.2, n_gaps=60,
                     head_rotation_deg=15.0, head_translation_mm=30.0, seed=2).take
    path = tmp_path / f"capture{ext}"
    mocap.write(take, path)
    back = mocap.read(path)
    assert back.labels == take.labels and back.rate == take.rate
    np.testing.assert_array_equal(back.missing, take.missing)
    np.testing.assert_allclose(back.positions, take.positions, atol=CAPTURE_FILE_MM,
                               equal_nan=True)
    if ext == ".c3d":                                        # an independent reader
        ez = ezc3d.c3d(str(path))
        points = ez["data"]["points"][:3].transpose(2, 1, 0)
        np.testing.assert_array_equal(np.isnan(points[..., 0]), take.missing)
        np.testing.assert_allclose(points, take.positions, rtol=FLOAT32_REL, equal_nan=True)
        assert tuple(ez["parameters"]["POINT"]["LABELS"]["value"]) == take.labels


def test_neutral_lead_in_holds_the_neutral_then_blends_into_the_performance(
        synth_basis, performance, ict_layout, head):
    plain = _simulate(synth_basis, performance, ict_layout, head).truth
    led = _simulate(synth_basis, performance, ict_layout, head, neutral_lead_s=0.8).truth
    n_lead, n_blend = 80, 40                       # 0.8 s at 100 Hz; the last 0.5 s, at most half
    assert led.n_frames == plain.n_frames + n_lead
    np.testing.assert_array_equal(led.weights[n_lead:], plain.weights)
    assert not led.weights[:n_lead - n_blend].any()
    driven = plain.weights[0] > 0
    assert driven.any() and not led.weights[n_lead - n_blend:n_lead, ~driven].any()
    fraction = led.weights[n_lead - n_blend:n_lead, driven] / plain.weights[0, driven]
    np.testing.assert_allclose(fraction, fraction[:, :1] * np.ones(driven.sum()))  # alike
    ramp = fraction[:, 0]
    assert 0 < ramp[0] < 0.01 and 0.99 < ramp[-1] < 1 and (np.diff(ramp) > 0).all()
    # the hold is the neutral face: the layout on the neutral mesh
    np.testing.assert_allclose(led.markers_head[:n_lead - n_blend],
                               np.broadcast_to(MM_PER_CM * ict_layout.positions(
                                   synth_basis.neutral.vertices), (n_lead - n_blend,
                                                              ict_layout.n_markers, 3)),
                               rtol=0, atol=SYNTH_VS_DENSE_MM)
    with pytest.raises(InputError, match=r"neutral_lead_s must be >= 0, got -1.0"):
        _simulate(synth_basis, performance, ict_layout, head, neutral_lead_s=-1.0)


def test_simulation_errors(synth_basis, performance, ict_layout, head):
    other = Mesh(synth_basis.neutral.vertices, synth_basis.neutral.faces)          # units unknown
    tiny = make_layout(_triangle(), {"a": {"vertex": 0}, "b": {"vertex": 1},
                                     "c": {"vertex": 2}})
    with pytest.raises(InputError, match=r"layout '' was made for a mesh of 3 vertices"):
        simulate_capture(synth_basis, performance, tiny, ["a", "b", "c"])
    with pytest.raises(MarkerError, match=r"marker 'nose-top': not in layout"):
        simulate_capture(synth_basis, performance, ict_layout, ["nose-top", "head-1", "head-2"])
    unitless = load_marker_layout(ICT_LAYOUT_TOML, other)
    with pytest.raises(InputError, match=r"units of layout 'ict-layout' .* are unknown"):
        simulate_capture(synth_basis, performance, unitless, head)
    with pytest.raises(InputError, match=r"n_gaps must be at least 0"):
        simulate_capture(synth_basis, performance, ict_layout, head, n_gaps=-1)
    with pytest.raises(InputError, match=r"noise_mm, head_rotation_deg and .* must be >= 0"):
        simulate_capture(synth_basis, performance, ict_layout, head, noise_mm=-0.1)
    unknown = Performance(("Foo",), [0.0, 1.0], [[0.0], [1.0]], rate=1.0, path="foo.csv")
    with pytest.raises(InputError, match=r"foo\.csv: none of its weight columns \(Foo\)"):
        simulate_capture(synth_basis, unknown, ict_layout, head)
    with pytest.raises(InputError, match=r"basis must have names, neutral and displacements"):
        simulate_capture(object(), performance, ict_layout, head)


def _triangle():
    return Mesh(np.eye(3), np.array([[0, 1, 2]]), units="cm")


def test_truth_checks_shapes():
    with pytest.raises(InputError, match=r"truth rotation must have shape \(2, 3, 3\)"):
        CaptureTruth(labels=("a",), head_markers=(), shape_names=("s",),
                     weights=np.zeros((2, 1)), rotation=np.zeros((3, 3, 3)),
                     translation=np.zeros((2, 3)), markers_world=np.zeros((2, 1, 3)),
                     markers_head=np.zeros((2, 1, 3)), missing=np.zeros((2, 1), bool),
                     rate=1.0, mm_per_unit=10.0, noise_mm=0.0, seed=0)
