"""Marker layouts (mocap.mesh.layout), the ICT layout files, and marker binding (mocap.bind)."""

from __future__ import annotations

import igl
import numpy as np
import pytest
from helpers import numba_cannot_cache
from scipy.spatial.transform import Rotation
from tolerances import (
    BIND_CLOSEST_POINT_CM,
    BIND_EXACT,
    BIND_ICP_GAIN,
    BIND_LAYOUT_MAX_MM,
    BIND_LAYOUT_MEAN_MM,
    BIND_SCALE_REL,
    LAYOUT_TOML_CM,
    MESH_EXACT,
    NEUTRAL_FRAME_RMS_MM,
)

import mocap.mesh.layout as layout_module
from mocap.bind import Binding, bind_markers, closest_surface_points, load_binding
from mocap.errors import FileFormatError, InputError, MarkerError
from mocap.markerset import REQUIRED_REGIONS
from mocap.mesh.layout import load_marker_layout, make_layout, save_marker_layout
from mocap.mesh.mesh import boundary_loops, load_mesh
from mocap.neutral import hold_window, pick_neutral_frame, resolve_neutral_frame

CM_PER_MM = 0.1


# ---------------------------------------------------------------- the ICT layout

def test_ict_layout_matches_its_markerset(ict_layout, ict_markerset):
    assert 60 <= ict_layout.n_markers <= 70
    assert set(ict_layout.labels) == set(ict_markerset.markers)
    assert 4 <= len(ict_markerset.head) <= 7
    for region in REQUIRED_REGIONS[:-1]:
        assert len(ict_markerset.regions[region]) >= 4, region
    assert {"mouth_corner_left", "upper_lip_top", "eye_outer_right"} \
        <= set(ict_markerset.landmarks)


def _lip_branches(mesh):
    """The mouth-opening loop split at its corners into upper and lower lip edges."""
    v = mesh.vertices
    mouth = min(boundary_loops(mesh)[1:], key=lambda loop: v[loop, 1].mean())
    rolled = np.roll(mouth, -int(np.argmin(v[mouth, 0])))
    split = int(np.flatnonzero(rolled == mouth[np.argmax(v[mouth, 0])])[0])
    a, b = rolled[:split + 1], np.r_[rolled[split:], rolled[0]]
    return (a, b) if v[a, 1].mean() > v[b, 1].mean() else (b, a)


def test_lip_markers_sit_on_their_side_of_the_mouth(ict_mesh, ict_layout, ict_markerset):
    upper, lower = _lip_branches(ict_mesh)
    skin = ict_layout.positions(ict_mesh.vertices, offset=False)
    for region, own, other in (("upper_lip", upper, lower), ("lower_lip", lower, upper)):
        for label in ict_markerset.regions[region]:
            p = skin[ict_layout.index(label)]
            d_own = np.linalg.norm(ict_mesh.vertices[own] - p, axis=1).min()
            d_other = np.linalg.norm(ict_mesh.vertices[other] - p, axis=1).min()
            assert d_own < d_other, label
    y = skin[:, 1]
    lowest_upper = min(y[ict_layout.index(l)] for l in ict_markerset.regions["upper_lip"])
    highest_lower = max(y[ict_layout.index(l)] for l in ict_markerset.regions["lower_lip"])
    assert lowest_upper > highest_lower


def test_left_and_right_are_the_subjects(ict_mesh, ict_layout, ict_markerset):
    x = ict_layout.positions(ict_mesh.vertices)[:, 0]
    for region, labels in ict_markerset.regions.items():
        for label in labels:
            side = ("left" in region or label.endswith("-L") or "-L" in label,
                    "right" in region or label.endswith("-R") or "-R" in label)
            if side[0]:
                assert x[ict_layout.index(label)] > 0.3, label
            if side[1]:
                assert x[ict_layout.index(label)] < -0.3, label


def test_head_markers_barely_move_in_expressions(ict_mesh, ict_layout, ict_markerset,
                                                 ict_expressions_dir):
    folder = ict_expressions_dir
    head = [ict_layout.index(l) for l in ict_markerset.head]
    face = [ict_layout.index(l) for l in ict_markerset.face_markers]
    skin = ict_layout.positions(ict_mesh.vertices, offset=False)
    moves = []
    for name in ("browInnerUp_L", "browOuterUp_R", "browDown_L", "jawOpen", "noseSneer_L",
                 "mouthSmile_R", "eyeBlink_L"):
        shape = load_mesh(folder / f"{name}.obj")
        moves.append(np.linalg.norm(ict_layout.positions(shape.vertices, offset=False) - skin,
                                    axis=1))
    moves = np.max(moves, axis=0) / CM_PER_MM                    # mm
    assert moves[head].max() < 1.5
    assert np.median(moves[face]) > 2 * moves[head].max()


def test_landmark_markers_are_near_their_mesh_landmarks(ict_mesh, ict_layout, ict_markerset,
                                                        ict_landmarks):
    skin = ict_layout.positions(ict_mesh.vertices, offset=False)
    for point, label in ict_markerset.landmarks.items():
        gap = np.linalg.norm(skin[ict_layout.index(label)]
                             - ict_mesh.vertices[ict_landmarks[point]])
        assert gap / CM_PER_MM < 12, (point, label)


# ---------------------------------------------------------------- layout evaluation

def test_positions_offset_along_interpolated_normals(ict_mesh, ict_layout):
    normals = igl.per_vertex_normals(ict_mesh.vertices, ict_mesh.faces,
                                     igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_AREA)
    skin = np.einsum("mkc,mk->mc", ict_mesh.vertices[ict_layout.vertex_ids], ict_layout.weights)
    n = np.einsum("mkc,mk->mc", normals[ict_layout.vertex_ids], ict_layout.weights)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    expected = skin + ict_layout.offsets[:, None] * n
    np.testing.assert_allclose(ict_layout.positions(ict_mesh.vertices), expected, atol=MESH_EXACT)
    np.testing.assert_allclose(ict_layout.positions(ict_mesh.vertices, offset=False), skin,
                               atol=MESH_EXACT)
    assert np.all(ict_layout.offsets == 0.2)


@pytest.mark.parametrize("frames", [2, 5, 64, 130])
def test_compiled_placement_is_the_numpy_placement_bit_for_bit(ict_mesh, ict_basis, frames,
                                                               monkeypatch):
    """With numba (the `speed` extra) markers are placed by one compiled loop: the same
    positions, bit for bit, as the NumPy path, for face and vertex markers, with and
    without offsets, under weights and on meshes with NaN vertices."""
    rng = np.random.default_rng(frames)
    faces = rng.choice(len(ict_mesh.faces), 20, replace=False)
    markers = {f"face-{i}": {"face": int(f), "bary": list(rng.dirichlet(np.ones(3)))}
               for i, f in enumerate(faces)}
    markers.update({f"vertex-{i}": {"vertex": int(v)}
                    for i, v in enumerate(rng.choice(ict_mesh.n_vertices, 10))})
    markers["face-0"]["offset"] = markers["vertex-0"]["offset"] = 0.0     # on the skin
    layout = make_layout(ict_mesh, markers, offset=0.2)
    assert layout_module._compiled_place() is not None     # numba: the speed extra, in .[test]
    weights = rng.uniform(-0.2, 1.1, (frames, len(ict_basis.names)))
    meshes = ict_mesh.vertices + rng.normal(0, 0.1, (frames,) + ict_mesh.vertices.shape)
    meshes[1, layout.vertex_ids[3, 0]] = np.nan           # NaN where a marker reads
    for marker in (0, 5):                       # where only a normal reads, of a marker on
        ring = ict_mesh.faces[(ict_mesh.faces == layout.vertex_ids[marker, 0]).any(axis=1)]
        meshes[0, np.setdiff1d(ring, layout.vertex_ids)[0]] = np.nan      # the skin and off it
    runs = []
    for compiled in (True, False):
        if not compiled:
            monkeypatch.setattr(layout_module, "_compiled_place", lambda: None)
        runs.append([layout.positions_under_weights(ict_basis.neutral.vertices,
                                                    ict_basis.displacements, weights),
                     layout.positions(meshes), layout.positions(meshes, offset=False)])
    for got, expected in zip(*runs):
        np.testing.assert_array_equal(got, expected)
    assert np.isnan(runs[0][1][1]).any() and np.isnan(runs[0][1][0, 5]).all()
    assert np.isfinite(runs[0][1][0, 0]).all()     # on the skin: its normal is not read


def test_numba_without_a_cache_folder_falls_back_to_numpy_with_a_warning(ict_mesh, ict_layout,
                                                                        monkeypatch):
    """numba raises RuntimeError when it can write its compiled code nowhere (a read-only
    install and home): the markers are then placed by NumPy, with a warning saying so."""
    meshes = np.stack([ict_mesh.vertices, ict_mesh.vertices[::-1]])
    numba_cannot_cache(monkeypatch, "mocap.mesh._layout_kernel")
    layout_module._compiled_place.cache_clear()
    try:
        with pytest.warns(UserWarning, match="compiled marker placement is off .*no locator"):
            got = ict_layout.positions(meshes)
        assert layout_module._compiled_place() is None
    finally:
        monkeypatch.undo()
        layout_module._compiled_place.cache_clear()
    np.testing.assert_array_equal(got, ict_layout.positions(meshes))


def test_positions_vectorized_over_frames(ict_mesh, ict_layout):
    rng = np.random.default_rng(1)
    frames = ict_mesh.vertices + rng.normal(0, 0.1, (2, 3) + ict_mesh.vertices.shape)
    batch = ict_layout.positions(frames)
    assert batch.shape == (2, 3, ict_layout.n_markers, 3)
    for i in range(2):
        for j in range(3):
            np.testing.assert_allclose(batch[i, j], ict_layout.positions(frames[i, j]),
                                       atol=MESH_EXACT)
    frames[0, 0, ict_layout.vertex_ids[5, 0]] = np.nan
    before = frames.copy()
    out = ict_layout.positions(frames)
    assert np.isnan(out[0, 0, 5]).all() and not np.isnan(out[1]).any()
    np.testing.assert_array_equal(frames, before)              # the input is not mutated


def test_layout_round_trip(ict_mesh, ict_layout, tmp_path):
    path = tmp_path / "layout.toml"
    save_marker_layout(ict_layout, path)
    back = load_marker_layout(path, ict_mesh)
    assert back.labels == ict_layout.labels
    np.testing.assert_allclose(back.positions(ict_mesh.vertices),
                               ict_layout.positions(ict_mesh.vertices), atol=LAYOUT_TOML_CM)


_BAD_SPECS = [
    ({"vertex": 1, "face": 2}, "needs exactly one of 'vertex' or 'face'"),
    ({}, "needs exactly one of 'vertex' or 'face'"),
    ({"vertex": 99999}, "vertex must be an integer in 0..9408"),
    ({"face": 2, "bary": [0.5, 0.6, 0.1]}, "bary must be 3 non-negative weights summing to 1"),
    ({"face": 2, "bary": [1.5, -0.5, 0.0]}, "bary must be 3 non-negative weights summing to 1"),
    ({"vertex": 1, "colour": "red"}, "specification must be a table with keys among"),
    ({"vertex": 1, "bary": [1, 0, 0]}, "'bary' goes with 'face'"),
    ({"vertex": 1, "offset": "far"}, "offset must be a finite number"),
]


@pytest.mark.parametrize("spec,message", _BAD_SPECS, ids=[m for _, m in _BAD_SPECS])
def test_bad_marker_specifications(ict_mesh, spec, message):
    with pytest.raises(MarkerError, match="marker 'm1': " + message):
        make_layout(ict_mesh, {"m1": spec})


def test_layout_file_checks_the_mesh(ict_mesh, tmp_path):
    path = tmp_path / "l.toml"
    path.write_text('n_vertices = 10\n[markers]\na = { vertex = 1 }\n')
    with pytest.raises(FileFormatError, match="l.toml: written for a mesh of 10 vertices"):
        load_marker_layout(path, ict_mesh)
    path.write_text('units = "mm"\n[markers]\na = { vertex = 1 }\n')
    with pytest.raises(FileFormatError, match="offsets are in 'mm' but the mesh is in 'cm'"):
        load_marker_layout(path, ict_mesh)
    path.write_text('[markers]\na = { face = 1, bary = [1, 1, 1] }\n')
    with pytest.raises(FileFormatError, match="l.toml: marker 'a': bary must be"):
        load_marker_layout(path, ict_mesh)


# ---------------------------------------------------------------- closest point

def _closest_on_triangles(p, a, b, c):
    """Brute force oracle: closest point of every triangle (Ericson, Real-Time Collision
    Detection 5.1.5), vectorized over triangles for one point p."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp = p - b
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    cp = p - c
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        out = a + ab * (vb / denom)[:, None] + ac * (vc / denom)[:, None]
        cases = [
            ((d1 <= 0) & (d2 <= 0), a),
            ((d3 >= 0) & (d4 <= d3), b),
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * (d1 / (d1 - d3))[:, None]),
            ((d6 >= 0) & (d5 <= d6), c),
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * (d2 / (d2 - d6))[:, None]),
            ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0),
             b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)))[:, None]),
        ]
    for mask, value in reversed(cases):
        out = np.where(mask[:, None], value, out)
    return out


def test_closest_point_matches_brute_force(ict_mesh):
    rng = np.random.default_rng(2)
    points = ict_mesh.vertices[rng.choice(ict_mesh.n_vertices, 25)] + rng.normal(0, 0.5, (25, 3))
    face_ids, bary, dist = closest_surface_points(ict_mesh, points)
    a, b, c = (ict_mesh.vertices[ict_mesh.faces[:, k]] for k in range(3))
    for p, f, w, d in zip(points, face_ids, bary, dist):
        candidates = _closest_on_triangles(p, a, b, c)
        brute = np.linalg.norm(candidates - p, axis=1)
        assert d == pytest.approx(brute.min(), abs=MESH_EXACT)
        np.testing.assert_allclose(w @ ict_mesh.vertices[ict_mesh.faces[f]],
                                   candidates[np.argmin(brute)], atol=BIND_CLOSEST_POINT_CM)
        assert np.all(w >= 0) and w.sum() == pytest.approx(1)


# ---------------------------------------------------------------- binding

def _similarity(rng, scale):
    return scale, Rotation.random(random_state=rng).as_matrix(), rng.normal(0, 50, 3)


@pytest.mark.parametrize("icp", [False, True])
def test_known_similarity_is_recovered_exactly(ict_mesh, ict_markerset, ict_landmarks, icp):
    rng = np.random.default_rng(3)
    scale, rot, trans = _similarity(rng, 0.1)                  # capture mm -> mesh cm
    vertices = np.array(list(ict_landmarks.values())
                        + rng.choice(ict_mesh.n_vertices, 30).tolist())
    labels = [f"m{i}" for i in range(len(vertices))]
    markers_mm = (ict_mesh.vertices[vertices] - trans) @ rot / scale
    landmarks = {point: f"m{i}" for i, point in enumerate(ict_landmarks)}
    binding = bind_markers(markers_mm, labels, landmarks, ict_mesh, ict_landmarks, icp=icp)
    assert binding.scale == pytest.approx(scale, rel=BIND_EXACT)
    np.testing.assert_allclose(binding.rotation, rot, atol=BIND_EXACT)
    np.testing.assert_allclose(binding.translation, trans, atol=BIND_EXACT)
    np.testing.assert_allclose(binding.marker_points(ict_mesh.vertices),
                               ict_mesh.vertices[vertices], atol=BIND_EXACT)
    assert binding.distances.max() < BIND_EXACT and binding.converged
    np.testing.assert_allclose(binding.to_capture(binding.to_mesh(markers_mm)), markers_mm,
                               atol=BIND_EXACT)


def _simulated_capture(mesh, layout, rng, noise_mm=0.2):
    mm_per_cm = 10 * rng.uniform(0.9, 1.1)   # a face a little bigger or smaller than ICT
    _, rot, trans = _similarity(rng, 1.0)
    markers = mm_per_cm * layout.positions(mesh.vertices) @ rot.T + trans
    return markers + rng.normal(0, noise_mm, markers.shape), mm_per_cm


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ict_layout_binding_recovers_the_layout(ict_mesh, ict_layout, ict_markerset,
                                                ict_landmarks, seed):
    rng = np.random.default_rng(seed)
    markers, mm_per_cm = _simulated_capture(ict_mesh, ict_layout, rng)
    offset_mm = 0.2 * mm_per_cm
    truth = ict_layout.positions(ict_mesh.vertices, offset=False)
    errors = {}
    for icp in (False, True):
        binding = bind_markers(markers, ict_layout.labels, ict_markerset.landmarks, ict_mesh,
                               ict_landmarks, icp=icp, skin_offset=offset_mm, max_distance_warn=10)
        err = np.linalg.norm(binding.marker_points(ict_mesh.vertices) - truth, axis=1) * mm_per_cm
        errors[icp] = err
    print(f"seed {seed}: landmarks only mean {errors[False].mean():.3f} max "
          f"{errors[False].max():.3f} mm; ICP mean {errors[True].mean():.3f} max "
          f"{errors[True].max():.3f} mm")
    assert errors[True].mean() < BIND_LAYOUT_MEAN_MM
    assert errors[True].max() < BIND_LAYOUT_MAX_MM
    assert errors[True].mean() < errors[False].mean() / BIND_ICP_GAIN
    assert binding.scale * mm_per_cm == pytest.approx(1, abs=BIND_SCALE_REL)
    # noise and the skin offset end ICP in a cycle: it must still say it converged
    assert binding.converged and binding.n_iterations < 200, binding.message


def test_icp_without_scale_keeps_the_landmark_scale(ict_mesh, ict_layout, ict_markerset,
                                                    ict_landmarks):
    markers, _ = _simulated_capture(ict_mesh, ict_layout, np.random.default_rng(4))
    kwargs = dict(skin_offset=2.0, max_distance_warn=10)
    base = bind_markers(markers, ict_layout.labels, ict_markerset.landmarks, ict_mesh,
                        ict_landmarks, icp=False, **kwargs)
    fixed = bind_markers(markers, ict_layout.labels, ict_markerset.landmarks, ict_mesh,
                         ict_landmarks, icp_scale=False, **kwargs)
    assert fixed.scale == base.scale and fixed.rms < base.rms


def test_far_marker_warns_by_name(ict_mesh, ict_layout, ict_markerset, ict_landmarks):
    markers, mm_per_cm = _simulated_capture(ict_mesh, ict_layout, np.random.default_rng(5))
    markers[ict_layout.index("cheek-L2")] += 30.0
    with pytest.warns(UserWarning, match=r"1 markers are more than 3.0 mm off .*cheek-L2"):
        bind_markers(markers, ict_layout.labels, ict_markerset.landmarks, ict_mesh, ict_landmarks,
                     skin_offset=0.2 * mm_per_cm)


def test_binding_json_round_trip(ict_mesh, ict_layout, ict_markerset, ict_landmarks, tmp_path):
    markers, _ = _simulated_capture(ict_mesh, ict_layout, np.random.default_rng(6))
    binding = bind_markers(markers, ict_layout.labels, ict_markerset.landmarks, ict_mesh,
                           ict_landmarks, skin_offset=2.0, max_distance_warn=10)
    binding.save(tmp_path / "b.json")
    back = load_binding(tmp_path / "b.json")
    assert isinstance(back, Binding) and back.labels == binding.labels
    np.testing.assert_array_equal(back.marker_points(ict_mesh.vertices),
                                  binding.marker_points(ict_mesh.vertices))
    assert back.scale == binding.scale and back.message == binding.message
    (tmp_path / "x.json").write_text('{"format": "other"}')
    with pytest.raises(FileFormatError, match="x.json: not a binding file"):
        load_binding(tmp_path / "x.json")
    (tmp_path / "y.json").write_text("{")
    with pytest.raises(FileFormatError, match="y.json: not valid JSON"):
        load_binding(tmp_path / "y.json")


def test_binding_errors(ict_mesh, ict_landmarks):
    pts = ict_mesh.vertices[list(ict_landmarks.values())] * 10
    labels = [f"m{i}" for i in range(len(pts))]
    marks = {p: f"m{i}" for i, p in enumerate(ict_landmarks)}
    two = dict(list(marks.items())[:2])
    with pytest.raises(InputError, match="2 landmark pairs .* needs at least 3"):
        bind_markers(pts, labels, two, ict_mesh, ict_landmarks)
    midline = {p: marks[p] for p in ("upper_lip_top", "nose_tip", "chin")}
    line = pts.copy()
    idx = [labels.index(midline[p]) for p in midline]
    line[idx] = [[0, 0, 0], [0, 10, 0], [0, 25, 0]]
    with pytest.raises(InputError, match="are collinear"):
        bind_markers(line, labels, midline, ict_mesh, ict_landmarks)
    with pytest.raises(InputError, match="marker_landmarks: unknown anatomical point 'nose'"):
        bind_markers(pts, labels, {**marks, "nose": "m0"}, ict_mesh, ict_landmarks)
    with pytest.raises(InputError, match="mesh_landmarks: unknown anatomical point 'nose'"):
        bind_markers(pts, labels, marks, ict_mesh, {**ict_landmarks, "nose": 1})
    with pytest.raises(MarkerError, match="marker 'zz': marker_landmarks names it"):
        bind_markers(pts, labels, {**marks, "chin": "zz"}, ict_mesh, ict_landmarks)
    nan = pts.copy()
    nan[3] = np.nan
    with pytest.raises(MarkerError, match="marker 'm3': is missing \\(NaN\\)"):
        bind_markers(nan, labels, marks, ict_mesh, ict_landmarks)
    with pytest.raises(InputError, match="labels has 2 entries"):
        bind_markers(pts, labels[:2], marks, ict_mesh, ict_landmarks)


# ---------------------------------------------------------------- neutral frame

def test_pick_neutral_frame():
    rng = np.random.default_rng(7)
    rest = rng.normal(0, 30, (12, 3))
    frames = rest + rng.normal(0, 0.3, (300, 12, 3))
    frames[:100] += rng.normal(0, 5, (100, 1, 3)) * rng.random((100, 12, 1))  # expressions
    frames[rng.choice(300, 40), rng.choice(12, 40)] = np.nan
    frames[150] = rest                                       # the exact rest pose
    assert pick_neutral_frame(frames) == 150
    frames[150, 3] = np.nan
    chosen = pick_neutral_frame(frames)
    assert chosen != 150 and not np.isnan(frames[chosen]).any()
    assert np.sqrt(np.mean(np.sum((frames[chosen] - rest) ** 2, -1))) < NEUTRAL_FRAME_RMS_MM
    with pytest.raises(InputError, match="no frame has every marker visible"):
        pick_neutral_frame(np.full((4, 2, 3), np.nan))


def test_neutral_frame_not_biased_by_gaps_during_expressions():
    """Gaps that come with expressions must not pull the rest estimate towards them."""
    rng = np.random.default_rng(3)
    rest = rng.normal(0, 30, (10, 3))
    expression = rest + rng.normal(0, 5, (10, 3))
    n = 200
    positions = np.repeat(rest[None], n, axis=0)
    active = np.zeros(n, bool)
    active[60:130] = True                        # a third of the take is an expression...
    positions[active] = expression
    positions += rng.normal(0, 0.05, positions.shape)
    hidden = np.flatnonzero(~active)[:80]        # ...and most rest frames have a gap
    positions[hidden, 0] = np.nan
    frame = pick_neutral_frame(positions)
    assert not active[frame]


def _never_resting_take(rng, rate, n_hold):
    """A take (T, 10, 3) mm that never rests after `n_hold` frames at the true rest pose.

    After the hold the markers sweep smoothly between expressions (never back to
    rest), with still moments mid-expression; 0.2 mm noise throughout.
    """
    rest = rng.normal(0, 30, (10, 3))
    n = 20 * int(rate)
    t = np.arange(n - n_hold) / rate
    poses = rng.normal(0, 4, (3, 10, 3))
    blend = np.stack([1.2 + np.sin(0.7 * t), 1.2 + np.cos(0.45 * t),
                      np.clip(np.sin(0.3 * t), 0, 1)])
    moving = rest + np.einsum("kt,kmc->tmc", blend, poses)
    moving[n // 2 - n_hold:n // 2] = moving[n // 2 - n_hold]        # a still moment mid-expression
    positions = np.concatenate([np.repeat(rest[None], n_hold, axis=0), moving])
    return rest, positions + rng.normal(0, 0.2, positions.shape)


@pytest.mark.parametrize("rate", [30.0, 120.0])
def test_hold_method_finds_the_neutral_hold_the_median_misses(rate):
    rng = np.random.default_rng(11)
    n_hold = int(2 * rate)
    rest, positions = _never_resting_take(rng, rate, n_hold)
    positions[5, 2] = np.nan                                   # a gap in the hold
    median = pick_neutral_frame(positions)
    hold = pick_neutral_frame(positions, method="hold", rate=rate)
    assert median >= n_hold                                    # the median pose is no rest pose
    assert 0 <= hold < n_hold and not np.isnan(positions[hold]).any()
    assert resolve_neutral_frame(positions, "hold", rate=rate) == hold
    assert resolve_neutral_frame(positions, "auto") == median
    assert resolve_neutral_frame(positions, 7) == 7


@pytest.mark.parametrize("block_bytes", [None, 8 * 400])
def test_hold_is_the_first_window_as_still_as_twice_the_stillest(block_bytes, monkeypatch):
    """Against the definition window by window (np.var), the coordinates summed a block at a
    time as well as all at once."""
    import mocap.neutral as neutral_module
    if block_bytes is not None:
        monkeypatch.setattr(neutral_module, "_HOLD_BLOCK_BYTES", block_bytes)   # 1 coordinate
    rng = np.random.default_rng(5)
    rate, window = 30.0, hold_window(30.0)
    positions = np.cumsum(rng.normal(0, 1.0, (300, 4, 3)), axis=0)            # always moving
    positions[120:150] = positions[120] + rng.normal(0, 0.05, (30, 4, 3))    # a still stretch
    positions[50:80, 0] = positions[50, 0]                    # a decoy: one marker still only
    positions[40, 1, 2] = np.nan                                              # a gap
    still = np.full(len(positions), np.nan)
    for centre in range(window // 2, len(positions) - window // 2):
        part = positions[centre - window // 2:centre + window // 2 + 1]
        if not np.isnan(part).any():
            still[centre] = np.sqrt(part.var(axis=0).sum(axis=1).mean())
    expected = int(np.flatnonzero(still <= 2 * np.nanmin(still))[0])
    assert pick_neutral_frame(positions, method="hold", rate=rate) == expected
    assert 120 <= expected < 150


@pytest.mark.parametrize("method", ["median", "hold"])
def test_picking_on_some_markers_reads_them_where_they_are(method):
    """`markers` picks on those tracks, as a copy of them would; the other markers' gaps and
    motion do not count. Oracle: the pick on the copied tracks."""
    rng = np.random.default_rng(12)
    rate, n_hold = 60.0, 120
    _, face = _never_resting_take(rng, rate, n_hold)
    face[7, 1] = np.nan
    others = rng.normal(0.0, 50.0, (len(face), 3, 3))          # wild, often missing
    others[rng.random((len(face), 3)) < 0.3] = np.nan
    others[::2, 0] = others[1::2, 1] = np.nan                # never both there
    positions = np.concatenate([others[:, :2], face, others[:, 2:]], axis=1)
    markers = np.arange(2, 2 + face.shape[1])[::-1]
    expected = pick_neutral_frame(np.ascontiguousarray(positions[:, markers]), method=method,
                                  rate=rate)
    assert pick_neutral_frame(positions, method=method, rate=rate, markers=markers) == expected
    assert resolve_neutral_frame(positions, "hold" if method == "hold" else "auto", rate=rate,
                                 markers=markers) == expected
    with pytest.raises(InputError, match="no frame has every marker visible"):
        pick_neutral_frame(positions, method=method, rate=rate, markers=[0, 1, 2])
    with pytest.raises(InputError, match=r"markers must index the \d+ markers"):
        pick_neutral_frame(positions, markers=[2, positions.shape[1]])
    with pytest.raises(InputError, match="markers must be a 1-D array"):
        pick_neutral_frame(positions, markers=[[2, 3]])


def test_hold_method_errors():
    positions = np.zeros((20, 3, 3))
    with pytest.raises(InputError, match=r"method must be one of \('median', 'hold'\)"):
        pick_neutral_frame(positions, method="still")
    with pytest.raises(InputError, match="method 'hold' needs the take's frame rate"):
        pick_neutral_frame(positions, method="hold")
    with pytest.raises(InputError, match=r"a neutral hold is 0.5 s \(51 frames\); the take "
                                         r"has only 20"):
        pick_neutral_frame(positions, method="hold", rate=100.0)
    gappy = np.zeros((200, 3, 3))
    gappy[::40, 1] = np.nan
    with pytest.raises(InputError, match="no 51 consecutive frames have every marker visible"):
        pick_neutral_frame(gappy, method="hold", rate=100.0)
    with pytest.raises(InputError, match="frame must be at least 0"):
        resolve_neutral_frame(positions, -1)
