"""``mocap2mesh basis``: PCA and quasi-eigen bases of a synthetic retargeted take, end to end."""

from __future__ import annotations

import csv
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from tolerances import BASIS_CLI_MOVES_RTOL, BASIS_CLI_REL

from basis.artist import load_artist_basis
from basis.basis_io import load_basis
from basis.comparison import MOVE_COLUMNS
from basis.quasi_eigen import MISSING_POLICIES
from fit.cli.main import main
from mocap.mesh.mesh import Mesh, save_obj
from mocap.retarget.archive import CONTENTS, save_npz
from mocap.retarget.rbf import build_rbf_operator
from mocap.retarget.retargeting import Retargeting

N_SIDE, N_SHAPES, N_FRAMES = 12, 4, 120
M_PER_CM = 0.01
MARKERS = [14, 19, 26, 31, 52, 57, 63, 76, 81, 88, 112, 117, 125, 130]


def _grid_mesh() -> Mesh:
    """A bumped 12 x 12 grid, Y-up, facing +Z, in cm."""
    x, y = np.meshgrid(np.linspace(-5, 5, N_SIDE), np.linspace(-6, 6, N_SIDE))
    z = 2 * np.exp(-(x ** 2 + y ** 2) / 20)
    ids = np.arange(N_SIDE * N_SIDE).reshape(N_SIDE, N_SIDE)
    a, b, c, d = ids[:-1, :-1].ravel(), ids[:-1, 1:].ravel(), ids[1:, 1:].ravel(), \
        ids[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return Mesh(np.stack([x.ravel(), y.ravel(), z.ravel()], 1), faces, units="cm")


@pytest.fixture(scope="module")
def basis_case(tmp_path_factory):
    """Artist shapes e_i = W a_i, and a take D(t) = sum_i c_i(t) a_i + x(t) b with W b
    orthogonal to every e_i and x(t) centred and uncorrelated with the c_i."""
    folder = tmp_path_factory.mktemp("basis")
    rng = np.random.default_rng(7)
    mesh = _grid_mesh()
    operator = build_rbf_operator(mesh.vertices[MARKERS], mesh.vertices)
    w = np.asarray(operator.matrix)
    a = rng.normal(size=(N_SHAPES, len(MARKERS), 3)) * 0.3
    artist = np.einsum("nm,smc->snc", w, a)
    b = rng.normal(size=(len(MARKERS), 3)) * 0.3
    flat = artist.reshape(N_SHAPES, -1)                     # remove W b's part along the e_i
    coef = np.linalg.lstsq(flat.T, np.einsum("nm,mc->nc", w, b).ravel(), rcond=None)[0]
    b = b - np.einsum("s,smc->mc", coef, a)
    extra = np.einsum("nm,mc->nc", w, b)
    c = rng.normal(size=(N_FRAMES, N_SHAPES)) + 0.5
    x = rng.normal(size=N_FRAMES)
    centred = c - c.mean(axis=0)
    x -= x.mean()
    x -= centred @ np.linalg.lstsq(centred, x, rcond=None)[0]
    x *= 1.2 / x.std()
    disp = np.einsum("ts,smc->tmc", c, a) + x[:, None, None] * b
    labels = tuple(f"m{i}" for i in MARKERS)
    takes = {}
    for content in CONTENTS:
        takes[content] = folder / f"take_{content}.npz"
        save_npz(Retargeting(operator, disp, labels, mesh, 0, np.eye(3), 100.0, 1),
                 takes[content], content=content)
    neutral = folder / "neutral.obj"
    save_obj(mesh, neutral)
    shapes = folder / "shapes"
    shapes.mkdir()
    names = [f"shape{i}" for i in range(N_SHAPES)]
    for name, e in zip(names, artist):
        save_obj(mesh.with_vertices(mesh.vertices + e), shapes / f"{name}.obj")
    xi = np.einsum("nm,tmc->tnc", w, disp).reshape(N_FRAMES, -1)
    mean = xi.mean(axis=0)
    _, s, vt = np.linalg.svd(xi - mean, full_matrices=False)
    return dict(folder=folder, mesh=mesh, neutral=neutral, shapes=shapes, names=names,
                artist=artist, extra=extra / np.linalg.norm(extra), takes=takes,
                mean=mean.reshape(-1, 3), evals=s ** 2 / N_FRAMES, axes=vt)


def _run(case, output, *extra, take="vertices"):
    return main(["basis", str(case["takes"][take]), "--neutral", str(case["neutral"]),
                 "--shapes", str(case["shapes"]), "--units", "cm", "-o", str(output), *extra])


def _table(path: Path) -> list[dict]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _scale(x) -> float:
    return BASIS_CLI_REL * np.abs(x).max()


@pytest.mark.parametrize("missing", MISSING_POLICIES)
@pytest.mark.parametrize("take", CONTENTS)
def test_quasi_eigen_keeps_the_shapes_and_finds_the_extra_axis(basis_case, tmp_path, missing,
                                                               take):
    out = tmp_path / "out"
    images = "shape0,shape2" if missing == "augment" else "none"
    assert _run(basis_case, out, "--missing", missing, "--images", images, take=take) == 0
    evals, artist = basis_case["evals"], basis_case["artist"]
    m = int(np.nonzero(np.cumsum(evals) / evals.sum() >= 0.995)[0][0]) + 1
    assert m == N_SHAPES + 1                          # the data has rank 5, all above 0.5 %

    pca = load_basis(out / "pca.npz")
    assert pca.names == ("pca_mean",) + tuple(f"pc_{j:02d}" for j in range(m))
    np.testing.assert_allclose(pca.displacements[0], basis_case["mean"],
                               atol=_scale(basis_case["mean"]))
    np.testing.assert_allclose(np.sum(pca.displacements[1:] ** 2, axis=(1, 2)), evals[:m],
                               atol=_scale(evals))

    qe = load_basis(out / "qe.npz")
    np.testing.assert_allclose(qe.displacements[:N_SHAPES], artist, atol=_scale(artist))
    extra = basis_case["extra"].ravel()
    rows = _table(out / "moves.csv")
    assert tuple(rows[0]) == MOVE_COLUMNS
    missing_rows = [r for r in rows if r["kind"] == "missing_axis"]
    assert len(missing_rows) == 1
    axis = int(missing_rows[0]["axis"])
    assert abs(basis_case["axes"][axis] @ extra) == pytest.approx(1, abs=BASIS_CLI_REL)
    assert float(missing_rows[0]["variance_share"]) == pytest.approx(
        evals[axis] / evals.sum(), rel=BASIS_CLI_REL)
    for row in rows[:N_SHAPES]:
        assert float(row["relative_move"]) < BASIS_CLI_REL
    if missing == "augment":
        assert qe.names == tuple(basis_case["names"]) + (f"pca_axis_{axis:02d}",)
        assert abs(qe.displacements[-1].ravel() @ extra) == pytest.approx(1, abs=BASIS_CLI_REL)
    else:
        assert qe.names == tuple(basis_case["names"])

    mesh = basis_case["mesh"]                                # glTF is in metres
    in_metres = Mesh(mesh.vertices * M_PER_CM, mesh.faces, units="m")
    for stem, basis in (("qe", qe), ("pca", pca)):
        glb = load_artist_basis(in_metres, out / f"{stem}.glb")
        assert glb.names == basis.names
        np.testing.assert_allclose(glb.displacements / M_PER_CM, basis.displacements,
                                   atol=_scale(basis.displacements))
        objs = load_basis(out / stem)
        assert objs.names == basis.names
        np.testing.assert_allclose(objs.displacements, basis.displacements,
                                   atol=_scale(basis.displacements))

    coverage = cv2.imread(str(out / "coverage.png"))
    assert coverage.shape[0] > 300 and coverage.shape[1] > 600
    if images == "none":
        assert not (out / "comparison").exists()
        return
    pictures = sorted(p.name for p in (out / "comparison").iterdir())
    assert pictures == ["shape0.png", "shape2.png"]
    image = cv2.imread(str(out / "comparison" / "shape0.png"))
    assert image.shape[0] > 300 and image.shape[1] > 900 and image.std() > 10


def test_fewer_components_move_the_shapes_as_a_dense_projection_says(basis_case, tmp_path):
    out = tmp_path / "out"
    assert _run(basis_case, out, "-m", "2", "--images", "none", "--missing-eps", "0") == 0
    assert not (out / "comparison").exists()
    axes, mean = basis_case["axes"][:2], basis_case["mean"].ravel()
    artist = basis_case["artist"].reshape(N_SHAPES, -1)
    qe = mean + ((artist - mean) @ axes.T) @ axes            # eq. 3-4 on the dense SVD
    moves = np.linalg.norm((qe - artist).reshape(N_SHAPES, -1, 3), axis=2)
    rows = _table(out / "moves.csv")
    assert [r["kind"] for r in rows] == ["artist"] * N_SHAPES
    got = np.array([[float(r["relative_move"]), float(r["max_vertex_move"])] for r in rows])
    expected = np.column_stack([np.linalg.norm(moves, axis=1) / np.linalg.norm(artist, axis=1),
                                moves.max(axis=1)])
    np.testing.assert_allclose(got, expected, rtol=BASIS_CLI_MOVES_RTOL)
    assert np.all(got[:, 0] > 0.01)
    np.testing.assert_allclose(load_basis(out / "qe.npz").displacements.reshape(N_SHAPES, -1),
                               qe, atol=_scale(qe))


def _sub_mesh(mesh: Mesh, n: int) -> Mesh:
    return Mesh(mesh.vertices[:n], mesh.faces[(mesh.faces < n).all(axis=1)], units="cm")


def _bad_shape(case, tmp_path):
    shapes = tmp_path / "shapes"
    shapes.mkdir()
    for name in case["names"]:
        (shapes / f"{name}.obj").write_bytes((case["shapes"] / f"{name}.obj").read_bytes())
    small = _sub_mesh(case["mesh"], 24)
    save_obj(small, shapes / "shape1.obj")
    return ["--shapes", str(shapes)], r"shape1\.obj"


def _other_mesh_take(case, tmp_path):
    mesh = _sub_mesh(case["mesh"], 100)
    op = build_rbf_operator(mesh.vertices[[0, 5, 30, 40, 62, 75, 90, 99]], mesh.vertices)
    path = tmp_path / "other.npz"
    save_npz(Retargeting(op, np.zeros((5, 8, 3)), tuple("abcdefgh"), mesh, 0, np.eye(3), 100.0,
                         0), path)
    return [str(path)], r"other\.npz: vertices has shape \(5, 100, 3\).*144 vertices"


def _capture_without_binding(case, tmp_path):
    path = tmp_path / "capture.c3d"
    path.write_bytes(b"")
    return [str(path)], r"capture\.c3d is not a retargeted \.npz: a capture needs --binding"


def _unknown_image(case, tmp_path):
    return ["--images", "shape0,nose"], r"no artist shape 'nose'"


def _too_many_components(case, tmp_path):
    return ["-m", "99"], r"n_components must be at most"


@pytest.mark.parametrize("make", [_bad_shape, _other_mesh_take, _capture_without_binding,
                                  _unknown_image, _too_many_components])
def test_bad_input_exits_1_naming_the_fault(basis_case, tmp_path, capsys, make):
    extra, message = make(basis_case, tmp_path)
    argv = ["basis", str(basis_case["takes"]["vertices"]), "--neutral", str(basis_case["neutral"]),
            "--shapes", str(basis_case["shapes"]), "--units", "cm", "-o", str(tmp_path / "out")]
    if extra[0].endswith((".npz", ".c3d")):
        argv[1] = extra.pop(0)
    argv += extra
    if "--shapes" in extra:
        i = argv.index("--shapes")
        del argv[i:i + 2]
    assert main(argv) == 1
    assert re.search(message, capsys.readouterr().err)
