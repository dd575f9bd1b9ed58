"""Face meshes (mocap.mesh.mesh) and mesh landmarks (mocap.mesh.landmarks)."""

from __future__ import annotations

import json
from pathlib import Path

import igl
import numpy as np
import pytest
import trimesh
from helpers import ICT_LANDMARKS_TOML
from tolerances import FLOAT32_FACE_CM, MESH_EXACT

from mocap.anatomy import ANATOMICAL_POINTS, MASKLE_POINTS
from mocap.errors import FileFormatError, InputError
from mocap.mesh.landmarks import check_mesh_landmarks, load_mesh_landmarks
from mocap.mesh.mesh import (
    MESH_FORMATS,
    Mesh,
    boundary_loops,
    degenerate_faces,
    face_normals,
    load_mesh,
    mesh_edges,
    save_obj,
    vertex_normals,
)


def _polygons_by_loop(path) -> list[list[int]]:
    """Brute-force oracle: the OBJ's polygons, 0-based, line by line."""
    polys = []
    for line in Path(path).read_text().splitlines():
        if line.startswith("f "):
            polys.append([int(tok.split("/")[0]) - 1 for tok in line.split()[1:]])
    return polys


# ---------------------------------------------------------------- loading

def test_ict_mesh_loads_with_file_order_and_fan_triangles(ict_mesh, ict_neutral_path):
    assert ict_mesh.units == "cm"
    assert ict_mesh.n_vertices == 9409
    polys = _polygons_by_loop(ict_neutral_path)
    assert len(ict_mesh.polygon_sizes) == len(polys) == 9230
    assert ict_mesh.n_faces == sum(len(p) - 2 for p in polys)
    expected = [[p[0], p[k + 1], p[k + 2]] for p in polys for k in range(len(p) - 2)]
    np.testing.assert_array_equal(ict_mesh.faces, expected)
    np.testing.assert_array_equal(ict_mesh.polygon_corners, np.concatenate(polys))
    ref = trimesh.load(ict_neutral_path, process=False,
                       maintain_order=True)
    np.testing.assert_array_equal(ict_mesh.vertices, ref.vertices)
    assert not ict_mesh.vertices.flags.writeable


def test_expression_meshes_share_the_neutral_triangles(ict_mesh, ict_expressions_dir):
    shape = load_mesh(ict_expressions_dir / "jawOpen.obj")
    assert ict_mesh.same_topology(shape)
    assert not np.allclose(shape.vertices, ict_mesh.vertices)


_PLAIN = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0.5\nf 1 2 3 4\nf 2 5 6\nf 3 2 6 4 1\n"
_VARIANTS = {
    "plain": _PLAIN,
    "slashes": _PLAIN.replace("f 1 2 3 4", "f 1/1/1 2/2/2 3/3/3 4/4/4").replace(
        "f 2 5 6", "f 2//1 5//1 6//1"),
    "negative": _PLAIN.replace("f 2 5 6", "f -5 -2 -1"),
    "tabs-crlf": _PLAIN.replace("v 1 0 0", "v\t1\t0\t0").replace("\n", "\r\n"),
    "extras": "# comment\nmtllib x.mtl\n" + _PLAIN.replace("v 2 0 0", "v 2 0 0 1.0")
              + "vt 0 0\nvn 0 0 1\ns off\n",
}


@pytest.mark.parametrize("variant", sorted(_VARIANTS))
def test_obj_variants_give_the_same_mesh(tmp_path, variant):
    path = tmp_path / "m.obj"
    path.write_text(_VARIANTS[variant])
    mesh = load_mesh(path)
    np.testing.assert_array_equal(mesh.polygon_sizes, [4, 3, 5])
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 2, 3], [1, 4, 5], [2, 1, 5],
                                               [2, 5, 3], [2, 3, 0]])
    np.testing.assert_array_equal(mesh.face_polygon, [0, 0, 1, 2, 2, 2])
    np.testing.assert_array_equal(mesh.vertices[5], [2, 1, 0.5])


_BAD_OBJ = [
    ("v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN or infinite coordinates"),
    ("v 0 0 inf\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN or infinite coordinates"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", "line 4: face indexes vertex 4, out of range"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "line 4: face indexes vertex 0"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", "line 4: face has 2 corners"),
    ("v 0 0 0\nv 1 x 0\nv 0 1 0\nf 1 2 3\n", "line 2: vertex coordinates are not numbers"),
    ("v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n", "line 2: vertex line needs 3 coordinates"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3.5\n", "line 4: face indices are not integers"),
    ("# nothing\n", "empty mesh: no vertices"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\n", "empty mesh: no faces"),
]


@pytest.mark.parametrize("text,message", _BAD_OBJ, ids=[m for _, m in _BAD_OBJ])
def test_bad_obj_is_rejected_naming_the_file(tmp_path, text, message):
    path = tmp_path / "bad.obj"
    path.write_text(text)
    with pytest.raises(FileFormatError, match="bad.obj.*" + message.replace("(", r"\(")):
        load_mesh(path)


def test_unknown_format_and_missing_file(tmp_path):
    with pytest.raises(FileFormatError, match="unknown mesh format '.stl'"):
        load_mesh(tmp_path / "m.stl")
    with pytest.raises(FileFormatError, match="cannot read mesh"):
        load_mesh(tmp_path / "absent.obj")
    with pytest.raises(InputError, match="unknown length unit 'furlong'"):
        load_mesh(tmp_path / "absent.obj", units="furlong")


def test_degenerate_faces_warn_and_are_found(tmp_path):
    path = tmp_path / "deg.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\nf 1 1 3\n")
    with pytest.warns(UserWarning, match=r"deg.obj: 2 degenerate \(zero-area\) triangles"):
        mesh = load_mesh(path)
    np.testing.assert_array_equal(degenerate_faces(mesh.vertices, mesh.faces), [1, 2])


def test_degenerate_faces_are_trimeshs_zero_areas_on_the_ict_face(ict_mesh):
    """On the ICT face with triangles collapsed (a corner moved onto another, or onto the
    middle of the opposite edge; a later move may undo an earlier one's): exactly the
    faces whose area trimesh measures at or under 1e-12 of the squared box diagonal."""
    vertices = ict_mesh.vertices.copy()
    faces = ict_mesh.faces
    vertices[faces[:20, 1]] = vertices[faces[:20, 0]]
    vertices[faces[100:120, 2]] = 0.5 * (vertices[faces[100:120, 0]]
                                         + vertices[faces[100:120, 1]])
    area = trimesh.Trimesh(vertices, faces, process=False).area_faces
    diag2 = np.sum(np.ptp(vertices, axis=0) ** 2)
    expected = np.flatnonzero(2 * area <= 1e-12 * diag2)
    assert 20 <= len(expected) < 100
    np.testing.assert_array_equal(degenerate_faces(vertices, faces), expected)


@pytest.mark.parametrize("suffix", [s for s in MESH_FORMATS if s != ".obj"])
def test_ply_and_gltf_keep_vertex_order(ict_mesh, tmp_path, suffix):
    path = tmp_path / f"face{suffix}"
    trimesh.Trimesh(ict_mesh.vertices, ict_mesh.faces, process=False).export(path)
    mesh = load_mesh(path, units="cm")
    # trimesh writes float32 to both formats
    np.testing.assert_allclose(mesh.vertices, ict_mesh.vertices, atol=FLOAT32_FACE_CM, rtol=0)
    np.testing.assert_array_equal(mesh.faces, ict_mesh.faces)


def test_mesh_constructor_validates():
    v = np.eye(3)
    with pytest.raises(InputError, match="out of range for 3 vertices"):
        Mesh(v, [[0, 1, 3]])
    with pytest.raises(InputError, match=r"faces must have shape \(F, 3\)"):
        Mesh(v, [[0, 1, 2, 0]])
    with pytest.raises(InputError, match="face_polygon does not match polygon_sizes"):
        Mesh(v, [[0, 1, 2]], face_polygon=[0], polygon_sizes=[4])
    with pytest.raises(InputError, match="vertices contains infinite values"):
        Mesh([[0, 0, np.inf], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])


# ---------------------------------------------------------------- geometry

def test_vertex_normals_match_igl_and_batch(ict_mesh):
    ours = vertex_normals(ict_mesh.vertices, ict_mesh.faces)
    ref = igl.per_vertex_normals(ict_mesh.vertices, ict_mesh.faces,
                                 igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_AREA)
    np.testing.assert_allclose(ours, ref, atol=MESH_EXACT)
    rng = np.random.default_rng(0)
    frames = ict_mesh.vertices + rng.normal(0, 0.05, (3,) + ict_mesh.vertices.shape)
    batch = vertex_normals(frames, ict_mesh.faces)
    for frame, normals in zip(frames, batch):   # one mesh sums its faces in the batch's order
        np.testing.assert_array_equal(normals, vertex_normals(frame, ict_mesh.faces))
    faces_n = face_normals(ict_mesh.vertices, ict_mesh.faces)
    np.testing.assert_allclose(faces_n, igl.per_face_normals(ict_mesh.vertices, ict_mesh.faces,
                                                             np.zeros(3)), atol=MESH_EXACT)
    nose_tip = 4857
    assert ours[nose_tip, 2] > 0.9  # outward, towards the viewer (+z)


def test_ict_has_four_boundary_loops(ict_mesh):
    loops = boundary_loops(ict_mesh)
    assert len(loops) == 4
    ref = igl.boundary_loop_all(ict_mesh.faces) if hasattr(igl, "boundary_loop_all") else None
    if ref is not None:
        assert sorted(map(len, ref)) == sorted(map(len, loops))
        assert {frozenset(map(int, r)) for r in ref} == {frozenset(loop.tolist()) for loop in loops}
    all_edges = np.sort(ict_mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    edges = set(map(tuple, all_edges.tolist()))
    for loop in loops:  # consecutive loop vertices share an edge of the mesh
        pairs = np.sort(np.c_[loop, np.roll(loop, -1)], axis=1)
        assert all(tuple(pair) in edges for pair in pairs.tolist())
    centres = np.array([ict_mesh.vertices[loop].mean(axis=0) for loop in loops[1:]])
    mouth = np.argmin(centres[:, 1])
    eyes = np.delete(centres, mouth, axis=0)
    assert abs(centres[mouth, 0]) < 0.1 and np.all(eyes[:, 1] > centres[mouth, 1] + 4)
    assert sorted(np.sign(eyes[:, 0])) == [-1, 1]


@pytest.mark.parametrize("which", ["ict", "two triangles", "none"])
def test_mesh_edges_are_numpys_unique_rows_of_the_sides(ict_mesh, which):
    """Against NumPy's row-wise unique of the sorted sides (the oracle) and igl's edges."""
    faces = {"ict": ict_mesh.faces, "two triangles": np.array([[0, 1, 2], [2, 1, 3]]),
             "none": np.zeros((0, 3), np.int64)}[which]
    edges, side_edge, counts = mesh_edges(faces)
    sides = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    expected, inverse, expected_counts = np.unique(sides, axis=0, return_inverse=True,
                                                   return_counts=True)
    np.testing.assert_array_equal(edges, expected.reshape(-1, 2))
    np.testing.assert_array_equal(side_edge, inverse.ravel())
    np.testing.assert_array_equal(counts, expected_counts)
    np.testing.assert_array_equal(edges[side_edge], sides)
    if len(faces):
        assert {tuple(e) for e in igl.edges(faces).tolist()} == \
            {tuple(sorted(e)) for e in edges.tolist()}


def test_save_obj_round_trip_keeps_quads(ict_mesh, tmp_path):
    out = tmp_path / "copy.obj"
    save_obj(ict_mesh, out)
    back = load_mesh(out)
    np.testing.assert_array_equal(back.vertices, ict_mesh.vertices)
    np.testing.assert_array_equal(back.polygon_sizes, ict_mesh.polygon_sizes)
    np.testing.assert_array_equal(back.faces, ict_mesh.faces)
    tri = tmp_path / "tri.obj"
    save_obj(ict_mesh.vertices, tri, faces=ict_mesh.faces)
    assert np.all(load_mesh(tri).polygon_sizes == 3)
    with pytest.raises(InputError, match="refusing to overwrite an input file"):
        save_obj(ict_mesh, out, inputs=[out])
    with pytest.raises(InputError, match="save_obj needs faces"):
        save_obj(ict_mesh.vertices, tri)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["copy.obj", "tri.obj"]


# ---------------------------------------------------------------- mesh landmarks

def test_ict_landmarks_follow_the_multipie_68_ids(ict_mesh, ict_dir):
    marks = load_mesh_landmarks(ICT_LANDMARKS_TOML, ict_mesh)
    assert set(MASKLE_POINTS) <= set(marks)
    assert {"nose_tip", "chin", "brow_inner_left", "brow_outer_right"} <= set(marks)
    ibug = json.loads((ict_dir / "vertex_indices.json").read_text())["multi_pie_68_landmarks"]
    # iBUG-68: 36-41 right eye, 42-47 left eye (subject's), 48/54 mouth corners, 30 nose tip
    for point, index in [("eye_outer_right", 36), ("eye_inner_right", 39),
                         ("eye_inner_left", 42), ("eye_outer_left", 45),
                         ("mouth_corner_right", 48), ("mouth_corner_left", 54),
                         ("upper_lip_top", 51), ("lower_lip_bottom", 57),
                         ("nose_tip", 30), ("chin", 8)]:
        assert marks[point] == ibug[index], point
    x = ict_mesh.vertices[:, 0]
    for point, vertex in marks.items():
        if point.endswith("_left"):
            assert x[vertex] > 0.5, point       # the subject's left is +x on the ICT face
        if point.endswith("_right"):
            assert x[vertex] < -0.5, point
    y = ict_mesh.vertices[:, 1]
    assert y[marks["upper_lip_top"]] > y[marks["upper_lip_bottom"]] \
        >= y[marks["lower_lip_top"]] > y[marks["lower_lip_bottom"]]
    assert y[marks["forehead"]] > y[marks["brow_mid_left"]] > y[marks["eye_outer_left"]] \
        > y[marks["nose_tip"]] > y[marks["chin"]]


_BAD_LANDMARKS = [
    ("[landmarks]\nnose_tipp = 3\n", "unknown anatomical point 'nose_tipp'"),
    ("[landmarks]\nnose_tip = 99\n", "landmark 'nose_tip' is vertex 99, out of range"),
    ("[landmarks]\nnose_tip = -1\n", "landmark 'nose_tip' is vertex -1, out of range"),
    ("[landmarks]\nnose_tip = 1.5\n", "landmark 'nose_tip' must be a vertex id"),
    ("n_vertices = 12\n[landmarks]\nnose_tip = 1\n", "written for a mesh of 12 vertices"),
    ("mesh = 'x'\n", "needs a non-empty \\[landmarks\\] table"),
    ("colour = 1\n[landmarks]\nnose_tip = 1\n", "unknown keys \\['colour'\\]"),
    ("[landmarks\n", "not valid TOML"),
]


@pytest.mark.parametrize("text,message", _BAD_LANDMARKS, ids=[m for _, m in _BAD_LANDMARKS])
def test_bad_landmark_files(tmp_path, text, message):
    path = tmp_path / "marks.toml"
    path.write_text(text)
    with pytest.raises(FileFormatError, match="marks.toml: .*" + message):
        load_mesh_landmarks(path, 10)


def test_check_mesh_landmarks_in_memory():
    assert check_mesh_landmarks({"chin": np.int64(3)}, 4) == {"chin": 3}
    with pytest.raises(InputError, match="landmarks must be a mapping"):
        check_mesh_landmarks([("chin", 3)], 4)
    assert all(p in ANATOMICAL_POINTS for p in load_mesh_landmarks(ICT_LANDMARKS_TOML))


def test_vertex_normals_of_a_mesh_without_faces_are_zero():
    verts = np.random.default_rng(0).normal(size=(2, 5, 3))
    normals = vertex_normals(verts, np.zeros((0, 3), int))
    assert normals.shape == verts.shape and not normals.any()
