"""QA of reconstructions: charts, marker views, mesh renders, overlay video and a
self-contained HTML report per take.

:func:`build_report` runs it all for one take and several bases; the modules
beside it draw each piece on its own. The page is a list of sections
(:class:`fit.report.html.Section`); callers add their own with ``sections=``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from basis.coverage import plot_coverage
from fit.metrics import alpha_origin, reconstruction_errors
from fit.report.extremes import take_extremes
from fit.report.figure_queue import FigureQueue
from fit.report.html import Figure, Section, Video, ingest_stats, write_report
from fit.report.mesh_views import MESH_VIEWS, mesh_cameras, plot_mesh_frames
from fit.report.plots import (
    HeatmapColumns,
    error_axis_top,
    plot_alpha,
    plot_error_heatmaps,
    plot_held_out,
    plot_marker_error_charts,
)
from fit.report.retarget_qa import (
    cross_validation_section,
    lip_seal_section,
    plot_cross_validation,
    plot_lip_seal,
)
from fit.report.video import VIDEO_SUFFIX, overlay_frames
from fit.report.views import FrameViews, plot_views_of_bases, plottable_positions
from mocap.errors import InputError
from mocap.util.order_statistics import percentile
from mocap.viz.render import compiled_renders
from mocap.viz.webm import can_join, join_webm

__all__ = ["build_report"]

#: Worst frames of each basis rendered on the mesh.
_MESH_WORST = 3
#: At most this many frames in the W·D renders.
_MESH_RETARGETED = 6


def _given_errors(errors: Mapping, basis: str, take, neutral, origin):
    """``errors[basis]``, checked to be of `basis`, the take's markers and frames and the
    origin of α (`origin`, default the centroid of `neutral`)."""
    given = errors.get(basis)
    if given is None:
        raise InputError(f"errors has no entry for basis {basis!r}")
    expected = alpha_origin(neutral, origin)
    if given.name != basis or tuple(given.labels) != tuple(take.labels) \
            or given.errors.shape != (take.n_frames, len(take.labels)) \
            or not np.array_equal(given.origin, expected):
        raise InputError(f"errors of basis {basis!r} are not of this take, its markers and "
                         f"origin (name {given.name!r}, {given.errors.shape[0]} frames, "
                         f"{len(given.labels)} markers)")
    return given


def _queue_video(queue: FigureQueue, take, reconstructions: Mapping, path: Path, *, neutral,
                 markerset, step, exaggerate) -> list:
    """Queue the overlay video to `path`, ahead of the figures: in as many parts as there
    are processes to draw them (the queue's helpers and this one), when its parts can be
    joined; returns the parts' paths, to join once they are written (just `path` for one).

    The video is the report's longest part. Its drawing holds the GIL of the process that
    draws it, so it is no thread of this process (whose figures need the GIL); each part
    is drawn by one process while another thread of it encodes the frames before."""
    frames = overlay_frames(take.positions, reconstructions, neutral=neutral, rate=take.rate,
                            labels=take.labels, markerset=markerset, step=step,
                            exaggerate=exaggerate, first_frame=take.first_frame)
    n_parts = max(1, min(queue.helpers + 1 if can_join() else 1, len(frames)))
    if n_parts == 1:
        queue.submit(frames.write, path)
        return [path]
    bounds = np.linspace(0, len(frames), n_parts + 1).round().astype(int)
    parts = [path.with_name(f".{path.stem}-part{k}{path.suffix}") for k in range(n_parts)]
    # a core for each part's process: one encoder thread each (FFmpeg's default, a thread
    # per core, has the parts' encoders wait for each other's cores; see WebmWriter)
    for part, first, stop in zip(parts, bounds[:-1], bounds[1:]):
        queue.submit(frames[first:stop].write, part, threads=1)
    return parts


def build_report(take, reconstructions: Mapping, neutral, out_dir, *, markerset=None,
                 origin=None, pca=None, ingest=None, pictures=None, video: bool = False,
                 video_step: int | str = "auto", n_worst: int = 5, exaggerate: float = 1.0,
                 name: str | None = None, warnings=(), provenance: Mapping | None = None,
                 grades=(), held_out=None, mesh_space=None, sections=(), cross_validation=None,
                 selection=None, lip_seal=None, figures: FigureQueue | None = None,
                 errors: Mapping | None = None) -> dict:
    """Metrics, figures, (video) and the HTML report of one take.

    Parameters
    ----------
    take : mocap.take.Take
        The captured markers that were reconstructed, head-stabilized, mm, NaN
        where missing; typically ``stabilized.select(markerset.face_markers)``
        (head markers would dilute α).
    reconstructions : mapping of basis name to array_like (T, M, 3), mm
        Reconstructed positions of the take's markers, one per basis.
    neutral : array_like, shape (M, 3), mm
        Rest positions (no NaN).
    out_dir : str or os.PathLike
        Existing directory; receives ``<name>-*.png``, ``<name>.html`` (and
        ``<name>-video.webm``).
    markerset : mocap.markerset.MarkerSet, optional
        Regions (grouping), landmarks (view orientation, the take's extremes).
    origin : array_like (3,), mm, optional
        Origin of α (default: centroid of `neutral`).
    pca : basis.pca.PCAModel, optional
        Adds the coverage curve.
    ingest : mocap.clean.ingest.IngestResult, optional
        Adds the ingestion table.
    pictures : mapping of str to path, optional
        PNGs made elsewhere (the gap chart, the head residuals), embedded first
        under their captions (a caption may be a Figure with how to read it).
    video : bool
        Also write the overlay video, a panel per basis (VP9 WebM, embedded).
    video_step : int or "auto"
        Draw every n-th frame in the video; "auto" (default): every frame up to
        60 Hz, fewer above (:func:`fit.report.video.video_step`).
    n_worst : int
        Worst frames shown and listed (of each basis, by RMS).
    exaggerate : float
        Error vectors drawn this many times longer in views and video.
    name : str, optional
        File stem and title; default the take's file stem or ``"take"``.
    warnings : sequence of str
        Warnings of the run of the take, listed in a section of their own.
    provenance : mapping, optional
        What made the results (:func:`fit.report.html.render_report`).
    grades : sequence of (what, grade key, value)
        Graded figures of the stages before (binding, head fit); the bases'
        own are added here.
    held_out : fit.pipeline.holdout.HeldOut or callable, optional
        Reconstructions by bases not built from the frames they reconstruct:
        out-of-sample errors beside the in-sample ones; or a function of no
        arguments that makes them (or returns None), called once the figures
        before them are queued, so that `figures`' helpers draw those meanwhile.
    mesh_space : fit.report.mesh_views.MeshSpace, optional
        Adds shaded renders of each basis's mesh and of W·D at the worst frames
        and at the take's extremes (needs `markerset` for the extremes).
    sections : sequence of fit.report.html.Section
        Further sections, appended in order.
    cross_validation : mocap.retarget.cross_validation.CrossValidation, optional
        Adds the retargeting's held-out errors per marker and region
        (:attr:`mocap.retarget.retargeting.Retargeting.cross_validation`).
    selection : mocap.retarget.selection.RetargetSelection, optional
        With it, what ``kernel = "auto"`` tried.
    lip_seal : mocap.retarget.lip_seal.LipSealCheck, optional
        Adds the lip-seal section (its warnings at the top of it).
    figures : fit.report.figure_queue.FigureQueue, optional
        Draws the figures, shared with its helper processes (make it before other work,
        so that they have started); default: all in this process, one after another.
    errors : mapping of basis name to fit.metrics.ReconstructionErrors, optional
        The errors of `reconstructions` against `take` from `neutral`, already computed
        (the pipeline's, for its manifest): used as they are, after a check that each is
        of its basis, the take's markers and frames and `origin`. Default: computed here.

    Returns
    -------
    dict of str to pathlib.Path
        Every file written, keyed ``"html"``, ``"alpha"``, ``"coverage"``,
        ``"held-out"``, ``"heatmap-<basis>"``, ``"markers-<basis>"``,
        ``"views-<basis>"``, ``"video"`` (every basis), ``"mesh-<basis>"``, ``"mesh-WD"``,
        ``"cross-validation"``, ``"lip-seal"``.
    """
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise InputError(f"{out_dir}: output directory does not exist")
    if not reconstructions:
        raise InputError("reconstructions is empty: give at least one basis")
    name = name or (Path(take.source.path).stem if take.source.path else "take")
    separation = max(1, take.n_frames // 50)
    files = {}
    number = take.first_frame

    def out(key: str, suffix: str = ".png") -> Path:
        files[key] = out_dir / f"{name}-{key}{suffix}"
        return files[key]

    queue = FigureQueue(helpers=0) if figures is None else figures
    video_parts = []
    try:
        if video:
            video_parts = _queue_video(queue, take, reconstructions, out("video", VIDEO_SUFFIX),
                                       neutral=neutral, markerset=markerset, step=video_step,
                                       exaggerate=exaggerate)
        results, worst = {}, {}
        captured = plottable_positions(take.positions, "captured", labels=take.labels,
                                       first_frame=number)
        views, view_paths = {}, {}
        for basis, rec in reconstructions.items():
            results[basis] = (reconstruction_errors(take.positions, rec, neutral,
                                                    origin=origin, labels=take.labels,
                                                    name=basis)
                              if errors is None else _given_errors(errors, basis, take,
                                                                   neutral, origin))
            worst[basis] = results[basis].worst_frames(n_worst, separation=separation)
            views[basis] = _worst_views(captured, rec, worst[basis], basis, labels=take.labels,
                                        exaggerate=exaggerate, first_frame=number)
            view_paths[basis] = out(f"views-{basis}")
        # every basis's views on one scale, in one figure laid out once
        queue.submit(plot_views_of_bases, views, view_paths, neutral=neutral,
                     labels=take.labels, markerset=markerset, exaggerate=exaggerate)
        first = next(iter(results.values()))
        held_out, held, page = _figures(
            take, neutral, results, worst, reconstructions, out, files, number, queue.submit,
            markerset=markerset, pca=pca, pictures=pictures, video=video,
            exaggerate=exaggerate, held_out=held_out, mesh_space=mesh_space, origin=origin)
        if cross_validation is not None:
            queue.submit(plot_cross_validation, cross_validation, out("cross-validation"),
                         markerset=markerset)
            page.append(cross_validation_section(cross_validation, markerset=markerset,
                                                 selection=selection,
                                                 image=files["cross-validation"]))
        if lip_seal is not None:
            queue.submit(plot_lip_seal, lip_seal, out("lip-seal"))
            page.append(lip_seal_section(lip_seal, image=files["lip-seal"]))
        queue.run()
        if len(video_parts) > 1:
            join_webm(video_parts, files["video"])
    finally:
        if figures is None:
            queue.close()
        if len(video_parts) > 1:
            for part in video_parts:
                part.unlink(missing_ok=True)
    page += list(sections)
    graded = []
    for basis, res in results.items():
        graded += [(f"{basis}: marker RMS (mm)", "rms_mm", res.totals["rms_mm"]),
                   (f"{basis}: 95th-percentile error (mm)", "p95_mm", res.totals["p95_mm"])]
        if basis in held:
            in_rms = res.totals["rms_mm"]
            graded.append((f"{basis}: out-of-sample / in-sample RMS", "out_of_sample_ratio",
                           held[basis].totals["rms_mm"] / in_rms if in_rms > 0 else np.nan))
    files["html"] = out_dir / f"{name}.html"
    write_report(files["html"], results, {}, title=f"Reconstruction QA: {name}",
                 first_frame=number, worst=worst, markerset=markerset,
                 ingest=ingest_stats(ingest) if ingest is not None else None,
                 notes=f"{take.n_frames} frames at {take.rate:g} Hz (frames {number}–"
                       f"{number + take.n_frames - 1}), {len(first.labels)} markers, bases: "
                       f"{', '.join(results)}.",
                 provenance=provenance, grades=[*grades, *graded], sections=page,
                 held_out=held, held_out_label=held_out.label if held_out is not None else "",
                 warnings=warnings)
    return files


def _figures(take, neutral, results, worst, reconstructions, out, files, number, draw, *,
             markerset, pca, pictures, video, exaggerate, held_out, mesh_space, origin):
    """Every figure of the report, given to `draw` (``draw(function, *args, **kwargs)``)
    with what it shows; returns (held-out reconstructions, their errors, sections)."""
    page = []
    if pictures:
        page.append(Section("Ingestion and head stabilization", items=tuple(
            v if isinstance(v, Figure) else Figure(v, k) for k, v in pictures.items())))
    draw(plot_alpha, {b: r.per_frame() for b, r in results.items()}, out("alpha"),
         rate=take.rate, worst=worst, first_frame=number)
    page.append(Section("Error over time", items=(Figure(
        files["alpha"], "α(t) per basis",
        "One curve per basis on one axis; circles mark each basis's worst frames (by RMS), "
        "tagged with their frame numbers; a log axis is used when the bases differ by more "
        "than 10×."),)))
    # one colour scale and one error axis for every basis, each chart of every basis in
    # one figure laid out once, given what it shows (not every sample's error)
    heatmaps = {b: HeatmapColumns.of(r) for b, r in results.items()}
    vmax, ymax = max(h.top for h in heatmaps.values()), error_axis_top(results)
    draw(plot_error_heatmaps, heatmaps, {b: out(f"heatmap-{b}") for b in results},
         markerset=markerset, rate=take.rate, vmax=vmax)
    draw(plot_marker_error_charts, {b: r.per_frame() for b, r in results.items()},
         {b: out(f"markers-{b}") for b in results}, markerset=markerset, ymax=ymax)
    for basis, res in results.items():
        items = [
            Figure(files[f"heatmap-{basis}"], f"{basis}: error per marker and frame",
                   f"Rows are markers grouped by region, columns time; colour is the error "
                   f"in mm on one scale for every basis (0–{vmax:.2g} mm, the 99.5th "
                   "percentile of all bases; brighter is worse, grey is missing)."),
            Figure(files[f"markers-{basis}"], f"{basis}: mean and 95th percentile per marker",
                   "Narrow bars: mean error of each marker over the take; wide pale bars: "
                   "its 95th percentile; the same axis for every basis."),
            Figure(files[f"views-{basis}"], f"{basis}: worst frames, front and side",
                   "Red: captured markers; blue: reconstructed; black lines join them "
                   "(the error vectors); grey: the rest pose; one scale for every basis.")]
        page.append(Section(f"{basis}: marker-space errors", items=tuple(items)))
    if video:
        page.insert(2 if pictures else 1, Section("Overlay video", items=(Video(
            files["video"], "Captured vs reconstructed markers over the take",
            "One panel per basis, all on one scale, front view: captured (red) and "
            "reconstructed (blue) markers joined by their error vectors, the capture's frame "
            "number and each basis's RMS of that frame. Plays in the page (VP9 WebM)."),)))
    held = {}
    if callable(held_out):              # made while the figures queued so far are drawn
        held_out = held_out()
    if held_out is not None:
        held = {b: reconstruction_errors(take.positions, rec, neutral, origin=origin,
                                         labels=take.labels, name=b)
                for b, rec in held_out.reconstructed.items() if b in results}
        draw(plot_held_out, {b: r.per_frame() for b, r in results.items()},
             {b: r.per_frame() for b, r in held.items()}, out("held-out"), label=held_out.label)
        page.append(Section(
            "Out-of-sample basis errors",
            text=f"QE and PCA are built from this take; in-sample they are scored on the very "
                 f"frames they were built from, which flatters them. Out-of-sample: "
                 f"{held_out.label}. H does not come from the take: its figures are the same.",
            items=(Figure(files["held-out"], "In-sample vs out-of-sample marker errors",
                          "Blue: scored on the frames the basis was built from; orange: on "
                          "frames it was not built from. A large gap means the basis learnt "
                          "the take rather than the face."),)))
    if mesh_space is not None:
        page.append(_mesh_section(take, np.asarray(neutral, float), results, worst, mesh_space,
                                  markerset, out, files, number, draw))
    if pca is not None:
        draw(plot_coverage, pca.coverage_curve(), out("coverage"))
        page.append(Section("PCA coverage", items=(Figure(
            files["coverage"], "PCA coverage",
            "The share of the take's mesh motion (variance of W·D) the first k components "
            "explain; the PCA and QE bases keep the k marked."),)))
    return held_out, held, page


def _worst_views(captured, reconstructed, frames, basis: str, *, labels, exaggerate: float,
                 first_frame: int) -> FrameViews:
    """What the views of `basis` show: its 3 worst `frames`, only those frames."""
    shown = np.asarray(frames[:3])
    reconstructed = plottable_positions(reconstructed, "reconstructed", labels=labels,
                                        first_frame=first_frame)
    return FrameViews(captured[shown], reconstructed[shown], shown + first_frame,
                      title=f"{basis}: captured (red) vs reconstructed (blue) at the worst "
                            f"frames" + (f", errors ×{exaggerate:g}" if exaggerate != 1 else "")
                            + "; front: subject's left on the right")


def _mesh_section(take, neutral, results, worst, space, markerset, out, files, number,
                  draw) -> Section:
    """Renders of each basis's mesh and of W·D at the worst frames and the take's extremes."""
    extremes = [] if markerset is None else take_extremes(take.positions, neutral, take.labels,
                                                          markerset)
    cameras = mesh_cameras(space.neutral)

    def markers(index):
        """The captured markers at frames `index` in mesh coordinates."""
        shown = take.positions[index]
        return space.to_mesh(shown.reshape(-1, 3)).reshape(shown.shape)

    chosen = {}
    for basis in results:
        frames = [(int(t), f"frame {number + int(t)}: {basis} worst #{k}")
                  for k, t in enumerate(worst[basis][:_MESH_WORST], start=1)]
        frames += [(e.frame, f"frame {number + e.frame}: {e.name} ({e.measure} "
                             f"{e.value:.1f} mm)") for e in extremes]
        chosen[basis] = frames
    distances = {}
    for basis, frames in chosen.items():
        index = [t for t, _ in frames]
        gap = space.basis_mesh(basis, index) - space.retargeted_mesh(index)
        distances[basis] = np.linalg.norm(gap, axis=2) * space.mm_per_unit
    every = np.concatenate([d.ravel() for d in distances.values()])
    vmax = max(percentile(every, 99.0, overwrite_input=True), 0.5)
    renders = (sum(len(frames) for frames in chosen.values()) + _MESH_RETARGETED) \
        * len(MESH_VIEWS)
    # drawn here where this process renders by the compiled rasterizer (a helper would by
    # NumPy, about twice as slow), while the helpers draw the figures queued so far
    render = _draw_now if compiled_renders(renders, len(space.faces)) else draw
    items = []
    for basis, frames in chosen.items():
        index = [t for t, _ in frames]
        render(plot_mesh_frames, space.basis_mesh(basis, index), space.faces,
               out(f"mesh-{basis}"), captions=[c for _, c in frames], cameras=cameras,
               markers=markers(index), colors=distances[basis], vmax=vmax,
               color_label="mm to W.D",
               title=f"{basis} mesh at its worst frames and the take's extremes")
        items.append(Figure(files[f"mesh-{basis}"], f"{basis}: the reconstructed mesh",
                            "Front and side of the mesh this basis gives (what the exports "
                            "play), coloured by each vertex's distance to the retargeted mesh "
                            f"W·D on one scale for every basis (0–{vmax:.2g} mm); red dots: "
                            "the captured markers."))
    wd = list(dict.fromkeys([(e.frame, f"frame {number + e.frame}: {e.name}")
                             for e in extremes]
                            + [(int(worst[b][0]), f"frame {number + int(worst[b][0])}: "
                                                  f"{b} worst") for b in results]))
    seen, frames = set(), []
    for t, caption in wd:
        if t not in seen and len(frames) < _MESH_RETARGETED:
            seen.add(t)
            frames.append((t, caption))
    index = [t for t, _ in frames]
    render(plot_mesh_frames, space.retargeted_mesh(index), space.faces, out("mesh-WD"),
           captions=[c for _, c in frames], cameras=cameras, markers=markers(index),
           title="The retargeted mesh W.D at the same frames")
    items.append(Figure(files["mesh-WD"], "W·D: the retargeted mesh",
                        "The mesh motion every basis is fitted to: if the mouth stays shut "
                        "here while the red markers open it, no basis can open it."))
    return Section("Mesh-space QA", text="The meshes themselves, where a marker-space figure "
                   "cannot see: a basis can match every marker and still deform the face "
                   "wrongly between them.", items=tuple(items))


def _draw_now(function, *args, **kwargs) -> None:
    """Draw the figure ``function(*args, **kwargs)`` in this process, now."""
    function(*args, **kwargs)
