"""Artist bases (basis.artist) on the real ICT-FaceKit expressions."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pygltflib
import pytest
import trimesh
from tolerances import FLOAT32_FACE_CM, MESH_EXACT

from basis.artist import load_artist_basis
from mocap.errors import FileFormatError, InputError
from mocap.mesh.mesh import save_obj


def test_ict_expressions_load_as_displacements(ict_basis, ict_dir):
    listed = json.loads((ict_dir / "vertex_indices.json").read_text())["expressions"]
    assert ict_basis.names == tuple(sorted(listed))
    assert ict_basis.displacements.shape == (53, 9409, 3)
    assert ict_basis.neutral.units == "cm" and not ict_basis.displacements.flags.writeable
    neutral = trimesh.load(ict_dir / "generic_neutral_mesh.obj", process=False,
                           maintain_order=True).vertices
    for name in ("jawOpen", "mouthSmile_L", "eyeBlink_R"):
        shape = trimesh.load(ict_dir / "expressions" / f"{name}.obj", process=False,
                             maintain_order=True).vertices
        np.testing.assert_allclose(ict_basis.displacements[ict_basis.index(name)],
                                   shape - neutral, atol=MESH_EXACT)
    # ICT's _L is the subject's left, +x: the left smile moves the left mouth corner most
    smile = np.linalg.norm(ict_basis.displacements[ict_basis.index("mouthSmile_L")], axis=1)
    assert ict_basis.neutral.vertices[np.argmax(smile), 0] > 1


def test_evaluate_is_neutral_plus_weighted_displacements(ict_basis):
    rng = np.random.default_rng(0)
    weights = rng.random((4, ict_basis.n_shapes))
    out = ict_basis.evaluate(weights)
    assert out.shape == (4, 9409, 3)
    expected = ict_basis.neutral.vertices + np.tensordot(weights[2], ict_basis.displacements,
                                                         axes=1)
    np.testing.assert_allclose(out[2], expected, atol=MESH_EXACT)
    one_hot = np.eye(ict_basis.n_shapes)[ict_basis.index("jawOpen")]
    np.testing.assert_allclose(ict_basis.evaluate(one_hot),
                               ict_basis.neutral.vertices
                               + ict_basis.displacements[ict_basis.index("jawOpen")],
                               atol=MESH_EXACT)
    with pytest.raises(InputError, match=r"weights must have shape \(\.\.\., 53\)"):
        ict_basis.evaluate(np.ones(3))
    with pytest.raises(InputError, match="no artist shape 'smile'"):
        ict_basis.index("smile")


def test_names_select_and_order(ict_expressions_dir, ict_basis):
    sub = load_artist_basis(ict_basis.neutral, ict_expressions_dir,
                            names=["noseSneer_R", "browDown_L"])
    assert sub.names == ("noseSneer_R", "browDown_L")
    np.testing.assert_array_equal(sub.displacements[0],
                                  ict_basis.displacements[ict_basis.index("noseSneer_R")])
    with pytest.raises(InputError, match="no OBJ file for shapes smile"):
        load_artist_basis(ict_basis.neutral, ict_expressions_dir, names=["smile"])


@pytest.fixture(params=["loadtxt", "compiled"])
def shape_parser(request, monkeypatch) -> str:
    """The parser of the shapes' vertex lines: NumPy's loadtxt, or the compiled loop of the
    speed extra (used whatever the shapes' size)."""
    import mocap.mesh.mesh as mesh_module

    if request.param == "compiled":         # the speed extra, which the tests install
        monkeypatch.setattr(mesh_module, "_OBJ_BYTES_WORTH_COMPILING", 0)
    else:
        monkeypatch.setattr(mesh_module, "_compiled_vertex_rows", lambda: None)
    return request.param


@pytest.fixture()
def small_dir(ict_expressions_dir, tmp_path, shape_parser) -> Path:
    folder = tmp_path / "shapes"
    folder.mkdir()
    for name in ("jawOpen", "eyeBlink_L"):
        shutil.copy(ict_expressions_dir / f"{name}.obj", folder)
    return folder


def test_other_vertex_count_is_rejected_naming_the_file(ict_basis, small_dir):
    cut = trimesh.Trimesh(ict_basis.neutral.vertices, ict_basis.neutral.faces, process=False)
    cut = cut.submesh([np.arange(100)], append=True)
    save_obj(np.asarray(cut.vertices), small_dir / "broken.obj", faces=np.asarray(cut.faces))
    with pytest.raises(FileFormatError, match=r"broken.obj: has \d+ vertices but the neutral "
                                              r"has 9409"):
        load_artist_basis(ict_basis.neutral, small_dir)


def test_other_topology_is_rejected_naming_the_file(ict_basis, small_dir):
    faces = ict_basis.neutral.faces.copy()
    faces[0] = faces[0, [0, 2, 1]]
    save_obj(ict_basis.neutral.vertices, small_dir / "flipped.obj", faces=faces)
    with pytest.raises(FileFormatError, match="flipped.obj: has the neutral's vertex count but "
                                              "other faces"):
        load_artist_basis(ict_basis.neutral, small_dir)


def test_bad_shape_sources(ict_basis, tmp_path):
    with pytest.raises(InputError, match="must be a directory of OBJ files or a glTF"):
        load_artist_basis(ict_basis.neutral, tmp_path / "absent")
    with pytest.raises(InputError, match="no artist shapes found"):
        load_artist_basis(ict_basis.neutral, tmp_path)


def _write_gltf(path: Path, base: np.ndarray, deltas: list, names: list, faces) -> None:
    """A glTF with one morphed mesh, written with pygltflib (independent of our reader)."""
    arrays = [base.astype("<f4")] + [d.astype("<f4") for d in deltas] + \
             [np.asarray(faces, "<u4").ravel()]
    blob, views, accessors = b"", [], []
    for i, arr in enumerate(arrays):
        views.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob),
                                          byteLength=arr.nbytes))
        if arr.ndim == 2:
            accessors.append(pygltflib.Accessor(bufferView=i, componentType=pygltflib.FLOAT,
                                                count=len(arr), type=pygltflib.VEC3,
                                                min=arr.min(0).tolist(), max=arr.max(0).tolist()))
        else:
            accessors.append(pygltflib.Accessor(bufferView=i,
                                                componentType=pygltflib.UNSIGNED_INT,
                                                count=arr.size, type=pygltflib.SCALAR))
        blob += arr.tobytes()
    targets = [{"POSITION": i + 1} for i in range(len(deltas))]
    prim = pygltflib.Primitive(attributes=pygltflib.Attributes(POSITION=0),
                               indices=len(arrays) - 1, targets=targets)
    gltf = pygltflib.GLTF2(
        scene=0, scenes=[pygltflib.Scene(nodes=[0])], nodes=[pygltflib.Node(mesh=0)],
        meshes=[pygltflib.Mesh(primitives=[prim], extras={"targetNames": names})],
        buffers=[pygltflib.Buffer(byteLength=len(blob))], bufferViews=views,
        accessors=accessors)
    gltf.set_binary_blob(blob)
    if path.suffix == ".gltf":
        gltf.convert_buffers(pygltflib.BufferFormat.DATAURI)
    gltf.save(str(path))


@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
def test_gltf_morph_targets(ict_basis, tmp_path, suffix):
    names = ["jawOpen", "mouthSmile_L", "browDown_R"]
    deltas = [ict_basis.displacements[ict_basis.index(n)] for n in names]
    path = tmp_path / f"face{suffix}"
    cm_to_m = 0.01                                   # glTF stores metres
    _write_gltf(path, ict_basis.neutral.vertices * cm_to_m, [d * cm_to_m for d in deltas], names,
                ict_basis.neutral.faces)
    loaded = load_artist_basis(ict_basis.neutral, path)
    assert loaded.names == tuple(names)
    np.testing.assert_allclose(loaded.displacements, np.stack(deltas), atol=FLOAT32_FACE_CM)
    picked = load_artist_basis(ict_basis.neutral, path, names=["browDown_R"])
    np.testing.assert_allclose(picked.displacements[0], deltas[2], atol=FLOAT32_FACE_CM)


def test_gltf_mismatches(ict_basis, tmp_path):
    path = tmp_path / "small.glb"
    _write_gltf(path, ict_basis.neutral.vertices[:10], [np.zeros((10, 3))], ["a"], [[0, 1, 2]])
    with pytest.raises(FileFormatError, match="small.glb: has 10 vertices but the neutral has"):
        load_artist_basis(ict_basis.neutral, path)
    path = tmp_path / "centimetres.glb"                # not metres: wrong for glTF
    _write_gltf(path, ict_basis.neutral.vertices, [np.zeros((9409, 3))], ["a"],
                ict_basis.neutral.faces)
    with pytest.raises(FileFormatError, match="centimetres.glb: base positions differ"):
        load_artist_basis(ict_basis.neutral, path)
    path = tmp_path / "ok.glb"
    _write_gltf(path, ict_basis.neutral.vertices / 100, [np.zeros((9409, 3))], ["a"],
                ict_basis.neutral.faces)
    with pytest.raises(InputError, match="ok.glb: no morph target named b"):
        load_artist_basis(ict_basis.neutral, path, names=["b"])


def test_neutral_path_and_mesh_agree(ict_basis, ict_mesh):
    assert ict_mesh.same_topology(ict_basis.neutral)
    np.testing.assert_array_equal(ict_mesh.vertices, ict_basis.neutral.vertices)


def _edited(source: Path, target: Path, edit) -> None:
    """`target`: the OBJ text of `source` with `edit(lines)` applied to its lines."""
    lines = source.read_bytes().split(b"\n")
    target.write_bytes(b"\n".join(edit(lines)))


def _vertex_line(lines, vertex: int) -> int:
    return [i for i, line in enumerate(lines) if line.startswith(b"v ")][vertex]


def test_shapes_that_share_the_neutrals_face_text_are_read_as_load_mesh_reads_them(
        ict_basis, ict_dir, small_dir):
    """Shapes whose face lines are the neutral's text have only their vertices parsed: the
    oracle is load_mesh of each file; CRLF lines and faces written another way
    (v/vt/vn corners) take the whole reader and give the same."""
    from mocap.mesh.mesh import load_mesh

    source = small_dir / "jawOpen.obj"
    _edited(source, small_dir / "crlf.obj", lambda lines: [line + b"\r" for line in lines])
    _edited(source, small_dir / "with_uv.obj", lambda lines: [
        b"f " + b" ".join(c + b"/" + c for c in line.split()[1:]) if line.startswith(b"f ")
        else line for line in lines])
    basis = load_artist_basis(ict_basis.neutral, small_dir)
    for name in basis.names:
        np.testing.assert_array_equal(
            basis.displacements[basis.index(name)],
            load_mesh(small_dir / f"{name}.obj").vertices - ict_basis.neutral.vertices)
    np.testing.assert_array_equal(basis.displacements[basis.index("crlf")],
                                  basis.displacements[basis.index("with_uv")])


def _vertex_lines_edited(edit):
    """An edit of an OBJ's lines that replaces each ``v`` line by the lines `edit` gives."""
    return lambda lines: [out for line in lines
                          for out in (edit(line) if line.startswith(b"v ") else [line])]


#: Vertex lines written other ways, and whether load_mesh then reads the whole file (the
#: others are read by the shapes' own parser).
_VERTEX_WRITINGS = {
    "homogeneous": (_vertex_lines_edited(lambda line: [line + b" 1.0"]), False),
    "trailing_space": (_vertex_lines_edited(lambda line: [line + b" "]), False),
    "two_spaces": (_vertex_lines_edited(lambda line: [line.replace(b" ", b"  ", 1)]), True),
    "normals_between": (_vertex_lines_edited(lambda line: [line, b"vn 0 0 1"]), True),
}


@pytest.mark.parametrize("writing", sorted(_VERTEX_WRITINGS))
def test_shapes_whose_vertex_lines_are_written_other_ways_read_as_load_mesh_reads_them(
        ict_basis, small_dir, monkeypatch, writing):
    """The oracle is load_mesh of the file; the shapes' parser takes the plain ones (it
    does not call load_mesh for them) and leaves the others to load_mesh."""
    import mocap.mesh.mesh as mesh_module

    edit, read_whole = _VERTEX_WRITINGS[writing]
    _edited(small_dir / "jawOpen.obj", small_dir / f"{writing}.obj", edit)
    expected = mesh_module.load_mesh(small_dir / f"{writing}.obj").vertices
    original, reads = mesh_module.load_mesh, []
    monkeypatch.setattr(mesh_module, "load_mesh",
                        lambda path: reads.append(Path(path).name) or original(path))
    basis = load_artist_basis(ict_basis.neutral, small_dir)
    np.testing.assert_array_equal(basis.displacements[basis.index(writing)],
                                  expected - ict_basis.neutral.vertices)
    assert reads == ([f"{writing}.obj"] if read_whole else [])


@pytest.mark.parametrize("edit, error", [
    (lambda lines: lines[:_vertex_line(lines, 9000)] + lines[_vertex_line(lines, 9001):],
     r"bad.obj at line \d+: face indexes vertex 9409, out of range for 9408 vertices"),
    (lambda lines: lines[:_vertex_line(lines, 5)] + [b"v 0 nan 0"]
     + lines[_vertex_line(lines, 5) + 1:], r"bad.obj: 1 vertices have NaN"),
    (lambda lines: lines[:_vertex_line(lines, 7)] + [b"v 0 1"]
     + lines[_vertex_line(lines, 7) + 1:], r"bad.obj at line \d+: vertex line needs 3"),
])
def test_a_shape_with_the_neutrals_faces_but_bad_vertices_is_refused_by_name(
        ict_basis, small_dir, edit, error):
    _edited(small_dir / "jawOpen.obj", small_dir / "bad.obj", edit)
    with pytest.raises(FileFormatError, match=error):
        load_artist_basis(ict_basis.neutral, small_dir)


def test_a_shape_with_the_neutrals_faces_warns_of_its_degenerate_triangles(ict_basis, small_dir):
    a, b, c = ict_basis.neutral.faces[0]
    collapsed = ict_basis.neutral.vertices.copy()
    collapsed[[b, c]] = collapsed[a]
    _edited(small_dir / "jawOpen.obj", small_dir / "flat.obj", lambda lines: [
        b"v %r %r %r" % tuple(map(float, collapsed[i])) if i in (b, c) else line
        for i, line in zip(_vertex_numbers(lines), lines)])
    with pytest.warns(UserWarning, match=r"flat.obj: \d+ degenerate"):
        load_artist_basis(ict_basis.neutral, small_dir)


def _vertex_numbers(lines):
    """Each line's vertex id (-1 for lines that are not vertices)."""
    count = -1
    for line in lines:
        if line.startswith(b"v "):
            count += 1
            yield count
        else:
            yield -1
