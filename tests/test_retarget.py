"""Retargeting stage (mocap.retarget.retargeting) and ``mocap2mesh retarget``."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from helpers import ICT_MARKERSET_TOML, jaw_open_peak_time
from scipy.spatial.transform import Rotation
from tolerances import (
    EXACT_FLOAT64,
    FLOAT32_REL,
    OBJ_TEXT,
    RBF_AFFINE_EXACT,
    RETARGET_CLI_SIM_REL,
    RETARGET_EXACT,
    RETARGET_HEAD_ALIGN,
)

import mocap
from fit.cli.main import main
from mocap.bind import Binding, bind_take
from mocap.errors import InputError, MarkerError
from mocap.markerset import MarkerSet
from mocap.mesh.mesh import Mesh, load_mesh
from mocap.neutral import hold_window, neutral_pose
from mocap.retarget.archive import CONTENTS, save_npz, save_obj_sequence
from mocap.retarget.retargeting import (
    RetargetOptions,
    align_head_frame,
    build_retarget_operator,
    marker_displacements,
    retarget,
)
from mocap.synth.capture import simulate_capture
from mocap.take import Take

MM_PER_CM = 10.0


# -- a small synthetic face: a bumpy grid, markers on vertices ---------------------------

def _grid_mesh(n=21, size=10.0) -> Mesh:
    x, y = np.meshgrid(np.linspace(-size / 2, size / 2, n), np.linspace(-size / 2, size / 2, n))
    z = 1.5 * np.exp(-(x ** 2 + y ** 2) / 20.0) + 0.1 * x
    vertices = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    ids = np.arange(n * n).reshape(n, n)
    a, b, c, d = ids[:-1, :-1].ravel(), ids[:-1, 1:].ravel(), ids[1:, 1:].ravel(), ids[1:, :-1].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return Mesh(vertices, faces)


GRID = _grid_mesh()
#: Marker vertices of the grid (a 5 x 5 lattice, the bottom row a "lower lip").
MARKER_VERTICES = np.array([21 * i + j for i in range(1, 21, 4) for j in range(1, 21, 4)])
FACE_LABELS = tuple(f"m{i}" for i in range(len(MARKER_VERTICES)))
HEAD_LABELS = ("h0", "h1", "h2")
MARKERSET = MarkerSet("grid", HEAD_LABELS, {"lower_lip": FACE_LABELS[:5],
                                            "upper_lip": FACE_LABELS[5:10],
                                            "other": FACE_LABELS[10:]})
SCALE = 0.1                                        # mesh units per mm
ROTATION = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
TRANSLATION = np.array([1.0, -2.0, 3.0])


def _vertex_binding(mesh: Mesh, labels, vertex_ids) -> Binding:
    """A binding whose markers sit exactly on vertices (barycentric (1, 0, 0))."""
    vertex_ids = np.asarray(vertex_ids)
    face_ids = np.array([np.flatnonzero(mesh.faces[:, 0] == v)[0] for v in vertex_ids])
    bary = np.tile([1.0, 0.0, 0.0], (len(vertex_ids), 1))
    return Binding(labels=tuple(labels), scale=SCALE, rotation=ROTATION,
                   translation=TRANSLATION, face_ids=face_ids,
                   vertex_ids=mesh.faces[face_ids], barycentric=bary,
                   distances=np.zeros(len(vertex_ids)), rms=0.0, skin_offset=0.0,
                   n_landmarks=3, n_iterations=0, converged=True, message="by hand")


#: Head markers are bound too (on three far vertices); they must never drive the face.
BINDING = _vertex_binding(GRID, FACE_LABELS + HEAD_LABELS,
                          np.concatenate([MARKER_VERTICES, [0, 19, 418]]))


def _take_from_mesh_displacements(d_mesh, *, first_frame=1) -> Take:
    """A head-frame take (mm) whose markers move by `d_mesh` (T, M, 3) mesh units."""
    neutral_mm = BINDING.to_capture(BINDING.marker_points(GRID.vertices))
    positions = np.repeat(neutral_mm[None], len(d_mesh), axis=0)
    positions[:, :len(FACE_LABELS)] += d_mesh @ ROTATION / SCALE
    return Take(BINDING.labels, positions, rate=30.0, first_frame=first_frame)


# -- marker_displacements ------------------------------------------------------------------

def test_marker_displacements_match_a_hand_computation():
    rng = np.random.default_rng(0)
    positions = rng.normal(scale=50.0, size=(6, 4, 3))
    positions[4, 2] = np.nan
    take = Take(BINDING.labels[:4], positions, rate=100.0)
    extra = Rotation.from_rotvec([0.0, 0.4, 0.1]).as_matrix()
    got = marker_displacements(take, BINDING, neutral_frame=1, rotation=extra)
    expected = np.full_like(positions, np.nan)
    for t in range(6):                                   # brute force, marker by marker
        for m in range(4):
            expected[t, m] = SCALE * ROTATION @ extra @ (positions[t, m] - positions[1, m])
    np.testing.assert_allclose(got, expected, rtol=0, atol=EXACT_FLOAT64)
    assert np.isnan(got[4, 2]).all() and np.isfinite(np.delete(got, 2, axis=1)).all()
    np.testing.assert_array_equal(take.positions, positions)        # input untouched


def test_marker_displacements_from_the_mean_of_a_neutral_window():
    rng = np.random.default_rng(1)
    positions = rng.normal(scale=50.0, size=(8, 3, 3))
    take = Take(BINDING.labels[:3], positions, rate=100.0)
    for frame, window, frames in ((3, 5, [1, 2, 3, 4, 5]), (0, 5, [0, 1, 2]), (7, 3, [6, 7])):
        got = marker_displacements(take, BINDING, neutral_frame=frame, neutral_window=window)
        rest = positions[frames].mean(axis=0)                       # cut at the ends
        np.testing.assert_allclose(got, SCALE * (positions - rest) @ ROTATION.T,
                                   atol=EXACT_FLOAT64)
    positions[5, 1] = np.nan
    with pytest.raises(MarkerError,
                       match=r"'m1'.*in the 5 frames around the neutral frame \d+ \(index 3\)"):
        marker_displacements(Take(BINDING.labels[:3], positions, rate=100.0), BINDING,
                             neutral_frame=3, neutral_window=5)
    with pytest.raises(InputError, match="neutral_window must be at least 1"):
        marker_displacements(take, BINDING, neutral_frame=3, neutral_window=0)


def test_marker_displacements_rejects_a_missing_neutral_marker():
    positions = np.zeros((3, 2, 3))
    positions[2, 1] = np.nan
    take = Take(BINDING.labels[:2], positions, rate=100.0, first_frame=10)
    with pytest.raises(MarkerError, match=r"'m1'.*neutral frame 12 \(index 2\)"):
        marker_displacements(take, BINDING, neutral_frame=2)


def test_marker_displacements_rejects_an_unbound_marker():
    take = Take(("m0", "stranger"), np.zeros((2, 2, 3)), rate=100.0)
    with pytest.raises(MarkerError, match=r"'stranger'.*not in the binding"):
        marker_displacements(take, BINDING, neutral_frame=0)


def test_marker_displacements_rejects_a_reflection():
    take = Take(BINDING.labels[:2], np.zeros((2, 2, 3)), rate=100.0)
    with pytest.raises(InputError, match="proper rotation"):
        marker_displacements(take, BINDING, neutral_frame=0, rotation=-np.eye(3))


def test_align_head_frame_recovers_the_capture_rotation():
    # a binding made on a raw frame: the take's head frame is rotated away from it
    turn = Rotation.from_rotvec([0.1, 0.7, -0.2]).as_matrix()
    take = _take_from_mesh_displacements(np.zeros((2, len(FACE_LABELS), 3)))
    head = take.replace(positions=take.positions @ turn)          # p_head = turn^T p
    np.testing.assert_allclose(align_head_frame(head, BINDING, GRID, neutral_frame=0), turn,
                               atol=RETARGET_HEAD_ALIGN)


# -- the operator ------------------------------------------------------------------------

EXACT_OPTIONS = {
    "tps": RetargetOptions(),
    "gaussian": RetargetOptions(kernel="gaussian", epsilon=0.4),
    "wendland": RetargetOptions(kernel="wendland_c2", epsilon=0.15),
    "tps-regions": RetargetOptions(use_regions=True, region_width=0.5),
}


@pytest.mark.parametrize("name", list(EXACT_OPTIONS))
def test_operator_reproduces_marker_displacements_at_the_markers(name):
    op = build_retarget_operator(BINDING, GRID, MARKERSET, None, EXACT_OPTIONS[name])
    assert op.n_centers == len(FACE_LABELS) and op.labels == FACE_LABELS  # head excluded
    d = np.random.default_rng(1).normal(size=(4, len(FACE_LABELS), 3))
    xi = op.apply(d, dtype=np.float64)
    np.testing.assert_allclose(xi[:, MARKER_VERTICES], d, rtol=0,
                               atol=RETARGET_EXACT * np.abs(d).max())


def test_operator_refuses_a_head_marker():
    with pytest.raises(MarkerError, match=r"'h0'.*head marker"):
        build_retarget_operator(BINDING, GRID, MARKERSET, FACE_LABELS + ("h0",))


@pytest.mark.parametrize("distance", ["euclidean", "geodesic"])
@pytest.mark.parametrize("use_regions", [False, True])
def test_retarget_reproduces_an_affine_field(distance, use_regions):
    rng = np.random.default_rng(2)
    n_frames = 5
    a = 0.05 * rng.normal(size=(n_frames, 3, 3))
    b = 0.2 * rng.normal(size=(n_frames, 1, 3))
    centers = GRID.vertices[MARKER_VERTICES]
    moved = centers @ a.transpose(0, 2, 1) + b
    take = _take_from_mesh_displacements(np.concatenate([np.zeros_like(moved[:1]), moved]))
    options = RetargetOptions(kernel="thin_plate_spline", degree=1, distance=distance,
                              use_regions=use_regions)
    result = retarget(take, BINDING, GRID, MARKERSET, options=options, neutral_frame=0)
    xi = result.vertex_displacements(dtype=np.float64)[1:]
    np.testing.assert_allclose(xi, GRID.vertices @ a.transpose(0, 2, 1) + b, rtol=0,
                               atol=RBF_AFFINE_EXACT)
    np.testing.assert_allclose(result.rotation, np.eye(3), atol=EXACT_FLOAT64)


def test_retarget_names_the_first_missing_marker_and_frame():
    positions = np.array(_take_from_mesh_displacements(np.zeros((4, len(FACE_LABELS), 3)))
                         .positions)
    positions[2:, 7] = np.nan
    take = Take(BINDING.labels, positions, rate=30.0, first_frame=100)
    with pytest.raises(MarkerError, match=r"'m7'.*frame 102 \(index 2; 2 missing"):
        retarget(take, BINDING, GRID, MARKERSET)


# -- outputs -------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def small_result():
    d = np.random.default_rng(3).normal(scale=0.1, size=(7, len(FACE_LABELS), 3))
    take = _take_from_mesh_displacements(np.concatenate([np.zeros_like(d[:1]), d]),
                                         first_frame=98)
    return retarget(take, BINDING, GRID, MARKERSET, neutral_frame=0,
                    options=RetargetOptions(chunk_frames=3))


@pytest.mark.parametrize("content", CONTENTS)
def test_npz_output_reads_back(small_result, tmp_path, content):
    path = tmp_path / "out.npz"
    save_npz(small_result, path, content=content)
    expected = small_result.vertex_displacements(dtype=np.float64)
    if content == "vertices":
        expected = expected + GRID.vertices
    with np.load(path) as data:
        assert data[content].dtype == np.float32 and data[content].shape == expected.shape
        np.testing.assert_allclose(data[content], expected, rtol=0,
                                   atol=FLOAT32_REL * np.abs(GRID.vertices).max())
        np.testing.assert_array_equal(data["faces"], GRID.faces)
        np.testing.assert_allclose(data["neutral"], GRID.vertices, rtol=FLOAT32_REL)
        assert float(data["rate"]) == 30.0 and int(data["first_frame"]) == 98
        assert tuple(data["labels"]) == FACE_LABELS


def test_obj_sequence_reads_back(small_result, tmp_path):
    paths = save_obj_sequence(small_result, tmp_path / "seq")
    assert [p.name for p in paths] == [f"frame_{n:04d}.obj" for n in range(98, 106)]
    expected = small_result.vertex_displacements(dtype=np.float64) + GRID.vertices
    for path, vertices in zip(paths, expected):
        mesh = load_mesh(path)
        np.testing.assert_allclose(mesh.vertices, vertices, rtol=OBJ_TEXT, atol=OBJ_TEXT)
        np.testing.assert_array_equal(mesh.faces, GRID.faces)


def test_obj_sequence_refuses_a_file_as_directory(small_result, tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="is not a directory"):
        save_obj_sequence(small_result, tmp_path / "file")


def test_options_validate_choices():
    with pytest.raises(InputError, match="kernel must be one of"):
        RetargetOptions(kernel="sinc")


# -- the command line on a simulated ICT capture -------------------------------------------

@pytest.fixture(scope="module")
def ict_capture(ict_basis, ict_markerset, ict_layout, ict_landmarks, ict_neutral_path,
                arkit_performance, tmp_path_factory):
    """A 1.2 s simulated capture (30 Hz, 0.2 mm noise, head motion, gaps) and its binding."""
    basis, markerset, layout = ict_basis, ict_markerset, ict_layout
    full = arkit_performance
    peak = jaw_open_peak_time(full)
    with pytest.warns(UserWarning, match="match no shape"):
        sim = simulate_capture(basis, full, layout, markerset.head, rate=30.0,
                               start=peak - 1.0, duration=1.2, noise_mm=0.2, n_gaps=4,
                               max_gap_s=0.1, seed=5)
    folder = tmp_path_factory.mktemp("retarget")
    capture, binding_path = folder / "capture.c3d", folder / "binding.json"
    mocap.write(sim.take, capture)
    with warnings.catch_warnings():    # an expressive clip: some markers sit off the mesh
        warnings.simplefilter("ignore")
        binding = bind_take(mocap.read(capture), markerset, basis.neutral, ict_landmarks,
                            skin_offset=2.0, head_frame=True).binding
    binding.save(binding_path)
    return basis, sim, capture, binding_path, ict_neutral_path


def _retarget_args(ict_capture, output, *extra, binding=None):
    _, _, capture, binding_path, mesh = ict_capture
    return ["retarget", str(capture), "--markerset", str(ICT_MARKERSET_TOML), "--mesh", str(mesh),
            "--binding", str(binding or binding_path), "-o", str(output), *extra]


def test_cli_retargets_a_simulated_capture(ict_capture, ict_layout, ict_markerset, tmp_path):
    basis, sim, *_ = ict_capture
    output = tmp_path / "face.npz"
    # --neutral-frame takes the capture's frame numbers: 1 is the first frame
    assert main(_retarget_args(ict_capture, output, "--neutral-frame", "1")) == 0
    with np.load(output) as data:
        moved = data["vertices"].astype(np.float64) - basis.neutral.vertices
    layout = ict_layout
    face = [layout.index(x) for x in ict_markerset.face_markers]
    # the marker points (on the skin) of the retargeted and of the true mesh, frame 0 as rest
    truth = layout.positions(basis.evaluate(sim.truth.weights), offset=False)[:, face]
    truth -= truth[0]
    got = layout.positions(basis.neutral.vertices + moved, offset=False)[:, face] \
        - layout.positions(basis.neutral.vertices, offset=False)[face]
    rms_error = np.sqrt(np.mean(np.sum((got - truth) ** 2, axis=-1)))
    rms_motion = np.sqrt(np.mean(np.sum(truth ** 2, axis=-1)))
    print(f"CLI retarget at the markers: rms error {MM_PER_CM * rms_error:.3f} mm, rms "
          f"motion {MM_PER_CM * rms_motion:.3f} mm")
    assert rms_motion * MM_PER_CM > 1.0                       # the clip does move
    assert rms_error < RETARGET_CLI_SIM_REL * rms_motion


def test_cli_writes_an_obj_sequence(ict_capture, tmp_path):
    _, sim, *_ = ict_capture
    output = tmp_path / "seq"
    assert main(_retarget_args(ict_capture, output, "--kernel", "gaussian", "--epsilon",
                               "0.5", "--regions")) == 0
    assert len(list(output.glob("frame_*.obj"))) == sim.take.n_frames


def test_cli_fails_on_gaps_without_filling(ict_capture, tmp_path, capsys):
    assert ict_capture[1].truth.missing.any()
    assert main(_retarget_args(ict_capture, tmp_path / "x.npz", "--fill", "none")) == 1
    err = capsys.readouterr().err
    assert "is missing (NaN) in frame" in err and "fill gaps" in err


def test_cli_fails_on_a_neutral_frame_beyond_the_take(ict_capture, tmp_path, capsys):
    assert main(_retarget_args(ict_capture, tmp_path / "x.npz", "--neutral-frame",
                               "100000")) == 1
    assert "--neutral-frame 100000 is not a frame of the take" in capsys.readouterr().err


def test_cli_fails_on_a_binding_without_a_face_marker(ict_capture, tmp_path, capsys):
    doc = json.loads(Path(ict_capture[3]).read_text())
    i = doc["labels"].index("chin")
    for key in ("labels", "face_ids", "vertex_ids", "barycentric", "distances_mm"):
        del doc[key][i]
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    assert main(_retarget_args(ict_capture, tmp_path / "x.npz", binding=bad)) == 1
    assert "marker 'chin': is not in the binding" in capsys.readouterr().err


def test_cli_fails_on_a_missing_binding_file(ict_capture, tmp_path, capsys):
    missing = tmp_path / "nope.json"
    assert main(_retarget_args(ict_capture, tmp_path / "x.npz", binding=missing)) == 1
    assert f"{missing}: cannot read binding" in capsys.readouterr().err


def test_neutral_pose_is_the_window_mean_and_checks_its_arguments():
    rng = np.random.default_rng(3)
    positions = rng.normal(size=(20, 4, 3))
    np.testing.assert_allclose(neutral_pose(positions, 10, 5), positions[8:13].mean(axis=0))
    np.testing.assert_allclose(neutral_pose(positions, 1, 5), positions[0:4].mean(axis=0))
    np.testing.assert_array_equal(neutral_pose(positions, 19), positions[19])
    with pytest.raises(InputError, match=r"neutral frame index 20 is beyond the take's 20 frames"):
        neutral_pose(positions, 20)
    with pytest.raises(InputError, match=r"neutral_window must be at least 1, got 0"):
        neutral_pose(positions, 3, 0)
    with pytest.raises(InputError, match=r"positions must have shape \(n_frames, n_markers, "
                                         r"3\), got \(20, 12\)"):
        neutral_pose(positions.reshape(20, 12), 3)


def test_bind_capture_names_a_frame_of_no_kind(ict_capture, ict_markerset, ict_landmarks):
    basis, sim = ict_capture[:2]
    with pytest.raises(InputError, match=r"frame must be an integer, got 'still'"):
        bind_take(sim.take, ict_markerset, basis.neutral, ict_landmarks, frame="still")


def test_cli_hold_measures_displacements_from_the_mean_of_the_hold(ict_capture, ict_markerset,
                                                                   ict_layout, arkit_performance,
                                                                   tmp_path):
    """``--neutral-frame hold``: the rest pose is the mean of the hold window, not one frame.

    Oracle: arithmetic. Displacements from a window's mean average to zero
    over that window, and no single frame is the rest pose (with one noisy
    frame as the rest pose, that frame's displacements would be exactly 0).
    """
    basis, _, _, binding_path, mesh = ict_capture
    markerset, layout = ict_markerset, ict_layout
    full = arkit_performance
    with pytest.warns(UserWarning, match="match no shape"):
        sim = simulate_capture(basis, full, layout, markerset.head, rate=30.0, duration=0.6,
                               noise_mm=0.2, n_gaps=0, neutral_lead_s=1.0, seed=7)
    capture = tmp_path / "held.c3d"
    mocap.write(sim.take, capture)
    output = tmp_path / "held.npz"
    assert main(["retarget", str(capture), "--markerset", str(ICT_MARKERSET_TOML), "--mesh",
                 str(mesh), "--binding", str(binding_path), "-o", str(output),
                 "--neutral-frame", "hold", "--content", "displacements"]) == 0
    with np.load(output) as data:
        moved = data["marker_displacements"].astype(np.float64)
    window = hold_window(30.0)
    means = np.abs(np.stack([moved[s:s + window].mean(axis=0)
                             for s in range(len(moved) - window + 1)])).max(axis=(1, 2))
    start = int(np.argmin(means))
    assert means[start] < FLOAT32_REL                     # float32 storage
    assert start + window <= 30                           # inside the 1 s lead at 30 Hz
    assert np.abs(moved).max(axis=(1, 2)).min() > 1e-3    # no frame is the rest pose
