"""The QA report a TD reads: out-of-sample basis errors, the take's extremes, mesh renders,
provenance, grades, sections and the embedded video, on a short demo take."""

from __future__ import annotations

import base64
import dataclasses
import hashlib
import html
import re

import numpy as np
import pytest
from tolerances import RENDER_KERNEL_LEVELS

from fit.demo import DEMO_MAX_GAP, make_demo_session
from fit.pipeline.holdout import held_out_fits, time_blocked_splits
from fit.pipeline.reconstruction import Reconstruction
from fit.pipeline.stages import basis_stage, fit_stage
from fit.report import build_report
from fit.report.extremes import take_extremes
from fit.report.figure_queue import FigureQueue
from fit.report.grades import GRADES, grade
from fit.report.html import Section, Table
from mocap.errors import InputError
from mocap.markerset import MarkerSet


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """A 3 s demo take through the chain, and its report written once."""
    root = tmp_path_factory.mktemp("qa")
    session = make_demo_session(root / "session", seconds=3.0)
    p = session.paths
    recon = Reconstruction(markerset=p["markerset"], mesh=p["neutral"], mesh_units="mm",
                           landmarks=p["landmarks"], basis=p["shapes"],
                           ingest={"max_gap": DEMO_MAX_GAP}, bind={"skin_offset": 2.0},
                           report={"video_step": 6, "held_out_folds": 3})
    result = recon.process(p["capture"])
    files = result.report(root / "report", inputs={"capture": p["capture"],
                                                   "mesh": p["neutral"]})
    return dict(result=result, files=files, root=root, paths=p)


@pytest.fixture(params=["helpers", "here"])
def csv_writer(request, monkeypatch):
    """Where save writes the weights CSVs: queued for the figure helpers (this process has
    no compiled CSV text loaded), or here, on a thread of its own while it writes the other
    files (it has). Returns the list of the functions save queues."""
    import fit.pipeline.reconstruction as reconstruction

    monkeypatch.setattr(reconstruction, "compiled_lines_ready",
                        lambda: request.param == "here")
    queued = []
    submit = FigureQueue.submit
    monkeypatch.setattr(FigureQueue, "submit",
                        lambda self, fn, *a, **k: queued.append(fn) or submit(self, fn, *a, **k))
    return request.param, queued


def test_exports_written_with_a_helper_are_the_same_files(demo, tmp_path, csv_writer):
    """The weights CSVs written by a figure helper while this process writes the rest, or
    by this process after the rest, are the bytes written with no helper, and every export
    is there when save returns; an error of a CSV is raised by save."""
    where, queued = csv_writer
    result = demo["result"]
    alone = result.save(tmp_path / "alone")
    queued.clear()
    with FigureQueue(helpers=1) as figures:
        shared = result.save(tmp_path / "shared", figures=figures)
        assert figures.helpers == 1
    assert len(queued) == (len(result.bases.bases) if where == "helpers" else 0)
    assert [p.relative_to(tmp_path / "shared") for p in shared] == \
        [p.relative_to(tmp_path / "alone") for p in alone]
    assert all(p.is_file() for p in shared)
    csvs = [p for p in alone if p.suffix == ".csv"]
    assert len(csvs) == len(result.bases.bases)
    for path in csvs:
        assert (tmp_path / "shared" / path.name).read_bytes() == path.read_bytes()
    first = next(iter(result.bases.bases))
    (tmp_path / "taken" / f"weights-{first}.csv").mkdir(parents=True)   # not a file
    with FigureQueue(helpers=1) as figures, pytest.raises(InputError) as raised:
        result.save(tmp_path / "taken", figures=figures)
    assert f"weights-{first}.csv" in str(raised.value)
    assert (tmp_path / "taken" / f"face-{first}.glb").is_file()   # the others written
    # an error of a binary export: raised once the CSVs are finished, none written behind it
    (tmp_path / "glb" / f"face-{first}.glb").mkdir(parents=True)
    with FigureQueue(helpers=1) as figures, pytest.raises(InputError) as raised:
        result.save(tmp_path / "glb", figures=figures)
    assert f"face-{first}.glb" in str(raised.value)
    if where == "here":
        for path in csvs:
            assert (tmp_path / "glb" / path.name).read_bytes() == path.read_bytes()


def test_exports_left_to_the_helpers_are_written_by_the_queue_s_next_run(demo, tmp_path,
                                                                         csv_writer):
    """With ``wait=False`` queued weights CSVs are left to the helper: the queue's next run
    writes the bytes written with no helper and raises a CSV's error, which save did not.
    CSVs written here are written, or their error raised, before save returns."""
    where, _ = csv_writer
    result = demo["result"]
    alone = result.save(tmp_path / "alone")
    with FigureQueue(helpers=1) as figures:
        shared = result.save(tmp_path / "shared", figures=figures, wait=False)
        if where == "here":
            assert all(p.is_file() for p in shared)
        figures.run()
    assert [p.relative_to(tmp_path / "shared") for p in shared] == \
        [p.relative_to(tmp_path / "alone") for p in alone]
    for path in alone:
        assert (tmp_path / "shared" / path.name).read_bytes() == path.read_bytes()
    first = next(iter(result.bases.bases))
    (tmp_path / "taken" / f"weights-{first}.csv").mkdir(parents=True)   # not a file
    with FigureQueue(helpers=1) as figures:
        if where == "helpers":
            result.save(tmp_path / "taken", figures=figures, wait=False)     # not raised here
            with pytest.raises(InputError) as raised:
                figures.run()
        else:
            with pytest.raises(InputError) as raised:
                result.save(tmp_path / "taken", figures=figures, wait=False)
    assert f"weights-{first}.csv" in str(raised.value)


# ---------------------------------------------------------------- out of sample

@pytest.mark.parametrize("n_frames, n_folds, guard", [(10, 2, 0), (101, 5, 3), (7, 7, 0)])
def test_time_blocked_splits_test_each_frame_once_and_train_away_from_it(n_frames, n_folds,
                                                                        guard):
    splits = time_blocked_splits(n_frames, n_folds, guard=guard)
    tested = np.concatenate([test for _, test in splits])
    np.testing.assert_array_equal(np.sort(tested), np.arange(n_frames))
    for train, test in splits:
        assert np.all(np.diff(test) == 1)                                # one block
        near = np.abs(train[:, None] - test[None, :]).min(axis=1)
        assert near.min() > guard                                        # never within guard
        assert len(train) + len(test) + min(guard, test[0]) \
            + min(guard, n_frames - 1 - test[-1]) == n_frames            # all others train


def test_time_blocked_splits_refuse_what_cannot_be_split():
    with pytest.raises(InputError, match="3 frames cannot make 4 time-blocked folds"):
        time_blocked_splits(3, 4)
    with pytest.raises(InputError, match="a guard of 5 frames leaves the test block 0..4 no "
                                         "training frame"):
        time_blocked_splits(10, 2, guard=5)


def test_other_takes_plug_in_as_bases_built_elsewhere(demo):
    """The other-takes variant: bases made elsewhere, one split testing every frame; with the
    take's own bases that is exactly the in-sample fit."""
    r = demo["result"]
    everything = np.arange(r.take.n_frames)
    held = held_out_fits(r.take, r.bound, r.retargeted, r.reconstruction.basis,
                         splits=[(None, everything)], label="the take's own bases",
                         make_bases=lambda train: r.bases)
    for name in ("QE", "PCA"):
        np.testing.assert_array_equal(held.reconstructed[name], r.fitted.reconstructed[name])


def test_held_out_frames_fit_alone_as_in_the_whole_take(demo):
    """Frames fit independently are fit on the test frames alone: the same as fitting the
    whole take with the split's bases and keeping the test frames."""
    r = demo["result"]
    splits = time_blocked_splits(r.take.n_frames, 3, guard=2)
    made = []

    def make_bases(train):
        made.append(basis_stage(dataclasses.replace(
            r.retargeted, displacements=r.retargeted.displacements[train]),
            r.reconstruction.basis))
        return made[-1]
    held = held_out_fits(r.take, r.bound, r.retargeted, r.reconstruction.basis,
                         splits=splits, label="", make_bases=make_bases)
    for bases, (_, test) in zip(made, splits):
        whole = fit_stage(r.take, r.bound, r.retargeted, bases)
        for name in ("QE", "PCA"):
            np.testing.assert_allclose(held.reconstructed[name][test],
                                       whole.reconstructed[name][test], rtol=0, atol=1e-9)


@pytest.mark.parametrize("scattered", [False, True])
def test_held_out_bases_are_the_basis_stage_on_the_training_frames(demo, scattered):
    """The default bases of a split, made from its training frames' pooled moments, are the
    take's basis stage run on a copy of those frames: the same reconstructions. Time
    blocks pool a few runs; scattered training frames take their moments directly."""
    r = demo["result"]
    n_frames = r.take.n_frames
    if scattered:
        order = np.random.default_rng(3).permutation(n_frames)
        splits = [(np.sort(np.setdiff1d(order, part)), np.sort(part))
                  for part in np.array_split(order, 3)]
    else:
        splits = time_blocked_splits(n_frames, 3, guard=2)

    def on_a_copy(train):
        return basis_stage(dataclasses.replace(
            r.retargeted, displacements=r.retargeted.displacements[train]),
            r.reconstruction.basis)
    expected = held_out_fits(r.take, r.bound, r.retargeted, r.reconstruction.basis,
                             splits=splits, label="", make_bases=on_a_copy)
    held = held_out_fits(r.take, r.bound, r.retargeted, r.reconstruction.basis,
                         splits=splits, label="")
    assert held.n_components == expected.n_components
    for name in ("QE", "PCA"):
        assert np.isfinite(held.reconstructed[name]).all()
        np.testing.assert_allclose(held.reconstructed[name], expected.reconstructed[name],
                                   rtol=0, atol=1e-7)


def test_held_out_bases_score_worse_than_in_sample(demo):
    """PCA is the best basis of its size on the frames it was built from: on frames it was not
    built from its error is larger, and the report says so."""
    r = demo["result"]
    held = r.held_out()
    assert "3 time-blocked folds" in held.label
    for name in ("QE", "PCA"):
        assert np.isfinite(held.reconstructed[name]).all()
        out = np.linalg.norm(held.reconstructed[name] - r.face.positions, axis=2)
        inside = np.linalg.norm(r.fitted.reconstructed[name] - r.face.positions, axis=2)
        assert np.sqrt(np.mean(out ** 2)) > np.sqrt(np.mean(inside ** 2))
    page = _html(demo)
    assert "out-of-sample" in page and held.label in page


def _html(demo) -> str:
    return next(f for f in demo["files"] if f.suffix == ".html").read_text(encoding="utf-8")


# ---------------------------------------------------------------- extremes

def test_extremes_are_the_frames_the_markers_say():
    ms = MarkerSet(name="m", head=(), regions={"upper_lip": ("u",), "lower_lip": ("l",),
                                               "left_brow": ("b",)},
                   landmarks={"mouth_corner_left": "cl", "mouth_corner_right": "cr"})
    labels = ("u", "l", "b", "cl", "cr")
    rest = np.array([[0, 0, 0], [0, -2, 0], [20, 40, 0], [25, -1, 0], [-25, -1, 0.0]])
    p = np.repeat(rest[None], 30, axis=0)
    p[7, 1, 1] -= 12.0                     # the jaw drops at frame 7
    p[19, 3, 0] += 4.0                     # the corners pull out at frame 19
    p[19, 4, 0] -= 4.0
    p[23, 2, 1] += 6.0                     # the brow goes up at frame 23
    found = {e.name: e for e in take_extremes(p, rest, labels, ms)}
    assert (found["mouth open"].frame, found["smile"].frame, found["brows up"].frame) \
        == (7, 19, 23)
    assert found["mouth open"].value == pytest.approx(14.0)
    assert found["smile"].value == pytest.approx(8.0)


# ---------------------------------------------------------------- mesh space

def test_mesh_space_is_the_basis_and_the_operator(demo):
    r = demo["result"]
    space = r.mesh_space()
    frames = [0, 5, r.take.n_frames - 1]
    W = np.asarray(r.retargeted.operator.matrix)
    for k, t in enumerate(frames):                       # brute force, frame by frame
        np.testing.assert_allclose(space.retargeted_mesh(frames)[k],
                                   space.neutral + W @ r.retargeted.displacements[t],
                                   rtol=0, atol=1e-9)
        np.testing.assert_allclose(space.basis_mesh("H", frames)[k], r.meshes("H").vertices(t),
                                   rtol=0, atol=1e-9)


def test_mesh_renders_show_the_face_and_the_red_markers(demo):
    import cv2

    for key in ("mesh-H", "mesh-QE", "mesh-PCA", "mesh-WD"):
        path = next(f for f in demo["files"] if f.name.endswith(f"-{key}.png"))
        image = cv2.imread(str(path))[:, :, ::-1].astype(int)
        assert image.shape[1] <= 1480                                  # at its display size
        r, g, b = image[..., 0], image[..., 1], image[..., 2]
        assert ((r > 150) & (g < 60) & (b < 60)).sum() > 200          # the markers
        shaded = (np.abs(r - g) < 20) & (r > 60) & (r < 235)          # grey-ish skin
        assert shaded.sum() > 10000 or key != "mesh-WD"


def test_mesh_renders_are_drawn_here_where_this_process_renders_them_compiled(
        demo, tmp_path, monkeypatch):
    """Where this process has the compiled rasterizer (compiled_renders), the report draws
    its mesh figures itself while the helpers draw the others; else it queues them. The
    pictures are the same (to the specular power's last bit)."""
    import cv2

    import fit.report as report_module

    queued, submit = [], FigureQueue.submit
    monkeypatch.setattr(FigureQueue, "submit",
                        lambda self, fn, *a, **k: queued.append(fn.__name__)
                        or submit(self, fn, *a, **k))
    pictures = {}
    for here in (True, False):
        monkeypatch.setattr(report_module, "compiled_renders", lambda *a, here=here: here)
        queued.clear()
        with FigureQueue(helpers=1) as figures:
            files = demo["result"].report(tmp_path / str(here), figures=figures)
        assert queued.count("plot_mesh_frames") == (0 if here else 4)
        assert "plot_alpha" in queued
        pictures[here] = {f.name: cv2.imread(str(f)).astype(int) for f in files
                          if "-mesh-" in f.name}
    assert len(pictures[True]) == 4 and pictures[True].keys() == pictures[False].keys()
    for name, image in pictures[True].items():
        assert np.abs(image - pictures[False][name]).max() <= RENDER_KERNEL_LEVELS


# ---------------------------------------------------------------- the page

def test_provenance_hashes_the_inputs_and_names_the_neutral_frame(demo):
    page = _html(demo)
    for role in ("capture", "mesh"):
        digest = hashlib.sha256(demo["paths"][role if role == "capture" else "neutral"]
                                .read_bytes()).hexdigest()
        assert digest in page
    r = demo["result"]
    neutral = r.take.first_frame + r.bound.frame
    assert re.search(rf'neutral frame</td><td class="num" data-value="{neutral}"', page)
    assert f'data-value="{r.binding.rms!r}"' in page


def test_provenance_shows_a_digest_it_is_given_without_reading_the_file(demo, tmp_path):
    """An input given with its digest (a run's record of it) is listed as given: the file
    is not read again (a digest that is not the file's proves it)."""
    given = "0" * 64
    page = demo["result"].report(tmp_path / "report", inputs={
        "capture": {"path": str(demo["paths"]["capture"]), "sha256": given},
        "mesh": demo["paths"]["neutral"]})
    html = next(p for p in page if str(p).endswith(".html"))
    text = html.read_text()
    assert f"<td>{demo['paths']['capture']}</td><td>{given}</td>" in text
    digest = hashlib.sha256(demo["paths"]["neutral"].read_bytes()).hexdigest()
    assert f"<td>{demo['paths']['neutral']}</td><td>{digest}</td>" in text


def test_grades_follow_their_stated_thresholds(demo):
    page = _html(demo)
    rows = re.findall(r"<tr><td>([^<]+)</td><td class=\"num\" data-value=\"([^\"]+)\">[^<]*"
                      r"</td><td><span class=\"badge (\w+)\">", page)
    assert len(rows) >= 9
    keys = {"RMS (mm)": "rms_mm", "95th-percentile error (mm)": "p95_mm",
            "out-of-sample / in-sample RMS": "out_of_sample_ratio"}
    for what, value, badge in rows:
        key = next((k for tail, k in keys.items() if what.endswith(tail)), None)
        if key is not None:
            assert badge == grade(key, float(value))
    assert html.escape(GRADES["rms_mm"].rule()) in page
    assert grade("rms_mm", float("nan")) == "n/a"


def test_video_is_embedded_as_webm_in_a_video_element(demo):
    page = _html(demo)
    (src,) = re.findall(r'<video[^>]*><source src="data:video/webm;base64,([^"]+)"', page)
    video = next(f for f in demo["files"] if f.suffix == ".webm")
    assert base64.b64decode(src) == video.read_bytes()


def test_extra_sections_are_appended(demo, tmp_path):
    r = demo["result"]
    face = r.face
    extra = Section("Lip seal", text="added by another check",
                    tables=(Table(("frame", "gap (mm)"), ((12, 3.5),), "lip-seal"),))
    files = build_report(face, r.fitted.reconstructed, r.bound.neutral_pose(face.positions),
                         tmp_path, sections=[extra], name="x")
    page = files["html"].read_text(encoding="utf-8")
    assert page.index('<h2 id="lip-seal">Lip seal</h2>') < page.index("Per-marker errors")
    assert '<table id="lip-seal">' in page and "added by another check" in page
