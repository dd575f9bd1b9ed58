"""The generated demo session: face, muscle basis, performance, markers, files."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial.transform import Rotation
from tolerances import (
    DEMO_CAPTURE_MM,
    DEMO_LAYOUT_MM,
    DEMO_NEUTRAL_MM,
    DEMO_SHAPES_MM,
    DEMO_SHAPES_SPAN_REL,
    EXACT_FLOAT64,
    EXACT_MM,
    MESH_EXACT,
    OBJ_TEXT,
)

import mocap
from basis.artist import load_artist_basis
from basis.basis_io import load_basis
from fit.demo import SESSION_FILES, make_demo_session
from fit.demo.muscles import JAW, MUSCLES, UPPER_FACE
from fit.demo.performance import HIDDEN, DemoPerformance
from mocap.anatomy import MASKLE_POINTS
from mocap.errors import InputError
from mocap.markerset import load_markerset
from mocap.mesh.landmarks import load_mesh_landmarks
from mocap.mesh.layout import load_marker_layout
from mocap.mesh.mesh import boundary_loops, degenerate_faces, face_normals, load_mesh

SECONDS, RATE, SEED = 4.0, 60.0, 3


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    return make_demo_session(tmp_path_factory.mktemp("demo"), seed=SEED, seconds=SECONDS,
                             rate=RATE)


@pytest.fixture(scope="module")
def lips(session):
    """Upper and lower chains of the mouth loop, found from the mesh alone."""
    v = session.face.mesh.vertices
    loops = boundary_loops(session.face.mesh)
    centres = [v[loop, :2].mean(axis=0) for loop in loops[1:]]
    mouth = loops[1 + int(np.argmin([c[1] for c in centres]))]   # the lowest hole
    ends = sorted(np.argsort(v[mouth, 0])[[0, -1]])
    chain_a, chain_b = mouth[ends[0] + 1:ends[1]], np.r_[mouth[ends[1] + 1:], mouth[:ends[0]]]
    upper, lower = sorted((chain_a, chain_b), key=lambda c: -v[c, 1].mean())
    return upper, lower


def _edges(faces):
    return np.unique(np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)


def test_face_mesh_is_one_clean_surface_with_four_openings(session):
    mesh = session.face.mesh
    assert mesh.n_vertices >= 5000 and mesh.units == "mm"
    loops = boundary_loops(mesh)
    assert len(loops) == 4
    edges = _edges(mesh.faces)
    graph = sp.coo_matrix((np.ones(len(edges)), edges.T), shape=(mesh.n_vertices,) * 2)
    assert connected_components(graph, directed=False)[0] == 1
    assert len(degenerate_faces(mesh.vertices, mesh.faces)) == 0
    assert np.all(face_normals(mesh.vertices, mesh.faces)[:, 2] > 0)     # facing +z
    assert len(np.unique(mesh.faces)) == mesh.n_vertices                 # no stray vertex


def test_lips_are_not_connected(session, lips):
    upper, lower = lips
    edges = _edges(session.face.mesh.faces)
    across = np.isin(edges[:, 0], upper) & np.isin(edges[:, 1], lower) \
        | np.isin(edges[:, 0], lower) & np.isin(edges[:, 1], upper)
    assert len(upper) > 10 and len(lower) > 10 and not across.any()
    faces = session.face.mesh.faces
    assert not np.any(np.isin(faces, upper).any(axis=1) & np.isin(faces, lower).any(axis=1))


@pytest.mark.parametrize("name", MUSCLES)
def test_every_shape_is_localized_and_mm_sized(session, name, lips):
    v = session.face.mesh.vertices
    d = np.linalg.norm(session.basis.displacements[session.basis.index(name)], axis=1)
    assert 3.0 < d.max() < 35.0
    if name in UPPER_FACE:
        assert np.all(d[v[:, 1] < 5.0] == 0)           # nose, cheeks, both lips, chin
        assert np.all(d[np.concatenate(lips)] == 0)
    else:
        assert np.all(d[v[:, 1] > 25.0] == 0)          # eyes, brows, forehead
    head = np.unique(session.layout.vertex_ids[:len(session.head_markers)])
    assert np.all(d[head] == 0)


@pytest.mark.parametrize("name, moved, still", [
    ("jaw_open", 1, 0), ("mentalis", 1, 0), ("depressor_labii_inferioris", 1, 0),
    ("levator_labii_superioris_L", 0, 1), ("levator_labii_superioris_R", 0, 1)])
def test_lip_shapes_move_one_lip_only(session, lips, name, moved, still):
    v = session.face.mesh.vertices
    d = np.linalg.norm(session.basis.displacements[session.basis.index(name)], axis=1)
    central = [chain[np.abs(v[chain, 0]) < 12.0] for chain in lips]
    assert np.all(d[central[still]] == 0)
    assert d[central[moved]].max() > 1.0


def test_hidden_shapes_spare_the_head_markers(session):
    head = np.unique(session.layout.vertex_ids[:len(session.head_markers)])
    assert np.all(session.truth_basis.displacements[:, head] == 0)


def test_shapes_do_what_their_muscles_do(session, lips):
    b = session.basis
    lm = session.face.landmarks
    brow = lm["brow_mid_left"]
    assert b.displacements[b.index("frontalis_outer_L"), brow, 1] > 3.0       # brow up
    assert b.displacements[b.index("corrugator_L"), lm["brow_inner_left"], 1] < -1.0
    corner = lm["mouth_corner_left"]
    smile = b.displacements[b.index("zygomaticus_major_L"), corner]
    assert smile[0] > 2.0 and smile[1] > 4.0                                  # up and out
    chin = b.displacements[b.index("jaw_open"), lm["chin"]]
    assert chin[1] < -10.0


def test_jaw_follows_a_true_rotation(session, lips):
    """truth weights give the rotated lower lip exactly (scipy oracle) at any opening."""
    n = len(MUSCLES)
    for a in (0.3, 0.7, 1.0):
        act = np.zeros((1, n))
        act[0, MUSCLES.index("jaw_open")] = a
        perf = DemoPerformance(act, np.zeros((1, len(HIDDEN) - 1)), 60.0)
        moved = session.truth_basis.evaluate(perf.truth_weights()[0])
        lower = lips[1][np.abs(session.face.mesh.vertices[lips[1], 0]) < 10.0]
        rot = Rotation.from_rotvec(np.deg2rad(JAW["degrees"]) * a * np.array(JAW["axis"]))
        pivot = np.array(JAW["pivot"])
        expected = rot.apply(session.face.mesh.vertices[lower] - pivot) + pivot
        np.testing.assert_allclose(moved[lower], expected, atol=MESH_EXACT)
        if a == 1.0:   # full opening is the artist's shape
            np.testing.assert_allclose(moved - session.face.mesh.vertices,
                                       session.basis.displacements[MUSCLES.index("jaw_open")],
                                       atol=EXACT_FLOAT64)


def _residual(basis_disp, displacements):
    """Relative least-squares residual of displacements (K, N, 3) on shapes (n, N, 3)."""
    a = basis_disp.reshape(len(basis_disp), -1).T
    b = displacements.reshape(len(displacements), -1).T
    coef = np.linalg.lstsq(a, b, rcond=None)[0]
    return np.linalg.norm(a @ coef - b) / np.linalg.norm(b)


def test_performance_is_outside_the_basis_span_but_the_shapes_are_exact(session):
    frames = np.arange(0, session.performance.n_frames, 5)
    weights = session.performance.truth_weights()[frames]
    true = session.truth_basis.evaluate(weights) - session.face.mesh.vertices
    assert _residual(session.basis.displacements, true) > 0.02
    assert _residual(session.basis.displacements,
                     session.basis.displacements) < DEMO_SHAPES_SPAN_REL
    hidden = session.truth_basis.displacements[len(MUSCLES):]
    for shape in hidden:
        assert _residual(session.basis.displacements, shape[None]) > 0.3


def test_performance_is_smooth_and_lively(session):
    perf = session.performance
    assert perf.activations.shape == (int(SECONDS * RATE), len(MUSCLES))
    for arr in (perf.activations, perf.hidden):
        assert arr.min() >= 0 and arr.max() <= 1
        assert np.abs(np.diff(arr, axis=0)).max() < 0.3     # no jumps between frames at 60 Hz
    assert perf.activations[:, MUSCLES.index("jaw_open")].max() > 0.3
    assert perf.hidden[:, 0].max() > 0.5                      # at least one blink


def test_files_load_with_the_project_readers(session):
    paths = session.paths
    assert set(paths) == set(SESSION_FILES) and all(p.exists() for p in paths.values())
    mesh = load_mesh(paths["neutral"])
    np.testing.assert_allclose(mesh.vertices, session.face.mesh.vertices, rtol=OBJ_TEXT,
                               atol=DEMO_NEUTRAL_MM)
    assert np.array_equal(mesh.faces, session.face.mesh.faces)
    for basis in (load_artist_basis(paths["neutral"], paths["shapes"], names=MUSCLES),
                  load_basis(paths["shapes"])):
        assert basis.names == MUSCLES
        np.testing.assert_allclose(basis.displacements, session.basis.displacements,
                                   atol=DEMO_SHAPES_MM)
    landmarks = load_mesh_landmarks(paths["landmarks"], mesh)
    assert landmarks == session.face.landmarks
    assert set(MASKLE_POINTS) | {"nose_tip", "chin", "brow_inner_left", "brow_outer_right"} \
        <= set(landmarks)
    layout = load_marker_layout(paths["layout"], mesh)
    np.testing.assert_allclose(layout.positions(mesh.vertices),
                               session.layout.positions(session.face.mesh.vertices),
                               atol=DEMO_LAYOUT_MM)
    markerset = load_markerset(paths["markerset"])
    assert set(markerset.markers) == set(layout.labels)
    assert markerset.head == session.head_markers and 4 <= len(markerset.head) <= 7
    assert 40 <= len(markerset.face_markers) <= 66
    take = mocap.read(paths["capture"])
    assert take.labels == layout.labels and take.rate == pytest.approx(RATE)
    np.testing.assert_allclose(take.positions, session.capture.take.positions,
                               atol=DEMO_CAPTURE_MM)
    with np.load(paths["truth"]) as truth:
        assert tuple(truth["shape_names"]) == MUSCLES
        np.testing.assert_array_equal(truth["weights"], session.performance.activations)
        seen = ~truth["missing"]
        noise = take.positions[seen] - truth["markers_world"][seen]
        assert np.isnan(take.positions[~seen]).all() and (~seen).any()
        assert 0.1 < noise.std() < 0.3                              # 0.2 mm noise
        world = np.einsum("tij,tmj->tmi", truth["rotation"], truth["markers_head"]) \
            + truth["translation"][:, None]
        np.testing.assert_allclose(world, truth["markers_world"], atol=EXACT_MM)


def test_landmarks_sit_where_their_names_say(session, lips):
    v, lm = session.face.mesh.vertices, session.face.landmarks
    assert v[lm["mouth_corner_left"], 0] > 20 and v[lm["mouth_corner_right"], 0] < -20
    assert lm["upper_lip_bottom"] in lips[0] and lm["lower_lip_top"] in lips[1]
    assert v[lm["upper_lip_top"], 1] > v[lm["upper_lip_bottom"], 1] \
        > v[lm["lower_lip_top"], 1] > v[lm["lower_lip_bottom"], 1]
    for side in ("left", "right"):
        assert abs(v[lm[f"eye_inner_{side}"], 0]) < abs(v[lm[f"eye_outer_{side}"], 0])
    assert np.linalg.norm(v[lm["nose_tip"]] - v[np.argmax(v[:, 2])]) < 3.0


def test_lip_markers_lie_on_their_side_of_the_slit(session, lips):
    markerset = load_markerset(session.paths["markerset"])
    layout = session.layout
    skin = layout.positions(session.face.mesh.vertices, offset=False)
    v = session.face.mesh.vertices
    for region, chain, sign in (("upper_lip", lips[0], 1), ("lower_lip", lips[1], -1)):
        order = np.argsort(v[chain, 0])
        for label in markerset.regions[region]:
            x, y = skin[layout.index(label), :2]
            edge = np.interp(x, v[chain[order], 0], v[chain[order], 1])
            assert sign * (y - edge) > 1.0, label


def test_same_seed_same_session_other_seed_other_performance(session, tmp_path):
    again = make_demo_session(tmp_path / "a", seed=SEED, seconds=SECONDS, rate=RATE)
    np.testing.assert_array_equal(again.face.mesh.vertices, session.face.mesh.vertices)
    np.testing.assert_array_equal(again.basis.displacements, session.basis.displacements)
    np.testing.assert_array_equal(again.performance.activations, session.performance.activations)
    np.testing.assert_array_equal(again.capture.take.positions, session.capture.take.positions)
    other = make_demo_session(tmp_path / "b", seed=SEED + 1, seconds=SECONDS, rate=RATE)
    assert not np.array_equal(other.performance.activations, session.performance.activations)


@pytest.mark.parametrize("option, value, match", [
    ("seed", -1, "seed must be at least 0"), ("seconds", 0.0, "seconds must be positive"),
    ("rate", "fast", "rate must be a number"), ("n_gaps", 1.5, "n_gaps must be an integer")])
def test_bad_options_are_rejected(tmp_path, option, value, match):
    with pytest.raises(InputError, match=match):
        make_demo_session(tmp_path, **{option: value})
