"""One PCA/QE basis for every take of a session (``[basis] scope = "session"``), and the
warnings of ``run`` on stderr, in the manifest and in the report.

Oracle: a dense SVD of the mesh sequences of the takes materialized (Ξ_k = W_k D_k,
each take through its own operator) and concatenated; numpy's own statistics.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import html
import io
import json
import re
import shutil
import warnings

import numpy as np
import pytest
from helpers import stub_take
from scipy.linalg import subspace_angles, svd
from tolerances import EXACT_FLOAT64, PCA_ANGLE_RAD, PCA_IMPLICIT_RTOL

from basis.basis_io import load_basis
from basis.pca import PCAModel, marker_moments, pca_from_operator, pca_from_operators, pool_moments
from fit.cli.main import main
from fit.demo import demo_config_toml, make_demo_session
from fit.pipeline import BasisOptions, Reconstruction, kept_takes
from fit.pipeline.config import load_run_config
from fit.pipeline.session import run_takes
from fit.pipeline.session_basis import TakeMoments, session_basis
from mocap.errors import InputError

#: Relative accuracy of a basis saved as float32 (its shapes are written in float32).
FLOAT32_REL = 1e-6
TAKES = ("a", "b", "c")


def dense_pooled_pca(sequences):
    """Mean, eigenvalues (1/T), components (rows) and total variance of the pooled frames."""
    flat = np.concatenate([x.reshape(len(x), -1) for x in sequences])
    mean = flat.mean(axis=0)
    _, s, vt = svd(flat - mean, full_matrices=False)
    return mean, s ** 2 / len(flat), vt, np.sum((flat - mean) ** 2) / len(flat)


def random_session(seed=0, n_vertices=40, n_markers=6, frames=(50, 30, 20)):
    """Operators of one mesh and marker displacements of different means, one per take."""
    rng = np.random.default_rng(seed)
    ops = [rng.normal(size=(n_vertices, n_markers)) for _ in frames]
    disps = [rng.normal(size=(t, n_markers, 3)) * rng.uniform(0.5, 2.0) + rng.normal(size=3)
             for t in frames]
    return ops, disps


# ---------------------------------------------------------------- the pooled PCA itself

def test_pooled_pca_is_the_dense_pca_of_the_concatenated_sequences():
    ops, disps = random_session()
    model = pca_from_operators(ops, disps)
    xi = [np.einsum("nm,tmc->tnc", w, d) for w, d in zip(ops, disps)]
    mean, evals, vt, total = dense_pooled_pca(xi)
    m = model.n_components
    assert model.n_frames == 100 and m == 54              # 3 takes x 3 x 6 markers
    np.testing.assert_allclose(model.mean.ravel(), mean, rtol=PCA_IMPLICIT_RTOL, atol=0)
    np.testing.assert_allclose(model.eigenvalues, evals[:m], rtol=PCA_IMPLICIT_RTOL)
    assert model.total_variance == pytest.approx(total, rel=PCA_IMPLICIT_RTOL)
    comps = model.components.reshape(m, -1)
    np.testing.assert_allclose(np.abs(np.sum(comps * vt[:m], axis=1)), 1.0,
                               rtol=0, atol=PCA_IMPLICIT_RTOL)
    assert subspace_angles(comps.T, vt[:m].T).max() < PCA_ANGLE_RAD


def test_moments_stand_for_the_frames_and_one_take_is_the_take_pca():
    ops, disps = random_session(seed=1)
    by_frames = pca_from_operators(ops, disps)
    by_moments = pca_from_operators(ops, [marker_moments(d) for d in disps])
    np.testing.assert_array_equal(by_frames.components, by_moments.components)
    one = pca_from_operators(ops[:1], disps[:1])
    alone = pca_from_operator(ops[0], disps[0])
    for name in ("mean", "components", "eigenvalues"):
        np.testing.assert_array_equal(getattr(one, name), getattr(alone, name))
    assert one.sha256() == alone.sha256() != by_frames.sha256()


def test_marker_moments_match_numpy():
    d = random_session(seed=2)[1][0]
    moments = marker_moments(d)
    flat = d.reshape(len(d), -1)
    np.testing.assert_allclose(moments.mean.ravel(), flat.mean(axis=0), rtol=EXACT_FLOAT64)
    np.testing.assert_allclose(moments.covariance, np.cov(flat.T, bias=True),
                               rtol=EXACT_FLOAT64, atol=EXACT_FLOAT64)


@pytest.mark.parametrize("edit, match", [
    (lambda o, d: ([], []), "operators is empty: give one operator per take"),
    (lambda o, d: (o, d[:2]), "3 operators but 2 takes of displacements"),
    (lambda o, d: (o[:1] + [o[1][:-1]] + o[2:], d),
     r"operators\[1\] has 39 rows \(vertices\), operators\[0\] 40: the takes must share a mesh"),
    (lambda o, d: (o, d[:1] + [d[1][:, :5]] + d[2:]),
     r"take 1: operator \(40, 6\) maps 6 markers but its displacements have 5"),
    (lambda o, d: (o, d[:2] + [np.where(np.arange(20)[:, None, None] == 4, np.nan, d[2])]),
     "frame 4 has NaN"),
    (lambda o, d: ([np.zeros_like(w) for w in o], d), "every operator is all zeros"),
    (lambda o, d: (o[:1] + [np.full_like(o[1], np.inf)] + o[2:], d),
     r"operators\[1\] contains infinite values"),
])
def test_pooled_pca_errors(edit, match):
    with pytest.raises(InputError, match=match):
        pca_from_operators(*edit(*random_session()))


@pytest.mark.parametrize("options, match", [
    ({"n_components": 55}, r"the operators of the takes have numerical rank 18: at most 54 "
                           r"components exist, got n_components=55"),
    ({"n_components": 5, "coverage": 0.9}, "give n_components or coverage, not both"),
    ({"coverage": 0.0}, r"coverage must be in \(0, 1\], got 0.0"),
])
def test_pooled_pca_component_errors(options, match):
    ops, disps = random_session()
    with pytest.raises(InputError, match=match):
        pca_from_operators(ops, disps, **options)


def test_session_basis_errors():
    ops, disps = random_session()
    takes = [TakeMoments(n, w, marker_moments(d)) for n, w, d in zip(TAKES, ops, disps)]
    with pytest.raises(InputError, match="a session basis needs at least one take"):
        session_basis([])
    odd = TakeMoments("d", ops[0][:, :5], marker_moments(disps[0][:, :5]))
    with pytest.raises(InputError, match=r"different numbers of face markers \[5, 6\]"):
        session_basis(takes + [odd])
    with pytest.raises(InputError, match=r"basis.pca_components = 60 is more than the 54 "
                                         r"components the session's mesh sequences can have "
                                         r"\(3 takes\)"):
        session_basis(takes, BasisOptions(pca_components=60))
    basis = session_basis(takes, BasisOptions(pca_components=7))
    assert basis.pca.n_components == 7 and basis.takes == TAKES and basis.frames == (50, 30, 20)
    full = pca_from_operators(ops, disps)
    by_coverage = session_basis(takes, BasisOptions(pca_coverage=0.9))
    assert by_coverage.pca.n_components == full.n_for_coverage(0.9)
    np.testing.assert_allclose(by_coverage.pca.components,       # the BLAS's rounding only
                               full.components[:by_coverage.pca.n_components], rtol=0,
                               atol=EXACT_FLOAT64)
    with pytest.raises(InputError, match="scope must be one of"):
        BasisOptions(scope="shot")


# ---------------------------------------------------------------- a session through `run`

@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """Three takes of the demo face (three performances), run with scope = "session"."""
    root = tmp_path_factory.mktemp("session")
    for seed, name in zip((7, 8, 9), TAKES):
        made = make_demo_session(root / f"made{seed}", seed=seed, seconds=2.0, n_gaps=4)
        shutil.copy(made.paths["capture"], root / f"{name}.c3d")
    for name in ("markerset.toml", "neutral.obj", "landmarks.toml"):
        shutil.copy(root / "made7" / name, root / name)
    shutil.copytree(root / "made7" / "shapes", root / "shapes")
    text = demo_config_toml(".", "out").replace(
        '"./capture.c3d"', ", ".join(f'"{t}.c3d"' for t in TAKES)).replace(
        "video = true", "video = false")
    path = root / "run.toml"
    path.write_text(text, encoding="utf-8")
    stderr = io.StringIO()
    with contextlib.redirect_stderr(stderr):
        code = main(["run", str(path), "-j", "2"])     # the shared basis pickled to workers
    manifest = json.loads((root / "out" / "manifest.json").read_text())
    return dict(root=root, path=path, code=code, manifest=manifest, stderr=stderr.getvalue())


def test_every_take_is_fitted_in_one_basis(session):
    manifest, out = session["manifest"], session["root"] / "out"
    assert session["code"] == 0
    shared = manifest["session_basis"]
    assert shared["scope"] == "session" and list(shared["takes"]) == list(TAKES)
    assert shared["n_frames"] == sum(shared["takes"].values())
    for take in TAKES:
        record = manifest["takes"][take]
        assert record["status"] == "ok"
        assert record["basis"] == {"scope": "session", "pca_sha256": shared["sha256"]}
        assert record["pca_components"] == shared["n_components"]
    for name in ("PCA", "QE"):
        first = load_basis(out / TAKES[0] / f"basis-{name}.npz")
        for take in TAKES[1:]:
            other = load_basis(out / take / f"basis-{name}.npz")
            assert other.names == first.names
            np.testing.assert_array_equal(other.displacements, first.displacements)


@pytest.fixture(scope="module")
def prepared(session):
    """The reconstruction of the run and its takes through ingest, bind and retarget."""
    recon = Reconstruction.from_config(load_run_config(session["path"]))
    return recon, [recon.prepare(session["root"] / f"{t}.c3d") for t in TAKES]


def test_the_session_pca_is_the_dense_pca_of_the_takes_pooled(session, prepared):
    """Each take's mesh sequence W_k D_k materialized, all concatenated, a dense SVD."""
    xi = [np.einsum("nm,tmc->tnc", np.asarray(p.retargeted.operator.matrix),
                    p.retargeted.displacements) for p in prepared[1]]
    mean, evals, vt, total = dense_pooled_pca(xi)
    shared = session["manifest"]["session_basis"]
    m = shared["n_components"]
    assert shared["n_frames"] == sum(len(x) for x in xi)
    assert shared["total_variance"] == pytest.approx(total, rel=PCA_IMPLICIT_RTOL)
    np.testing.assert_allclose(shared["eigenvalues"], evals[:m], rtol=PCA_IMPLICIT_RTOL)
    coverage = np.cumsum(evals) / evals.sum()
    assert m == int(np.argmax(coverage >= 0.995)) + 1           # the demo's pca_coverage
    saved = load_basis(session["root"] / "out" / "b" / "basis-PCA.npz")
    shapes = saved.displacements.reshape(m + 1, -1)
    np.testing.assert_allclose(shapes[0], mean, rtol=0, atol=FLOAT32_REL * np.abs(mean).max())
    scaled = vt[:m] * np.sqrt(evals[:m])[:, None]
    signs = np.sign(np.sum(shapes[1:] * scaled, axis=1))
    np.testing.assert_allclose(shapes[1:], signs[:, None] * scaled, rtol=0,
                               atol=FLOAT32_REL * np.abs(scaled).max())


def test_warnings_are_printed_recorded_and_reported(session):
    printed = {}
    for line in session["stderr"].splitlines():
        found = re.match(r"mocap2mesh: warning: take (\w+): (.*)$", line)
        if found:
            printed.setdefault(found[1], []).append(found[2])
    for take in TAKES:
        record = session["manifest"]["takes"][take]["warnings"]
        assert printed[take] == record
        assert any("filled" in m and f"{take}.c3d" in m for m in record)
        page = (session["root"] / "out" / take / "report" / f"{take}.html").read_text()
        items = re.search(r'<ul id="warnings">(.*?)</ul>', page, re.S)[1]
        assert [html.unescape(i) for i in re.findall(r"<li>(.*?)</li>", items)] == record


def test_a_session_re_runs_every_take_when_one_capture_changes(session, monkeypatch, tmp_path):
    """The skip logic alone: the chain and the basis are stubs that record their calls."""
    calls, pooled = [], []

    def fake_basis(config, *, executor, progress, keep, built):
        pooled.append(len(config.captures))
        return None, {}

    monkeypatch.setattr("fit.pipeline.session._guarded", stub_take(calls))
    monkeypatch.setattr("fit.pipeline.session.build_session_basis", fake_basis)
    for take in TAKES:
        shutil.copy(session["root"] / f"{take}.c3d", tmp_path / f"{take}.c3d")
    config = dataclasses.replace(load_run_config(session["path"]), output=tmp_path / "out",
                                 captures=tuple(tmp_path / f"{t}.c3d" for t in TAKES))
    run_takes(config, workers=1, progress=False)
    assert len(calls) == 3 and pooled == [3]
    outcome = run_takes(config, workers=1, progress=False)
    assert outcome.n_skipped == 3 and len(calls) == 3 and pooled == [3]   # nothing to do
    session_input = json.loads(outcome.manifest.read_text())["inputs"]["session"]
    digests = [hashlib.sha256((tmp_path / f"{t}.c3d").read_bytes()).hexdigest() for t in TAKES]
    assert session_input == {"takes": list(TAKES), "sha256": hashlib.sha256("\n".join(
        f"{t}:{d}" for t, d in zip(TAKES, digests)).encode()).hexdigest()}
    (tmp_path / "c.c3d").write_bytes((tmp_path / "c.c3d").read_bytes() + b"\0")
    outcome = run_takes(config, workers=1, progress=False)
    assert sorted(calls[3:]) == ["a.c3d", "b.c3d", "c.c3d"]
    assert outcome.n_skipped == 0 and pooled == [3, 3]


def test_takes_kept_prepared_run_as_takes_prepared_again(session, monkeypatch, tmp_path):
    """The session basis keeps each take prepared for its run: ingest, bind and retarget run
    once a take, and the outputs and warnings are those of a run that prepares every take
    again (nothing kept: no room)."""
    calls = []
    prepare = Reconstruction.prepare

    def counted(self, capture):
        calls.append(capture)
        return prepare(self, capture)
    monkeypatch.setattr(Reconstruction, "prepare", counted)
    runs = {}
    for label, room in (("kept", kept_takes.KEPT_BYTES), ("again", 0)):
        monkeypatch.setattr(kept_takes, "KEPT_BYTES", room)
        calls.clear()
        config = dataclasses.replace(load_run_config(session["path"]),
                                     output=tmp_path / label)
        outcome = run_takes(config, workers=1, progress=False)
        assert outcome.n_failed == 0
        runs[label] = (len(calls), json.loads(outcome.manifest.read_text()))
        assert not (tmp_path / label / ".staging").exists()
    assert runs["kept"][0] == len(TAKES) and runs["again"][0] == 2 * len(TAKES)
    for take in TAKES:
        assert runs["kept"][1]["takes"][take]["warnings"] == \
            runs["again"][1]["takes"][take]["warnings"]
        assert any("filled" in m for m in runs["kept"][1]["takes"][take]["warnings"])
        for name in ("weights-H.csv", "weights-QE.csv", "mesh-PCA.npz"):
            assert (tmp_path / "kept" / take / name).read_bytes() == \
                (tmp_path / "again" / take / name).read_bytes()


def test_the_run_builds_its_reconstruction_once_and_each_take_keeps_its_warnings(
        session, monkeypatch, tmp_path):
    """The mesh, marker set and basis are read once for the session basis and every take,
    not once per task; a warning raised reading them is in every take's record, first."""
    built = []
    from_config = Reconstruction.from_config.__func__

    def counted(cls, config):
        built.append(config)
        warnings.warn("a warning of the shared inputs", UserWarning, stacklevel=2)
        return from_config(cls, config)
    monkeypatch.setattr(Reconstruction, "from_config", classmethod(counted))
    config = dataclasses.replace(load_run_config(session["path"]), output=tmp_path / "out")
    outcome = run_takes(config, workers=1, progress=False)
    assert outcome.n_failed == 0 and len(built) == 1
    manifest = json.loads(outcome.manifest.read_text())
    for take in TAKES:
        recorded = manifest["takes"][take]["warnings"]
        assert recorded[0] == "a warning of the shared inputs"
        assert recorded.count("a warning of the shared inputs") == 1


def test_a_kept_take_that_does_not_read_back_is_prepared_again(prepared, tmp_path):
    recon, takes = prepared
    files = kept_takes.kept_files(tmp_path, {"a.c3d": "a", "b.c3d": "b"})
    assert kept_takes.keep_prepared(takes[0], [("a warning", UserWarning)], files["a.c3d"])
    back, caught = kept_takes.take_kept(files["a.c3d"])
    assert caught == [("a warning", UserWarning)] and not files["a.c3d"].exists()
    np.testing.assert_array_equal(back.retargeted.displacements,
                                  takes[0].retargeted.displacements)
    assert kept_takes.take_kept(files["a.c3d"]) is None                   # taken already
    assert kept_takes.keep_prepared(takes[0], [], files["b.c3d"])
    files["b.c3d"].write_bytes(files["b.c3d"].read_bytes()[:1000])          # cut short
    assert kept_takes.take_kept(files["b.c3d"]) is None and not files["b.c3d"].exists()


def test_scope_take_keeps_each_take_its_own_basis(session, prepared):
    recon, takes = prepared
    own = [recon.process(p) for p in takes[:2]]
    assert [r.bases.scope for r in own] == ["take", "take"]
    digests = {r.summary()["basis"]["pca_sha256"] for r in own}
    assert len(digests) == 2 and session["manifest"]["session_basis"]["sha256"] not in digests


def test_a_session_pca_of_another_mesh_is_refused(prepared):
    recon, takes = prepared
    n = recon.mesh.n_vertices + 1
    axis = np.zeros((1, n, 3))
    axis[0, 0, 0] = 1.0
    wrong = PCAModel(np.zeros((n, 3)), axis, [1.0], 1.0, 10)

    class Shared:
        pca = wrong

    with pytest.raises(InputError, match=rf"the session PCA has {n} vertices, the take's mesh "
                                         rf"{n - 1}"):
        recon.process(takes[0], session_basis=Shared())


def test_run_refuses_more_components_than_the_session_has(session, tmp_path, capsys):
    text = session["path"].read_text().replace("pca_coverage = 0.995",
                                               "pca_components = 100000")
    text = text.replace('"a.c3d", "b.c3d", "c.c3d"', '"a.c3d", "b.c3d"')
    path = session["root"] / "too-many.toml"
    path.write_text(text.replace('directory = "out"', f'directory = "{tmp_path / "out"}"'))
    assert main(["run", str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.fullmatch(
        r"mocap2mesh run: error: basis\.pca_components = 100000 is more than the \d+ "
        r"components the session's mesh sequences can have \(2 takes\)", err[0])


def test_run_refuses_an_unknown_scope(session, capsys):
    path = session["root"] / "bad-scope.toml"
    path.write_text(session["path"].read_text().replace(
        "pca_coverage = 0.995", 'pca_coverage = 0.995\nscope = "shot"'), encoding="utf-8")
    assert main(["run", str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"mocap2mesh run: error: {path}: basis.scope: scope must be one of "
                   "['session', 'take'], got 'shot'"]


def test_a_failed_take_keeps_the_warnings_that_say_why(session, tmp_path):
    text = session["path"].read_text().replace('"a.c3d", "b.c3d", "c.c3d"', '"a.c3d"')
    text = re.sub(r"(?m)^max_gap = .*$", "max_gap = 3", text)
    path = session["root"] / "short-gaps.toml"
    path.write_text(text.replace('directory = "out"', f'directory = "{tmp_path / "out"}"'))
    stderr = io.StringIO()
    with contextlib.redirect_stderr(stderr):
        assert main(["run", str(path)]) == 1
    record = json.loads((tmp_path / "out" / "manifest.json").read_text())["takes"]["a"]
    assert record["status"] == "failed"
    assert re.search(r"missing in frames \d+-\d+ .* \(longer than max_gap=3\); .* set \[ingest\] "
                     r"max_gap = \d+ or more to fill it", record["error"])
    assert any("left unfilled" in m for m in record["warnings"])
    lines = stderr.getvalue().strip().splitlines()
    assert lines[-1].startswith("mocap2mesh run: take a (") and "failed: marker" in lines[-1]
    assert lines[:-1] == [f"mocap2mesh: warning: take a: {m}" for m in record["warnings"]]


def test_unconverged_fits_are_warned_with_their_frame_numbers():
    from fit.pipeline.take_warnings import warn_unconverged

    class Solution:
        def __init__(self, status, message):
            self.status, self.message = status, message

    with pytest.warns(UserWarning, match=r"^fit of basis QE: 2 of 9 frames did not converge "
                                         r"\(frames counted from 0 at frame number 41\)$"):
        warn_unconverged({"H": Solution(0, "all converged"),
                          "QE": Solution(1, "2 of 9 frames did not converge")}, first_frame=41)


def test_pooled_moments_are_the_moments_of_the_frames_together():
    """Moments of pieces pooled are numpy's moments of the concatenated frames, also for
    frames far from the origin (no cancellation of sums of squares about zero)."""
    d = random_session(seed=4)[1][0] + 1e4
    pieces = [d[:3], d[3:4], d[4:20], d[20:]]
    pooled = pool_moments(marker_moments(p) for p in pieces)
    flat = d.reshape(len(d), -1)
    assert pooled.n_frames == len(d)
    np.testing.assert_allclose(pooled.mean.ravel(), flat.mean(axis=0), rtol=EXACT_FLOAT64)
    np.testing.assert_allclose(pooled.covariance, np.cov(flat.T, bias=True), rtol=1e-9,
                               atol=1e-9 * np.abs(np.cov(flat.T)).max())
    with pytest.raises(InputError, match="no moments to pool"):
        pool_moments([])
    with pytest.raises(InputError, match=r"different marker counts \[5, 6\]"):
        pool_moments([marker_moments(d), marker_moments(d[:, :5])])


def test_marker_moments_refuse_a_take_without_frames():
    with pytest.raises(InputError, match=r"displacements must have shape \(T, M, 3\) with "
                                         r"T >= 1, got \(0, 4, 3\)"):
        marker_moments(np.zeros((0, 4, 3)))
