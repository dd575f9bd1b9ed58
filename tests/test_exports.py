"""Exports of a solved take (fit.exports): weights CSV/DataFrame, mesh sequences."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from tolerances import FLOAT32_REL

from fit.exports import (
    read_mesh_sequence,
    read_weights_csv,
    weights_frame,
    write_mesh_sequence,
    write_weights_csv,
)
from fit.solve.weights import solve_weights
from mocap.errors import FileFormatError, InputError
from mocap.mesh.mesh import Mesh, load_mesh, save_obj
from mocap.take import Take

NAMES = ("jawOpen", "smile L", "blink")


@pytest.fixture()
def weights() -> np.ndarray:
    return np.random.default_rng(0).uniform(-0.1, 1.1, size=(37, 3))


@pytest.fixture()
def neutral() -> Mesh:
    rng = np.random.default_rng(1)
    return Mesh(rng.normal(size=(6, 3)), [[0, 1, 2], [2, 3, 4], [3, 4, 5]], units="cm")


@pytest.fixture()
def displacements() -> np.ndarray:
    return np.random.default_rng(2).normal(scale=0.5, size=(3, 6, 3))


def test_frame_and_time_follow_the_take(weights):
    take = Take(("m",), np.zeros((len(weights), 1, 3)), rate=120.0, first_frame=240)
    table = weights_frame(weights, NAMES, rate=take.rate, first_frame=take.first_frame)
    assert table.index.name == "frame" and list(table.columns) == ["time", *NAMES]
    np.testing.assert_array_equal(table.index.to_numpy(), take.frames)
    np.testing.assert_array_equal(table["time"].to_numpy(), take.times)
    np.testing.assert_array_equal(table[list(NAMES)].to_numpy(), weights)


def test_csv_round_trip_is_exact(weights, tmp_path):
    path = tmp_path / "w.csv"
    write_weights_csv(path, weights, NAMES, rate=60.0, first_frame=5)
    with open(path, newline="") as fh:  # plain csv module as the oracle of the layout
        rows = list(csv.reader(fh))
    assert rows[0] == ["frame", "time", *NAMES] and len(rows) == len(weights) + 1
    assert [int(r[0]) for r in rows[1:]] == list(range(5, 5 + len(weights)))
    np.testing.assert_array_equal(np.array([r[2:] for r in rows[1:]], dtype=float), weights)
    back = read_weights_csv(path)
    expected = weights_frame(weights, NAMES, rate=60.0, first_frame=5)
    assert back.index.name == "frame" and list(back.columns) == list(expected.columns)
    np.testing.assert_array_equal(back.index.to_numpy(), expected.index.to_numpy())
    np.testing.assert_array_equal(back.to_numpy(), expected.to_numpy())


def test_a_weight_solution_is_accepted(tmp_path):
    rng = np.random.default_rng(4)
    basis = rng.normal(size=(12, 3))
    solution = solve_weights(basis, rng.normal(size=(8, 12)), lower=0.0, upper=1.0)
    path = tmp_path / "w.csv"
    write_weights_csv(path, solution, NAMES, rate=100.0)
    np.testing.assert_array_equal(read_weights_csv(path)[list(NAMES)].to_numpy(),
                                  solution.weights)


@pytest.mark.parametrize("materialize", [False, True])
def test_mesh_sequence_evaluates_like_a_loop(neutral, displacements, weights, tmp_path,
                                             materialize):
    path = tmp_path / "seq.npz"
    write_mesh_sequence(path, neutral, displacements, weights, materialize=materialize,
                        names=NAMES, rate=60.0, first_frame=3)
    seq = read_mesh_sequence(path)
    expected = np.stack([neutral.vertices + sum(w[i] * displacements[i] for i in range(3))
                         for w in weights])  # brute force, frame by frame, float64
    atol = FLOAT32_REL * np.abs(expected).max()
    assert seq.n_frames == len(weights) and (seq.rate, seq.first_frame) == (60.0, 3)
    assert seq.units == "cm" and seq.names == NAMES
    np.testing.assert_array_equal(seq.faces, neutral.faces)
    np.testing.assert_allclose(seq.vertices(), expected, rtol=0, atol=atol)
    np.testing.assert_allclose(seq.vertices(7), expected[7], rtol=0, atol=atol)
    np.testing.assert_allclose(seq.vertices([2, 9]), expected[[2, 9]], rtol=0, atol=atol)
    with np.load(path) as z:  # float32, faces included, the documented keys
        stored = ["vertices"] if materialize else ["neutral", "displacements", "weights"]
        assert all(z[k].dtype == np.float32 for k in stored)
        assert ("vertices" in z.files) == materialize
        if not materialize:  # the documented evaluation with plain numpy
            v = z["neutral"] + np.tensordot(z["weights"][7], z["displacements"], 1)
            np.testing.assert_allclose(v, expected[7], rtol=0, atol=atol)


def test_mesh_sequence_keeps_its_head_motion(neutral, displacements, weights, tmp_path):
    rng = np.random.default_rng(6)
    rotation = Rotation.random(len(weights), random_state=7).as_matrix()
    translation = rng.normal(0.0, 3.0, (len(weights), 3))
    path = tmp_path / "moving.npz"
    write_mesh_sequence(path, neutral, displacements, weights, rotation=rotation,
                        translation=translation)
    seq = read_mesh_sequence(path)
    placed = np.stack([v @ r.T + t for v, r, t in zip(seq.vertices(), rotation, translation)])
    np.testing.assert_allclose(seq.placed_vertices(), placed, rtol=0, atol=1e-12)
    np.testing.assert_allclose(seq.placed_vertices(4), placed[4], rtol=0, atol=1e-12)
    with pytest.raises(InputError, match="rotation and translation go together"):
        write_mesh_sequence(path, neutral, displacements, weights, rotation=rotation)
    with np.load(path) as z:
        arrays = dict(z)
    arrays["translation"] = arrays["translation"][:-1]
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(FileFormatError, match=r"head motion must be rotation \(\d+, 3, 3\)"):
        read_mesh_sequence(tmp_path / "bad.npz")


def test_materialized_in_chunks_matches_compact(neutral, displacements, tmp_path):
    weights = np.random.default_rng(5).random((600, 3))  # more than one chunk of frames
    write_mesh_sequence(tmp_path / "a.npz", neutral, displacements, weights)
    write_mesh_sequence(tmp_path / "b.npz", neutral, displacements, weights, materialize=True)
    a, b = read_mesh_sequence(tmp_path / "a.npz"), read_mesh_sequence(tmp_path / "b.npz")
    assert a.rate is None and b.n_frames == 600
    np.testing.assert_allclose(a.vertices(), b.vertices(), rtol=0,
                               atol=2 * FLOAT32_REL * np.abs(b.vertices()).max())


@pytest.mark.parametrize("bad, message", [
    (dict(names=NAMES[:2]), "names has 2 entries but weights has 3 shapes"),
    (dict(names=("time", "a", "b")), "shape name 'time' is reserved"),
    (dict(weights=np.full((4, 3), np.nan)), r"weights contain NaN \(4 frames, first at frame "
                                            r"index 0"),
    (dict(weights=np.zeros((4, 2))), r"names has 3 entries but weights has 2 shapes"),
    (dict(rate=0.0), "rate must be positive"),
    (dict(first_frame=1.5), "first_frame must be an integer"),
])
def test_weights_table_refuses_bad_input(weights, tmp_path, bad, message):
    options = dict(rate=60.0, first_frame=1)
    options.update((k, v) for k, v in bad.items() if k in options)
    data = (bad.get("weights", weights), bad.get("names", NAMES))
    with pytest.raises(InputError, match=message):
        weights_frame(*data, **options)
    with pytest.raises(InputError, match=message):
        write_weights_csv(tmp_path / "w.csv", *data, **options)
    assert not (tmp_path / "w.csv").exists()


def test_mesh_sequence_refuses_bad_input(neutral, displacements, weights, tmp_path):
    path = tmp_path / "seq.npz"
    with pytest.raises(InputError, match=r"weights must have shape \(any, 3\)"):
        write_mesh_sequence(path, neutral, displacements, weights[:, :2])
    with pytest.raises(InputError, match="weights contain NaN"):
        write_mesh_sequence(path, neutral, displacements, np.full_like(weights, np.nan))
    with pytest.raises(InputError, match=r"displacements must have shape \(any, 6, 3\)"):
        write_mesh_sequence(path, neutral, displacements[:, :5], weights)
    with pytest.raises(InputError, match="names has 2 entries but displacements has 3"):
        write_mesh_sequence(path, neutral, displacements, weights, names=NAMES[:2])
    with pytest.raises(InputError, match="neutral must be a Mesh"):
        write_mesh_sequence(path, neutral.vertices, displacements, weights)
    assert not path.exists()


def test_outputs_name_the_file_they_cannot_write(neutral, displacements, weights, tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    with pytest.raises(InputError, match=r"a_file/w\.csv: cannot write"):
        write_weights_csv(blocker / "w.csv", weights, NAMES, rate=60.0)
    with pytest.raises(InputError, match=r"a_file/s\.npz: cannot write"):
        write_mesh_sequence(blocker / "s.npz", neutral, displacements, weights)
    src = tmp_path / "neutral.obj"
    save_obj(neutral, src)
    with pytest.raises(InputError, match="refusing to overwrite an input file"):
        write_mesh_sequence(src, load_mesh(src), displacements, weights)


def test_malformed_files_are_reported(tmp_path):
    path = tmp_path / "w.csv"
    path.write_text("frame,t,a\n1,0,0.5\n")
    with pytest.raises(FileFormatError, match=r"w\.csv at line 1: expected the columns frame"):
        read_weights_csv(path)
    path.write_text("frame,time,a\n1,0,0.5\n2,0.01,oops\n")
    with pytest.raises(FileFormatError, match=r"w\.csv at line 3: column 'a': 'oops' is empty"):
        read_weights_csv(path)
    path.write_text("frame,time,a\n1,0,0.5\n2,,0.5\n")
    with pytest.raises(FileFormatError, match=r"line 3: column 'time': '' is empty or not a"):
        read_weights_csv(path)
    path.write_text("frame,time,a\n2,0,0.5\n2,0.01,0.5\n")
    with pytest.raises(FileFormatError, match="frame numbers must be increasing integers"):
        read_weights_csv(path)
    with pytest.raises(FileFormatError, match="absent.csv: cannot read weights CSV"):
        read_weights_csv(tmp_path / "absent.csv")
    seq = tmp_path / "seq.npz"
    np.savez(seq, faces=np.zeros((1, 3), int))
    with pytest.raises(FileFormatError, match="seq.npz: not a mesh sequence: members"):
        read_mesh_sequence(seq)
    seq.write_bytes(b"junk")
    with pytest.raises(FileFormatError, match="seq.npz: cannot read mesh sequence"):
        read_mesh_sequence(seq)


def test_weights_csv_is_the_text_pandas_writes(tmp_path):
    """The block-formatted writer against pandas' own CSV of the same table (the oracle):
    the same bytes, header quoting included, for more rows than one block."""
    rng = np.random.default_rng(3)
    w = rng.random((9000, 5))
    w[::7, 0], w[::5, 1], w[1, 2], w[2, 3] = 0.0, 1.0, 1e-300, -2.5e17
    names = ["jaw", 'a,"b"', "c d", "é", "x"]
    path = tmp_path / "w.csv"
    write_weights_csv(path, w, names, rate=59.94, first_frame=-3)
    expected = weights_frame(w, names, rate=59.94, first_frame=-3).to_csv(lineterminator="\n")
    assert path.read_text(encoding="utf-8") == expected
    np.testing.assert_array_equal(read_weights_csv(path)[names].to_numpy(), w)


@pytest.mark.parametrize("member, bad, message", [
    ("weights", np.nan, r"weights contain NaN \(1 frames, first at frame index 2, shape 1\)"),
    ("weights", np.inf, "weights contains infinite values"),
    ("weights", 1e39, r"weights hold values beyond the range of float32"),
    ("displacements", np.nan, r"displacements contains NaN \(first at index \(1, 4, 2\)\)"),
    ("displacements", -np.inf, "displacements contains infinite values"),
    ("displacements", -1e39, r"displacements hold values beyond the range of float32"),
])
def test_mesh_sequence_refuses_values_it_cannot_store(neutral, displacements, weights,
                                                     tmp_path, member, bad, message):
    """The compact form's values are checked as they are written: the error still names
    the first bad value, and nothing is left behind."""
    data = dict(displacements=displacements.copy(), weights=weights.copy())
    data[member][(2, 1) if member == "weights" else (1, 4, 2)] = bad
    with pytest.raises(InputError, match=message):
        write_mesh_sequence(tmp_path / "seq.npz", neutral, **data)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("scale", [1e39, 1e20])
def test_materialized_sequence_refuses_vertices_beyond_float32(neutral, displacements, weights,
                                                               tmp_path, scale):
    """Finite float64 inputs whose vertices leave float32's range (a displacement
    beyond it, or finite factors whose product overflows) are refused, not stored as
    inf, and nothing is left behind."""
    big_d, big_w = displacements.copy(), weights.copy()
    big_d[1, 4, 2] = scale
    big_w[2, 1] = scale if scale < 1e38 else 1.0
    assert np.isfinite(big_d).all() and np.isfinite(big_w).all()
    with np.errstate(over="ignore"):
        assert np.isinf(np.float32(big_w[2] @ big_d.reshape(len(big_d), -1))).any()
    with pytest.raises(InputError, match="vertices hold values beyond the range of float32"):
        write_mesh_sequence(tmp_path / "seq.npz", neutral, big_d, big_w, materialize=True)
    assert list(tmp_path.iterdir()) == []
