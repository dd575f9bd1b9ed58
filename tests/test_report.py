"""QA report: charts, marker views, overlay video and HTML, on the real capture."""

from __future__ import annotations

import base64
import dataclasses
import pickle
import struct
import warnings
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers import ReportPage, wait_for_file
from matplotlib import rc_context
from PIL import Image
from tolerances import EXACT_FLOAT64

from basis.coverage import plot_coverage
from basis.pca import pca_streaming
from fit.metrics import reconstruction_errors
from fit.report import build_report
from fit.report.drawing import (
    IMAGE_WIDTH_PX,
    label_ticks,
    line_envelope,
    plain_log_axis,
    report_figure,
)
from fit.report.figure_queue import FigureQueue
from fit.report.html import render_report
from fit.report.ingest_plots import GapChart, HeadResiduals, plot_gaps, plot_head_residuals
from fit.report.plots import (
    HEATMAP_COLUMNS,
    HeatmapColumns,
    bar_collection,
    error_axis_top,
    plot_error_heatmap,
    plot_error_heatmaps,
    plot_marker_error_charts,
    plot_marker_errors,
    region_groups,
)
from fit.report.video import MAX_AUTO_FPS, write_overlay_video
from fit.report.views import (
    CAPTURED_COLOUR,
    RECONSTRUCTED_COLOUR,
    FrameViews,
    plot_frame_views,
    plot_views_of_bases,
    view_axes,
)
from mocap.errors import InputError
from mocap.stabilize import stabilize
from mocap.take import FILL_METHODS, Take
from mocap.viz.figures import draw_png, new_figure, write_png

N_FRAMES = 600


@pytest.fixture(scope="module")
def sing_case(facial_sing_take, facial_sing_markerset):
    """The first frames of facial-sing, stabilized, and two 'reconstructions':
    the capture plus smooth error fields of a few mm (one on the lips only)."""
    ms = facial_sing_markerset
    take = facial_sing_take
    take = take.replace(positions=take.positions[:N_FRAMES], filled=take.filled[:N_FRAMES])
    face = stabilize(take, ms.head).take.select(ms.face_markers)
    rng = np.random.default_rng(0)
    t = np.arange(face.n_frames)[:, None, None]
    bump = np.exp(-0.5 * ((t - 400) / 15.0) ** 2)
    lips = np.isin(face.labels, ms.regions["lower_lip"] + ms.regions["mouth_corners"])
    small = 0.3 * np.sin(t / 40 + rng.uniform(0, 6, size=(1, face.n_markers, 3)))
    qe = face.positions + small + 4.0 * bump * lips[None, :, None]
    h = face.positions + 3 * small + 6.0 * bump
    neutral = face.positions[0]
    return ms, face, {"QE": qe, "H": h}, neutral


@pytest.fixture(scope="module")
def report(sing_case, tmp_path_factory):
    ms, face, recs, neutral = sing_case
    disp = np.nan_to_num(face.positions - neutral)
    pca = pca_streaming(disp.reshape(face.n_frames, -1, 3), n_components=25)
    out = tmp_path_factory.mktemp("report")
    files = build_report(face, recs, neutral, out, markerset=ms, pca=pca, name="sing")
    results = {b: reconstruction_errors(face.positions, r, neutral, labels=face.labels, name=b)
               for b, r in recs.items()}
    return files, results, pca


def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def test_a_report_drawn_with_a_helper_is_the_same_pictures(sing_case, report, tmp_path):
    ms, face, recs, neutral = sing_case
    files, _, pca = report
    with FigureQueue(helpers=1) as figures:
        shared = build_report(face, recs, neutral, tmp_path, markerset=ms, pca=pca,
                              name="sing", figures=figures)
    pictures = [key for key, path in files.items() if path.suffix == ".png"]
    assert len(pictures) >= 6 and set(shared) == set(files)
    for key in pictures:
        assert shared[key].read_bytes() == files[key].read_bytes(), key


def test_a_report_from_errors_computed_before_is_the_same_report(sing_case, report, tmp_path):
    """The pipeline hands the report the errors it computed for its manifest: the pictures
    and the page are those of the errors the report computes itself; errors of another
    basis, take or origin are refused, naming the basis."""
    ms, face, recs, neutral = sing_case
    files, results, pca = report
    given = build_report(face, recs, neutral, tmp_path, markerset=ms, pca=pca, name="sing",
                         errors=results)
    assert set(given) == set(files)
    for key, path in files.items():
        assert given[key].read_bytes() == path.read_bytes(), key
    swapped = {"QE": results["H"], "H": results["QE"]}
    other_origin = {b: reconstruction_errors(face.positions, r, neutral, labels=face.labels,
                                             name=b, origin=neutral.mean(axis=0) + 1.0)
                    for b, r in recs.items()}
    shorter = {b: reconstruction_errors(face.positions[:-1], r[:-1], neutral,
                                        labels=face.labels, name=b) for b, r in recs.items()}
    for wrong in (swapped, other_origin, shorter):
        with pytest.raises(InputError, match="errors of basis 'QE' are not of this take"):
            build_report(face, recs, neutral, tmp_path, name="sing", errors=wrong)
    with pytest.raises(InputError, match="errors has no entry for basis 'QE'"):
        build_report(face, recs, neutral, tmp_path, name="sing", errors={"H": results["H"]})


def test_region_groups_follow_the_markerset(sing_case):
    ms, face, _, _ = sing_case
    labels = list(face.labels[::-1]) + ["extra"]
    order, groups = region_groups(labels, ms)
    shown = [labels[i] for i in order]
    assert shown[:len(ms.face_markers)] == list(ms.face_markers)
    assert groups[-1] == ("unassigned", len(labels) - 1, len(labels))
    assert [g[0] for g in groups[:-1]] == [r for r, m in ms.regions.items() if m]
    assert sorted(order.tolist()) == list(range(len(labels)))


def test_front_view_puts_the_subjects_left_on_the_viewers_right(sing_case):
    ms, face, _, neutral = sing_case
    axes = view_axes(neutral, face.labels, ms)
    np.testing.assert_allclose(axes @ axes.T, np.eye(3), atol=EXACT_FLOAT64)
    screen = neutral @ axes.T
    col = {label: i for i, label in enumerate(face.labels)}
    for left, right in (("section1-1", "section2-1"), ("section11-1", "section12-1"),
                        ("section5-1", "section6-1")):          # left/right mirror pairs
        assert screen[col[left], 0] > screen[col[right], 0]
    assert screen[col["section1-1"], 1] > screen[col["section14-2"], 1]    # brow above chin
    assert screen[col["section7-2"], 2] > screen[col["section5-2"], 2]     # nose tip in front
    # The capture's own axes (marker-set file): subject's left +x, up +z.
    assert axes[0, 0] > 0.9 and axes[1, 2] > 0.9


def test_pngs_are_non_trivial(report):
    files, _, _ = report
    pngs = [p for k, p in files.items() if p.suffix == ".png"]
    assert len(pngs) == 1 + 3 * 2 + 1
    for path in pngs:
        width, height = _png_size(path)
        assert path.stat().st_size > 10_000, path.name
        image = cv2.imread(str(path))
        assert image.shape == (height, width, 3)
        packed = image.astype(np.int64) @ np.array([1, 256, 65536])
        assert len(np.unique(packed)) > 50, path.name
    # Figure sizes in inches at 120 dpi.
    assert _png_size(files["alpha"]) == (1320, 576)
    assert _png_size(files["coverage"]) == (1440, 540)
    # The report's own figures at most as wide as the page shows them (text at its size).
    for key in ("alpha", "heatmap-QE", "markers-QE", "views-QE", "heatmap-H"):
        assert _png_size(files[key])[0] <= IMAGE_WIDTH_PX, key


@pytest.mark.parametrize("basis", ["QE", "H"])
def test_views_show_captured_and_reconstructed_colours(report, basis):
    files, _, _ = report
    image = cv2.imread(str(files[f"views-{basis}"]))[:, :, ::-1].astype(int)
    for colour in (CAPTURED_COLOUR, RECONSTRUCTED_COLOUR):
        rgb = np.array([int(colour[i:i + 2], 16) for i in (1, 3, 5)])
        assert (np.abs(image - rgb).sum(axis=2) < 30).sum() > 500


def test_coverage_without_reaching_the_threshold(report, tmp_path):
    _, _, pca = report
    path = tmp_path / "cov.png"
    plot_coverage(pca.truncate(3), path, thresholds=(0.995,))
    assert path.stat().st_size > 10_000
    with pytest.raises(InputError, match="thresholds must be in"):
        plot_coverage(pca, path, thresholds=(99.5,))


def test_html_is_self_contained_and_its_numbers_are_the_metrics(report):
    files, results, _ = report
    page = ReportPage.read(files["html"])
    assert page.links == []
    pngs = sorted(p.read_bytes() for p in files.values() if p.suffix == ".png")
    assert all(src.startswith("data:image/png;base64,") for src in page.images)
    embedded = sorted(base64.b64decode(src.split(",", 1)[1]) for src in page.images)
    assert embedded == pngs
    summary = page.tables["summary"][1:]
    keys = ["alpha", "alpha_mean", "alpha_max", "displacement_error", "rms_mm", "mean_mm",
            "p95_mm", "max_mm"]
    for row, res in zip(summary, results.values()):
        assert [float(v) for v in row[2:2 + len(keys)]] == [res.summary()[k] for k in keys]
        assert int(row[2 + len(keys)]) == res.summary()["worst_frame"] + 1   # frame number
    markers = page.tables["markers"][1:]
    qe, h = results["QE"], results["H"]
    assert len(markers) == len(qe.labels)
    got = np.array([[float(v) for v in row[2:8]] for row in markers])
    want = np.column_stack([qe.marker_mean, qe.marker_p95, qe.marker_max,
                            h.marker_mean, h.marker_p95, h.marker_max])
    np.testing.assert_array_equal(got, want)
    worst = page.tables["worst"][1:]
    assert [row[0] for row in worst] == ["QE"] * 5 + ["H"] * 5
    for row in worst:
        res, frame = results[row[0]], int(row[2]) - 1           # frame numbers start at 1
        assert [float(v) for v in row[3:7]] == [res.alpha[frame], res.displacement_error[frame],
                                                res.rms[frame], res.max_error[frame]]
    top_qe = int(worst[0][2]) - 1
    assert results["QE"].rms[top_qe] == np.nanmax(results["QE"].rms)


def test_html_errors(report):
    _, results, _ = report
    with pytest.raises(InputError, match="results is empty"):
        render_report({}, {}, title="x")
    with pytest.raises(InputError, match="is not a PNG"):
        render_report(results, {"bad": b"GIF89a"}, title="x")


@pytest.mark.parametrize("step,fps", [(1, None), (3, 24.0), ("auto", None)])
def test_video_round_trip(sing_case, tmp_path, step, fps):
    ms, face, recs, neutral = sing_case
    n = 150
    path = tmp_path / "overlay.webm"
    written = write_overlay_video(face.positions[:n], recs["H"][:n], path, neutral=neutral,
                                  rate=face.rate, labels=face.labels, markerset=ms,
                                  step=step, fps=fps, size=(320, 240))
    if step == "auto":              # the fewest frames dropped for at most 60 a second
        step = next(k for k in range(1, 100) if face.rate / k <= MAX_AUTO_FPS)
    assert written == len(range(0, n, step))
    video = cv2.VideoCapture(str(path))
    try:
        assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == written
        assert int(video.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little") == b"VP90"
        assert (video.get(cv2.CAP_PROP_FRAME_WIDTH), video.get(cv2.CAP_PROP_FRAME_HEIGHT)) \
            == (320, 240)
        assert video.get(cv2.CAP_PROP_FPS) == pytest.approx(fps or face.rate / step)
        frames = 0
        while True:
            ok, image = video.read()
            if not ok:
                break
            frames += 1
            b, g, r = (image[..., i].astype(int) for i in range(3))
            assert ((r > 150) & (g < 110) & (b < 110)).any()   # captured markers in red
            assert ((b > 150) & (r < 110)).any()               # reconstructed in blue
        assert frames == written
    finally:
        video.release()
    assert path.read_bytes()[:4] == b"\x1a\x45\xdf\xa3"                   # EBML: WebM
    assert [p.name for p in tmp_path.iterdir()] == ["overlay.webm"]   # no temp file left


def _decoded(path) -> list:
    import av
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        return [(frame.pts * frame.time_base, frame.to_ndarray(format="bgr24"))
                for frame in container.decode(stream)], float(stream.average_rate)


def test_a_video_written_in_parts_and_joined_is_the_whole_video(sing_case, tmp_path):
    """The oracle is the video written whole: the parts joined have its frames, in order,
    at its times and rate (each part starts with a key frame, so the pictures match to
    VP9's loss, not to the bit)."""
    from fit.report.video import overlay_frames
    from mocap.viz.webm import join_webm

    ms, face, recs, neutral = sing_case
    frames = overlay_frames(face.positions[:90], {b: recs[b][:90] for b in ("H", "QE")},
                            neutral=neutral, rate=face.rate, labels=face.labels, markerset=ms,
                            step=2, size=(160, 160), first_frame=face.first_frame)
    frames.write(tmp_path / "whole.webm")
    parts = [tmp_path / f"part{k}.webm" for k in range(3)]
    for part, rows in zip(parts, (slice(0, 10), slice(10, 31), slice(31, None))):
        frames[rows].write(part, threads=1)         # as the report's parts are encoded
    join_webm(parts, tmp_path / "joined.webm")
    (whole, rate), (joined, joined_rate) = (_decoded(tmp_path / f"{name}.webm")
                                            for name in ("whole", "joined"))
    assert len(joined) == len(whole) == len(frames) == 45
    assert joined_rate == pytest.approx(rate) and rate == pytest.approx(face.rate / 2)
    assert [t for t, _ in joined] == [t for t, _ in whole]
    for (_, a), (_, b) in zip(whole, joined):
        assert np.abs(a.astype(int) - b).mean() < 3
    with pytest.raises(ValueError, match="a run of its frames"):
        frames[::2]


def test_the_report_queues_a_part_of_the_video_per_process_each_on_one_thread(sing_case,
                                                                               tmp_path):
    """Each process (the queue's helpers and the caller) gets a part, encoded on one thread:
    the parts cover the frames in order."""
    from fit.report import _queue_video

    class Recording:
        helpers = 2

        def __init__(self):
            self.queued = []

        def submit(self, function, *args, **kwargs):
            self.queued.append((function.__self__, args, kwargs))

    ms, face, recs, neutral = sing_case
    queue = Recording()
    parts = _queue_video(queue, face, {b: recs[b] for b in ("H", "QE")},
                         tmp_path / "take-video.webm", neutral=neutral, markerset=ms, step=2,
                         exaggerate=1.0)
    assert [args for _, args, _ in queue.queued] == [(part,) for part in parts]
    assert len(parts) == 3 and all(kwargs == {"threads": 1} for _, _, kwargs in queue.queued)
    starts = [frames.start for frames, _, _ in queue.queued]
    assert starts[0] == 0 and starts == sorted(starts)
    assert sum(len(frames) for frames, _, _ in queue.queued) == -(-face.n_frames // 2)


def test_join_webm_names_a_part_that_is_no_video_or_of_another(tmp_path):
    from mocap.viz.webm import WebmWriter, join_webm

    (tmp_path / "bad.webm").write_bytes(b"not a video")
    with pytest.raises(InputError, match=r"bad\.webm: not a part of a WebM video"):
        join_webm([tmp_path / "bad.webm"], tmp_path / "out.webm")
    for name, size, fps in (("a", (64, 48), 30.0), ("wide", (96, 48), 30.0),
                            ("fast", (64, 48), 60.0)):
        with WebmWriter(tmp_path / f"{name}.webm", fps, size) as video:
            video.write(np.zeros((size[1], size[0], 3), np.uint8))
    with pytest.raises(InputError, match=r"wide\.webm: a part of another video \(vp9 96 x 48 "
                                         r"at 30 frames a second, not vp9 64 x 48 at 30\)"):
        join_webm([tmp_path / "a.webm", tmp_path / "wide.webm"], tmp_path / "out.webm")
    with pytest.raises(InputError, match=r"fast\.webm: a part of another video"):
        join_webm([tmp_path / "a.webm", tmp_path / "fast.webm"], tmp_path / "out.webm")
    assert not (tmp_path / "out.webm").exists()


def test_view_and_video_errors(sing_case, tmp_path):
    ms, face, recs, neutral = sing_case
    with pytest.raises(InputError, match="frames must be 1 or more indices"):
        plot_frame_views(face.positions, recs["H"], [N_FRAMES], tmp_path / "v.png",
                         neutral=neutral)
    with pytest.raises(InputError, match="reconstructed must have the shape"):
        write_overlay_video(face.positions, recs["H"][:10], tmp_path / "v.webm",
                            neutral=neutral, rate=100.0)
    with pytest.raises(InputError, match="step must be at least 1"):
        write_overlay_video(face.positions, recs["H"], tmp_path / "v.webm",
                            neutral=neutral, rate=100.0, step=0)
    with pytest.raises(InputError, match=r"v\.mp4: the overlay video is VP9 in WebM: name it "
                                         r"\*\.webm"):
        write_overlay_video(face.positions, recs["H"], tmp_path / "v.mp4",
                            neutral=neutral, rate=100.0)
    with pytest.raises(InputError, match="output directory does not exist"):
        build_report(face, recs, neutral, tmp_path / "absent")


@pytest.mark.parametrize("spike", [1_234, 6_001, 8_765])
def test_a_one_frame_error_of_a_long_take_shows_in_the_heatmap(tmp_path, spike):
    """10,000 frames drawn in about a thousand pixels: the image keeps the largest error of
    each column, so a single bad frame is there to see, wherever it falls (drawn as it was,
    one sample of ten, two of these three were not)."""
    from matplotlib import colormaps

    T, M = 10_000, 8
    top = (np.array(colormaps["magma"](1.0)[:3]) * 255).round().astype(int)

    def saturated_pixels(captured):
        errors = reconstruction_errors(captured, np.ones((T, M, 3)), np.zeros((M, 3)))
        plot_error_heatmap(errors, tmp_path / "h.png", vmax=1.0)
        image = cv2.imread(str(tmp_path / "h.png"))[:, :, ::-1].astype(int)
        return int((np.abs(image - top).max(axis=2) <= 2).sum())

    captured = np.ones((T, M, 3))
    without = saturated_pixels(captured)                         # the colour bar's top only
    captured[spike, 5, 0] = 50.0                                 # one marker, one frame
    assert saturated_pixels(captured) >= without + 3


@pytest.mark.parametrize("gap", [1_234, 6_001, 8_765])
def test_a_one_frame_gap_of_a_long_take_shows_in_the_gap_chart(tmp_path, gap):
    """As the heatmap: 10,000 frames in about a thousand pixels, each column shows a gap
    (missing, else filled) among its frames, so one missing frame is there to see: a
    column of the chart in the missing colour (drawn as it was, none of these three was)."""
    T, M = 10_000, 6

    def missing_columns(positions):
        """Pixel columns of the chart's middle half (no legend, title or axis labels) with
        a run of 10 pixels of the missing colour."""
        plot_gaps(Take(tuple("abcdef"), positions, rate=100.0), tmp_path / "g.png")
        image = cv2.imread(str(tmp_path / "g.png"))[:, :, ::-1].astype(int)
        image = image[len(image) // 4:3 * len(image) // 4]
        dark = np.abs(image - 0x20).max(axis=2) <= 2                 # #202020
        runs = np.lib.stride_tricks.sliding_window_view(dark, 10, axis=0).all(axis=-1)
        return int(runs.any(axis=0).sum())

    positions = np.zeros((T, M, 3))
    assert missing_columns(positions) == 0
    positions[gap, 3] = np.nan                                   # one marker, one frame
    assert missing_columns(positions) >= 1


def test_ingestion_figures_drawn_by_a_helper_from_what_they_show(tmp_path, facial_sing_take,
                                                                facial_sing_markerset):
    """The gap chart and the head residuals a helper draws from GapChart and HeadResiduals
    (a small part of the take) are the files drawn here from the take itself; the chart's
    counts are the take's."""
    take = facial_sing_take
    stabilization = stabilize(take, facial_sing_markerset.head)
    chart, residuals = GapChart.of(take), HeadResiduals.of(stabilization)
    counts = {"present": int((~take.missing & (take.filled == 0)).sum()),
              "missing": int(take.missing.sum())}
    counts.update({m: int((take.filled == i + 1).sum()) for i, m in enumerate(FILL_METHODS)})
    assert chart.counts == counts
    assert chart.codes.shape == (take.n_markers, min(take.n_frames, HEATMAP_COLUMNS))
    for small, whole in ((chart, take), (residuals, stabilization)):
        assert len(pickle.dumps(small)) * 10 < len(pickle.dumps(whole))
    plot_gaps(take, tmp_path / "gaps-here.png")
    plot_head_residuals(stabilization, tmp_path / "head-here.png")
    with FigureQueue(helpers=1) as figures:
        figures.submit(plot_gaps, chart, tmp_path / "gaps-helper.png")
        figures.submit(plot_head_residuals, residuals, tmp_path / "head-helper.png")
        wait_for_file(tmp_path / "head-helper.png")         # both drawn by the helper
        figures.run()
    for name in ("gaps", "head"):
        assert (tmp_path / f"{name}-helper.png").read_bytes() == \
            (tmp_path / f"{name}-here.png").read_bytes()


def test_a_line_envelope_draws_the_pixels_of_the_whole_line(tmp_path):
    """35,000 samples of four noisy lines drawn by their envelope (≤ 4 points a pixel
    column): the same picture, to antialiasing where lines cross."""
    rng = np.random.default_rng(0)
    t = np.arange(35_000) / 276.0
    lines = [np.abs(np.cumsum(rng.normal(0, 0.05, t.size))) + rng.normal(0, 0.3, t.size)
             for _ in range(4)]
    lines[1][1_000:1_200] = np.nan                                # a break in one line

    def draw(name, envelope):
        with report_figure(tmp_path / name, 11, 4.4) as fig:
            ax = fig.add_subplot()
            for y in lines:
                ax.plot(*(line_envelope(t, y, 11 * 120) if envelope else (t, y)), lw=0.8)
        return cv2.imread(str(tmp_path / name)).astype(int)

    x, y = line_envelope(t, lines[1], 11 * 120)
    assert len(x) < 4 * 11 * 120 + 200 and np.isnan(y).sum() == 200
    assert np.all(np.diff(x) > 0)
    full, drawn = draw("full.png", False), draw("envelope.png", True)
    differ = np.abs(full - drawn).max(axis=2)
    assert (differ > 0).mean() < 0.06 and (differ > 64).mean() < 0.01


@pytest.mark.parametrize("axis, text", [("y", {"fontsize": 6}),
                                         ("x", {"rotation": 70, "ha": "right",
                                                "rotation_mode": "anchor", "fontsize": 7})])
def test_labelled_ticks_draw_the_picture_of_the_axis_own(tmp_path, axis, text):
    """label_ticks (one line of tick markers, a text per label) against matplotlib's own
    ticks and labels at the same places: the same pixels, the layout making room for the
    labels as it does for the axis' (a long label widens the margin)."""
    labels = [f"marker-{i}" for i in range(60)]
    labels[7] = "a-much-longer-label-than-the-others"
    positions = np.arange(60) * 1.5

    def draw(name, ours):
        with report_figure(tmp_path / name, 11, 6) as fig:
            ax = fig.add_subplot()
            ax.plot(positions, np.sin(positions)) if axis == "x" else \
                ax.plot(np.sin(positions), positions)
            if ours:
                label_ticks(ax, positions, labels, axis=axis, **text)
            elif axis == "y":
                ax.set_yticks(positions, labels, **text)
            else:
                ax.set_xticks(positions, labels, **text)
            ax.set_title("ticks")
        return cv2.imread(str(tmp_path / name)).astype(int)

    ours, theirs = draw("ours.png", True), draw("theirs.png", False)
    assert ours.shape == theirs.shape
    np.testing.assert_array_equal(ours, theirs)


def test_long_lines_stroked_in_pieces_draw_the_picture_of_one_stroke(tmp_path):
    """draw_png strokes long lines in pieces: six noisy residual lines of a 35,000-frame take
    by their envelope (the head-residual plot's), against matplotlib's own picture of each
    line as one stroke. Only antialiased pixels at the pieces' joins differ."""
    rng = np.random.default_rng(5)
    t = np.arange(35_000) / 276.0
    lines = [np.abs(rng.normal(0.3, 0.15, t.size)) for _ in range(6)]

    def figure():
        fig = new_figure(11, 4.4)
        ax = fig.add_subplot()
        for y in lines:
            ax.plot(*line_envelope(t, y, 11 * 120), lw=0.8)
        return fig

    one = figure()
    with rc_context({"agg.path.chunksize": 0, "text.parse_math": False,
                     "text.hinting": "no_hinting"}):      # the text as ours
        one.set_dpi(120)
        one.canvas.draw()
    whole = np.asarray(one.canvas.buffer_rgba())[:, :, :3].astype(int)
    draw_png(figure(), tmp_path / "pieces.png", dpi=120)
    pieces = cv2.imread(str(tmp_path / "pieces.png"))[:, :, ::-1].astype(int)
    assert pieces.shape == whole.shape
    differ = np.abs(pieces - whole).max(axis=2)
    assert 0 < (differ > 0).mean() < 0.01 and (differ > 64).mean() < 0.003


def test_the_heatmap_of_a_real_marker_set_has_a_pixel_per_column(ict_markerset, tmp_path):
    """Beside the ICT layout's 60 marker names and 13 regions, at the page's width, the
    heatmap's image is wider than HEATMAP_COLUMNS pixels: resampling it to the screen drops
    no column."""
    from matplotlib import colormaps

    labels = ict_markerset.face_markers
    captured = np.ones((HEATMAP_COLUMNS, len(labels), 3))      # error √3 mm everywhere
    errors = reconstruction_errors(captured, np.zeros_like(captured),
                                   np.zeros((len(labels), 3)), labels=labels)
    plot_error_heatmap(errors, tmp_path / "h.png", markerset=ict_markerset, vmax=1.0)
    image = cv2.imread(str(tmp_path / "h.png"))[:, :, ::-1].astype(int)
    top = (np.array(colormaps["magma"](1.0)[:3]) * 255).round().astype(int)
    saturated = np.flatnonzero(np.abs(image[image.shape[0] // 2] - top).max(axis=1) <= 2)
    image_width = saturated[-1] - saturated[0] + 1        # the colour bar is not saturated here
    assert image.shape[1] <= IMAGE_WIDTH_PX
    assert image_width >= HEATMAP_COLUMNS


def _bases_of_one_take(labels, n_frames: int = 900) -> dict:
    """Errors of three made-up bases of one take: missing samples, errors of other sizes, and
    a marker that one basis never reconstructs (its bars are left out)."""
    rng = np.random.default_rng(7)
    captured = rng.normal(0, 20, (n_frames, len(labels), 3))
    captured[100:160, 3] = np.nan
    results = {}
    for k, name in enumerate(("H", "QE", "PCA")):
        reconstructed = captured + rng.normal(0, 0.5 + k, captured.shape)
        if name == "PCA":
            reconstructed[:, 5] = np.nan
        results[name] = reconstruction_errors(captured, reconstructed, np.zeros((len(labels), 3)),
                                              labels=labels, name=name)
    return results


def test_each_bases_charts_laid_out_once_are_the_charts_drawn_anew(ict_markerset, tmp_path):
    """The heatmaps and per-marker charts of three bases drawn on one figure, laid out for the
    first: each PNG has the pixels of the chart drawn alone (on the same scales), though
    their errors, titles and numbers of bars differ."""
    results = _bases_of_one_take(ict_markerset.face_markers)
    vmax, ymax = 4.0, error_axis_top(results)
    assert ymax == pytest.approx(1.08 * max(np.nanmax(r.marker_p95) for r in results.values()))
    plot_error_heatmaps(results, {b: tmp_path / f"heat-{b}.png" for b in results},
                        markerset=ict_markerset, rate=120.0, vmax=vmax)
    plot_marker_error_charts({b: r.per_frame() for b, r in results.items()},
                             {b: tmp_path / f"bars-{b}.png" for b in results},
                             markerset=ict_markerset)
    for b, errors in results.items():
        plot_error_heatmap(errors, tmp_path / "heat.png", markerset=ict_markerset, rate=120.0,
                           vmax=vmax)
        plot_marker_errors(errors, tmp_path / "bars.png", markerset=ict_markerset, ymax=ymax)
        for kind in ("heat", "bars"):
            alone = cv2.imread(str(tmp_path / f"{kind}.png"))
            together = cv2.imread(str(tmp_path / f"{kind}-{b}.png"))
            assert together.shape == alone.shape and np.array_equal(together, alone), (kind, b)
    first = cv2.imread(str(tmp_path / "heat-H.png"))
    assert not np.array_equal(first, cv2.imread(str(tmp_path / "heat-QE.png")))
    # what the report sends a figure helper: the heatmaps' columns, the same pictures
    columns = {b: HeatmapColumns.of(r) for b, r in results.items()}
    plot_error_heatmaps(columns, {b: tmp_path / f"cols-{b}.png" for b in results},
                        markerset=ict_markerset, rate=120.0, vmax=vmax)
    for b in results:
        assert np.array_equal(cv2.imread(str(tmp_path / f"cols-{b}.png")),
                              cv2.imread(str(tmp_path / f"heat-{b}.png"))), b


def test_each_bases_views_on_one_scale_laid_out_once_are_the_views_drawn_anew(sing_case,
                                                                              tmp_path):
    """The views of several bases, each at its own frames (markers missing in one), drawn on
    one figure laid out for the first: each PNG has the pixels of the views laid out for
    themselves (drawn first), though views of fewer frames or a title of two lines need
    layouts of their own; views of as many frames share one scale (one size)."""
    ms, face, recs, neutral = sing_case
    rng = np.random.default_rng(4)
    bases = {**recs, "PCA": face.positions + rng.normal(0.0, 1.5, face.positions.shape)}
    frames = {"H": [400, 120, 515], "QE": [398, 30, 250], "PCA": [9, 300, 590], "two": [1, 2],
              "tall": [5, 6, 7]}
    captured = face.positions.copy()
    captured[30, :4] = np.nan
    views = {name: FrameViews(captured[t], bases.get(name, recs["H"])[t], np.array(t) + 7,
                              title=f"{name}: views" + ("\nof two lines" if name == "tall" else
                                                        "")) for name, t in frames.items()}

    def draw(order, prefix):
        plot_views_of_bases({b: views[b] for b in order},
                            {b: tmp_path / f"{prefix}-{b}.png" for b in order},
                            neutral=neutral, labels=face.labels, markerset=ms)
    draw(list(views), "together")
    sizes = {b: cv2.imread(str(tmp_path / f"together-{b}.png")).shape for b in views}
    assert sizes["H"] == sizes["QE"] == sizes["PCA"] == sizes["tall"] != sizes["two"]
    for b in views:
        draw([b, *(other for other in views if other != b)], f"{b}-first")
        alone = cv2.imread(str(tmp_path / f"{b}-first-{b}.png"))
        together = cv2.imread(str(tmp_path / f"together-{b}.png"))
        assert np.array_equal(together, alone), b
    assert not np.array_equal(cv2.imread(str(tmp_path / "together-H.png")),
                              cv2.imread(str(tmp_path / "together-QE.png")))
    with pytest.raises(InputError, match=r"views 'odd': captured and reconstructed must have "
                                         r"shape \(2, "):
        plot_views_of_bases({"odd": FrameViews(captured[:2], captured[:3], np.arange(2))},
                            {"odd": tmp_path / "odd.png"}, neutral=neutral, labels=face.labels)


def test_heatmap_columns_keep_each_columns_largest_error():
    """A long take's heatmap columns: each marker's largest error over the frames of each
    column (NaN where all are missing), the default colour scale the 99.5th percentile of
    every error (numpy's), and a pickle a fraction of the errors' size."""
    labels = [f"m{i}" for i in range(6)]
    errors = _bases_of_one_take(labels, n_frames=5 * HEATMAP_COLUMNS + 37)["QE"]
    heatmap = HeatmapColumns.of(errors)
    assert heatmap.columns.shape == (6, HEATMAP_COLUMNS)
    starts = np.linspace(0, errors.n_frames, HEATMAP_COLUMNS, endpoint=False).astype(int)
    stops = np.r_[starts[1:], errors.n_frames]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)         # all-NaN columns
        expected = np.stack([np.nanmax(errors.errors[a:b], axis=0)
                             for a, b in zip(starts, stops)], axis=1)
    np.testing.assert_array_equal(heatmap.columns, expected)
    assert np.isnan(heatmap.columns[3]).any()                     # the gap of marker 3
    finite = errors.errors[np.isfinite(errors.errors)]
    assert heatmap.top == np.percentile(finite, 99.5)
    assert heatmap.n_frames == errors.n_frames
    assert len(pickle.dumps(heatmap)) < len(pickle.dumps(errors)) / 4


def test_charts_whose_titles_shape_their_layout_are_laid_out_apart(tmp_path):
    """A title of two lines among titles of one gets its own layout; one wider than the
    charts' axes does not need one (constrained layout leaves a title's width out): every
    PNG is still the chart drawn alone."""
    labels = [f"m{i}" for i in range(6)]
    results = _bases_of_one_take(labels, n_frames=300)
    results["H2"] = dataclasses.replace(results["H"], name="H2")
    titles = {"H": "one line", "QE": "two\nlines", "PCA": "one line again",
              "H2": "a title far wider than the axes of these charts " * 4}
    plot_error_heatmaps(results, {b: tmp_path / f"heat-{b}.png" for b in results}, vmax=3.0,
                        titles=titles)
    plot_marker_error_charts(results, {b: tmp_path / f"bars-{b}.png" for b in results},
                             ymax=5.0, titles=titles)
    for b, errors in results.items():
        plot_error_heatmap(errors, tmp_path / "heat.png", vmax=3.0, title=titles[b])
        plot_marker_errors(errors, tmp_path / "bars.png", ymax=5.0, title=titles[b])
        for kind in ("heat", "bars"):
            alone = cv2.imread(str(tmp_path / f"{kind}.png"))
            together = cv2.imread(str(tmp_path / f"{kind}-{b}.png"))
            assert together.shape == alone.shape and np.array_equal(together, alone), (kind, b)


def test_charts_of_several_bases_must_be_of_one_take(ict_markerset, tmp_path):
    labels = ict_markerset.face_markers
    results = _bases_of_one_take(labels)
    other = _bases_of_one_take(labels[::-1])["QE"]
    shorter = _bases_of_one_take(labels, n_frames=800)["QE"]
    for odd, match in ((other, "'QE' is of other markers than 'H'"),
                       (shorter, "'QE' has 800 frames, 'H' 900")):
        with pytest.raises(InputError, match=match):
            plot_error_heatmaps({"H": results["H"], "QE": odd},
                                {"H": tmp_path / "a.png", "QE": tmp_path / "b.png"})
    with pytest.raises(InputError, match="other markers"):
        plot_marker_error_charts({"H": results["H"], "QE": other},
                                 {"H": tmp_path / "a.png", "QE": tmp_path / "b.png"})
    plot_marker_error_charts({"H": results["H"], "QE": shorter},      # frames not drawn
                             {"H": tmp_path / "a.png", "QE": tmp_path / "b.png"})
    assert (tmp_path / "b.png").exists()


def _sample_chart(fig):
    ax = fig.add_subplot()
    ax.plot([0, 1, 2], [0.7, 1.3, 0.9], label="$\\frac{a}{$ b$")
    ax.scatter([0.5, 1.5], [1.0, 1.1], s=30, color="red")
    ax.set_title("$x$: a label from a file")
    fig.legend(loc="outside lower center")


def test_a_report_figure_has_the_pixels_of_savefig_in_one_draw(tmp_path):
    with report_figure(tmp_path / "once.png", 5, 3) as fig:
        _sample_chart(fig)
    # the labels as typed and their glyphs unhinted, as ours
    with rc_context({"text.parse_math": False, "text.hinting": "no_hinting"}):
        reference = new_figure(5, 3)
        _sample_chart(reference)
        reference.savefig(tmp_path / "savefig.png", dpi=120)
    once, saved = (cv2.imread(str(tmp_path / n)) for n in ("once.png", "savefig.png"))
    assert once.shape == (360, 600, 3)
    np.testing.assert_array_equal(once, saved)
    with pytest.raises(RuntimeError, match="drawing failed"):
        with report_figure(tmp_path / "none.png", 5, 3) as fig:
            fig.add_subplot()
            raise RuntimeError("drawing failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["once.png", "savefig.png"]


def test_log_axis_labels_are_plain_numbers(tmp_path):
    with report_figure(tmp_path / "log.png", 5, 3) as fig:
        ax = fig.add_subplot()
        ax.plot([0, 1], [0.65, 1.4])
        ax.set_yscale("log")
        plain_log_axis(ax.yaxis)
    shown = [t.get_text() for t in ax.yaxis.get_ticklabels(which="both")
             if t.get_text() and ax.get_ylim()[0] <= t.get_position()[1] <= ax.get_ylim()[1]]
    assert {"0.7", "0.8", "0.9", "1"} <= set(shown)
    assert all("$" not in text for text in shown)


def test_bar_collection_draws_finite_bars_from_zero():
    colours = np.array([[1, 0, 0, 1], [0, 1, 0, 1], [0, 0, 1, 0.5]], float)
    bars = bar_collection(np.array([0.0, 1.0, 2.0]), np.array([2.0, np.nan, -1.0]),
                          np.array([0.8, 0.8, 0.4]), colours)
    corners = [p.vertices[:4] for p in bars.get_paths()]
    np.testing.assert_allclose(corners, [[[-0.4, 0], [-0.4, 2], [0.4, 2], [0.4, 0]],
                                         [[1.8, 0], [1.8, -1], [2.2, -1], [2.2, 0]]])
    np.testing.assert_array_equal(bars.get_facecolor(), colours[[0, 2]])
    assert bars.sticky_edges.y == [0] and bars.sticky_edges.x == []
    across = bar_collection(np.array([3.0]), np.array([5.0]), np.array([0.5]), colours[:1],
                            horizontal=True)
    np.testing.assert_allclose(across.get_paths()[0].vertices[:4],
                               [[0, 2.75], [5, 2.75], [5, 3.25], [0, 3.25]])
    assert across.sticky_edges.x == [0] and across.sticky_edges.y == []


@pytest.mark.parametrize("bad, message", [
    (-2e6, r"reconstructed positions: marker 'm3' at frame 16 is -2e\+06, beyond ±1e\+06"),
    (2e6, r"reconstructed positions: marker 'm3' at frame 16 is 2e\+06, beyond ±1e\+06"),
    (-np.inf, "reconstructed contains infinite values")])
def test_views_refuse_a_value_out_of_range_in_a_frame_not_drawn(tmp_path, bad, message):
    rng = np.random.default_rng(1)
    neutral = rng.normal(size=(5, 3)) * 30
    captured = neutral + rng.normal(size=(8, 5, 3))
    captured[2, 1] = np.nan                              # missing: kept, not refused
    reconstructed = captured + 0.5
    reconstructed[6, 3, 2] = bad
    with pytest.raises(InputError, match=message):
        plot_frame_views(captured, reconstructed, [1], tmp_path / "v.png", neutral=neutral,
                         labels=[f"m{j}" for j in range(5)], first_frame=10)
    assert not (tmp_path / "v.png").exists()
    plot_frame_views(captured, captured + 0.5, [1, 2], tmp_path / "v.png", neutral=neutral)
    assert _png_size(tmp_path / "v.png")[0] <= IMAGE_WIDTH_PX



def _png_row_filters(path) -> list:
    """The filter type of every row of an 8-bit RGB PNG (the PNG specification: the IDAT
    chunks' zlib stream holds each row as its filter byte, then its filtered bytes)."""
    raw, at, idat = Path(path).read_bytes(), 8, b""
    while at < len(raw):
        length, kind = struct.unpack(">I4s", raw[at:at + 8])
        if kind == b"IHDR":
            width, height = struct.unpack(">II", raw[at + 8:at + 16])
        elif kind == b"IDAT":
            idat += raw[at + 8:at + 8 + length]
        at += 12 + length
    rows = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(height, 1 + 3 * width)
    return rows[:, 0].tolist()


def test_write_png_filters_each_row_by_the_row_above(tmp_path):
    """Every row is its difference from the row above (PNG filter type 2, "Up"), and the
    pixels read back by another decoder (PIL)."""
    rng = np.random.default_rng(4)
    image = np.repeat(rng.integers(0, 256, (40, 1, 3), np.uint8), 30, axis=1)  # flat rows
    image[::7] = rng.integers(0, 256, (6, 30, 3), np.uint8)                   # and noisy
    write_png(image, tmp_path / "a.png")
    assert set(_png_row_filters(tmp_path / "a.png")) == {2}
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "a.png")), image)


def test_write_png_keeps_the_pixels_and_refuses_what_is_no_image(tmp_path):
    rgba = np.zeros((4, 6, 4), np.uint8)
    rgba[1, 2] = (255, 10, 0, 255)
    write_png(rgba, tmp_path / "a.png")
    np.testing.assert_array_equal(cv2.imread(str(tmp_path / "a.png"))[:, :, ::-1],
                                  rgba[:, :, :3])
    with pytest.raises(InputError, match="need a uint8 RGB or RGBA image, got float64"):
        write_png(rgba.astype(float), tmp_path / "b.png")
    assert [p.name for p in tmp_path.iterdir()] == ["a.png"]
