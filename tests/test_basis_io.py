"""Saving and loading named bases (basis.basis_io): npz and OBJ-directory round trips."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from tolerances import FLOAT32_REL, OBJ_DISPLACEMENT_MM

from basis.artist import ArtistBasis, load_artist_basis
from basis.basis_io import BASIS_DTYPES, load_basis, save_basis, shape_file_stems
from mocap.errors import FileFormatError, InputError
from mocap.mesh.mesh import Mesh, load_mesh

#: Quads and one triangle: the polygon map must survive both forms.
_OBJ = """v 0 0 0
v 1 0 0
v 2 0 0
v 0 1 0
v 1 1 0
v 2 1 0
v 1 2 0
f 1 2 5 4
f 2 3 6 5
f 4 5 7
"""


@pytest.fixture()
def small_basis(tmp_path) -> ArtistBasis:
    (tmp_path / "in").mkdir()
    src = tmp_path / "in" / "neutral_src.obj"
    src.write_text(_OBJ)
    mesh = load_mesh(src, units="mm")
    rng = np.random.default_rng(3)
    neutral = mesh.with_vertices(mesh.vertices + rng.normal(scale=0.3, size=(7, 3)))
    neutral = Mesh(neutral.vertices, mesh.faces, mesh.face_polygon, mesh.polygon_sizes,
                         units="mm", path=str(src))
    return ArtistBasis(("jawOpen", "brow/up L", "NEUTRAL"), neutral,
                       rng.normal(scale=0.1, size=(3, 7, 3)))


def _printed(x: np.ndarray) -> np.ndarray:
    """What OBJ's 10 significant digits keep of `x` (the oracle of the text form)."""
    return np.array([float(f"{v:.10g}") for v in np.ravel(x)]).reshape(np.shape(x))


def _same_mesh(a, b) -> None:
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_array_equal(a.face_polygon, b.face_polygon)
    np.testing.assert_array_equal(a.polygon_sizes, b.polygon_sizes)
    assert a.units == b.units


@pytest.mark.parametrize("dtype", BASIS_DTYPES)
def test_npz_round_trip_is_exact(small_basis, tmp_path, dtype):
    path = tmp_path / "basis.npz"
    save_basis(small_basis, path, dtype=dtype)
    back = load_basis(path)
    assert back.names == small_basis.names
    _same_mesh(back.neutral, small_basis.neutral)
    np.testing.assert_array_equal(back.neutral.vertices, small_basis.neutral.vertices)
    np.testing.assert_array_equal(back.displacements,
                                  small_basis.displacements.astype(dtype).astype(np.float64))
    with np.load(path) as raw:  # the documented layout, read with plain numpy
        assert raw["displacements"].dtype == np.dtype(dtype)
        assert raw["polygon_sizes"].tolist() == [4, 4, 3]
        assert raw["names"].tolist() == list(small_basis.names) and str(raw["units"]) == "mm"


def test_obj_directory_round_trips_to_printed_precision(small_basis, tmp_path):
    folder = tmp_path / "out"
    save_basis(small_basis, folder)
    back = load_basis(folder)
    assert back.names == small_basis.names
    _same_mesh(back.neutral, small_basis.neutral)
    v0 = small_basis.neutral.vertices
    np.testing.assert_array_equal(back.neutral.vertices, _printed(v0))
    np.testing.assert_array_equal(back.displacements,
                                  _printed(v0 + small_basis.displacements) - _printed(v0))
    faces = [line for line in (folder / "neutral.obj").read_text().splitlines()
             if line.startswith("f ")]
    assert faces == ["f 1 2 5 4", "f 2 3 6 5", "f 4 5 7"]  # quads kept
    manifest = json.loads((folder / "basis.json").read_text())
    assert [s["name"] for s in manifest["shapes"]] == list(small_basis.names)
    # the same files through the artist reader, by the manifest's file stems
    stems = [Path(s["file"]).stem for s in manifest["shapes"]]
    artist = load_artist_basis(folder / "neutral.obj", folder, names=stems)
    np.testing.assert_array_equal(artist.displacements, back.displacements)


def test_directory_without_manifest_names_shapes_by_stem(small_basis, tmp_path):
    folder = tmp_path / "out"
    save_basis(small_basis, folder)
    (folder / "basis.json").unlink()
    back = load_basis(folder, units="mm")
    stems = shape_file_stems(small_basis.names)
    assert back.names == tuple(sorted(stems)) and back.neutral.units == "mm"
    order = [stems.index(n) for n in back.names]
    np.testing.assert_allclose(back.displacements, small_basis.displacements[order],
                               atol=OBJ_DISPLACEMENT_MM)


def test_file_stems_are_safe_unique_and_never_neutral():
    names = ["jawOpen", "brow/up L", "brow:up L", "NEUTRAL", "neutral", ".hidden", "",
             "JAWOPEN", "a b"]
    stems = shape_file_stems(names)
    assert len(stems) == len(names)
    assert all(re.fullmatch(r"[A-Za-z0-9_-][A-Za-z0-9_.-]*", s) for s in stems)
    lowered = [s.lower() for s in stems]
    assert len(set(lowered)) == len(stems) and "neutral" not in lowered
    assert stems[0] == "jawOpen"  # safe names are kept


def test_saving_again_replaces_a_saved_directory_only(small_basis, tmp_path):
    folder = tmp_path / "out"
    save_basis(small_basis, folder)
    smaller = ArtistBasis(small_basis.names[:1], small_basis.neutral,
                          small_basis.displacements[:1])
    save_basis(smaller, folder)
    assert load_basis(folder).names == small_basis.names[:1]
    assert sorted(p.name for p in folder.iterdir()) == ["basis.json", "jawOpen.obj",
                                                        "neutral.obj"]
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    other = tmp_path / "mine"
    other.mkdir()
    with pytest.raises(InputError, match="is not a basis directory written by save_basis"):
        save_basis(small_basis, other)


def test_never_writes_over_an_input(small_basis, tmp_path):
    path = tmp_path / "basis.npz"
    save_basis(small_basis, path)
    loaded = load_basis(path)
    with pytest.raises(InputError, match="refusing to overwrite an input file"):
        save_basis(loaded, path)
    folder = tmp_path / "out"
    save_basis(small_basis, folder)
    with pytest.raises(InputError, match="refusing to replace a directory holding the input"):
        save_basis(load_basis(folder), folder)


def test_unwritable_directory_names_the_file(small_basis, tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    with pytest.raises(InputError, match=r"a_file/basis\.npz: cannot write"):
        save_basis(small_basis, blocker / "basis.npz")
    with pytest.raises(InputError, match=r"a_file/out: cannot write"):
        save_basis(small_basis, blocker / "out")


def test_save_validates_its_arguments(small_basis, tmp_path):
    with pytest.raises(InputError, match="basis must be an ArtistBasis"):
        save_basis(small_basis.displacements, tmp_path / "b.npz")
    with pytest.raises(InputError, match="dtype must be one of"):
        save_basis(small_basis, tmp_path / "b.npz", dtype="float16")


def test_load_errors_name_the_file(small_basis, tmp_path):
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(FileFormatError, match="junk.npz: cannot read basis archive"):
        load_basis(junk)
    partial = tmp_path / "partial.npz"
    np.savez(partial, names=np.array(["a"]))
    with pytest.raises(FileFormatError, match="partial.npz: not a basis archive: members"):
        load_basis(partial)
    path = tmp_path / "bad.npz"
    save_basis(small_basis, path)
    with np.load(path) as z:
        arrays = dict(z)
    arrays["displacements"] = arrays["displacements"][:, :5]
    np.savez(path, **arrays)
    with pytest.raises(FileFormatError, match="bad.npz: inconsistent basis"):
        load_basis(path)
    with pytest.raises(InputError, match="a basis is an .npz file or a directory"):
        load_basis(tmp_path / "absent.npz")
    folder = tmp_path / "out"
    save_basis(small_basis, folder)
    (folder / "basis.json").write_text("{")
    with pytest.raises(FileFormatError, match=r"basis\.json: not a basis manifest"):
        load_basis(folder)
    (folder / "basis.json").unlink()
    (folder / "neutral.obj").unlink()
    with pytest.raises(FileFormatError, match="neutral.obj: a basis directory needs"):
        load_basis(folder)


def test_ict_expressions_round_trip(ict_neutral_path, ict_expressions_dir, tmp_path):
    small_basis = load_artist_basis(ict_neutral_path, ict_expressions_dir,
                              names=["jawOpen", "mouthSmile_L"], units="cm")
    save_basis(small_basis, tmp_path / "ict.npz", dtype="float32")
    save_basis(small_basis, tmp_path / "ict")
    for back in (load_basis(tmp_path / "ict.npz"), load_basis(tmp_path / "ict")):
        assert back.names == small_basis.names and back.neutral.units == "cm"
        _same_mesh(back.neutral, small_basis.neutral)
        assert back.neutral.polygon_sizes.max() == 4
        np.testing.assert_allclose(back.displacements, small_basis.displacements, rtol=0,
                                   atol=FLOAT32_REL * np.abs(small_basis.neutral.vertices).max())
