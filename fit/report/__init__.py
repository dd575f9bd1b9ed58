"""Marker-space QA of reconstructions: charts, marker views, overlay video and a
self-contained HTML report per take.

:func:`build_report` runs it all for one take and several bases; the modules
beside it draw each piece on its own.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

from basis.coverage import plot_coverage
from fit.metrics import reconstruction_errors
from fit.report.html import ingest_stats, write_report
from fit.report.plots import plot_alpha, plot_error_heatmap, plot_marker_errors
from fit.report.retarget_qa import (
    cross_validation_section,
    lip_seal_section,
    plot_cross_validation,
    plot_lip_seal,
)
from fit.report.video import write_overlay_video
from fit.report.views import plot_frame_views
from mocap.errors import InputError

__all__ = ["build_report"]


def build_report(take, reconstructions: Mapping, neutral, out_dir, *, markerset=None,
                 origin=None, pca=None, ingest=None, pictures=None, video: bool = False,
                 video_step: int = 1, n_worst: int = 5, exaggerate: float = 1.0,
                 name: str | None = None, cross_validation=None, selection=None,
                 lip_seal=None) -> dict:
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
        ``<name>-<basis>.mp4``).
    markerset : mocap.markerset.MarkerSet, optional
        Regions (grouping) and landmarks (view orientation).
    origin : array_like (3,), mm, optional
        Origin of α (default: centroid of `neutral`).
    pca : basis.pca.PCAModel, optional
        Adds the coverage curve.
    ingest : mocap.clean.ingest.IngestResult, optional
        Adds the ingestion table.
    pictures : mapping of str to path, optional
        PNGs made elsewhere (the gap chart, the head residuals), embedded first
        under their captions.
    video : bool
        Also write an overlay video per basis.
    video_step : int
        Draw every n-th frame in the video.
    n_worst : int
        Worst frames shown and listed (of the first basis, by RMS).
    exaggerate : float
        Error vectors drawn this many times longer in views and video.
    name : str, optional
        File stem and title; default the take's file stem or ``"take"``.
    cross_validation : mocap.retarget.cross_validation.CrossValidation, optional
        Adds the retargeting's held-out errors per marker and region
        (:attr:`mocap.retarget.retargeting.Retargeting.cross_validation`).
    selection : mocap.retarget.selection.RetargetSelection, optional
        With it, what ``kernel = "auto"`` tried.
    lip_seal : mocap.retarget.lip_seal.LipSealCheck, optional
        Adds the lip-seal section (its warnings at the top of it).

    Returns
    -------
    dict of str to pathlib.Path
        Every file written, keyed ``"html"``, ``"alpha"``, ``"coverage"``,
        ``"heatmap-<basis>"``, ``"markers-<basis>"``, ``"views-<basis>"``,
        ``"video-<basis>"``, ``"cross-validation"``, ``"lip-seal"``.
    """
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise InputError(f"{out_dir}: output directory does not exist")
    if not reconstructions:
        raise InputError("reconstructions is empty: give at least one basis")
    name = name or (Path(take.source.path).stem if take.source.path else "take")
    results = {basis: reconstruction_errors(take.positions, rec, neutral, origin=origin,
                                            labels=take.labels, name=basis)
               for basis, rec in reconstructions.items()}
    first = next(iter(results.values()))
    separation = max(1, take.n_frames // 50)
    worst = {b: r.worst_frames(n_worst, separation=separation) for b, r in results.items()}
    files, images = {}, dict(pictures or {})

    def out(key: str, suffix: str = ".png") -> Path:
        files[key] = out_dir / f"{name}-{key}{suffix}"
        return files[key]

    plot_alpha(results, out("alpha"), rate=take.rate, worst=worst,
               first_frame=take.first_frame)
    images["α(t) per basis"] = files["alpha"]
    for basis, res in results.items():
        plot_error_heatmap(res, out(f"heatmap-{basis}"), markerset=markerset, rate=take.rate)
        plot_marker_errors(res, out(f"markers-{basis}"), markerset=markerset)
        plot_frame_views(take.positions, reconstructions[basis], worst[basis][:3],
                         out(f"views-{basis}"), neutral=neutral, labels=take.labels,
                         markerset=markerset, exaggerate=exaggerate,
                         first_frame=take.first_frame,
                         title=f"{basis}: captured (red) vs reconstructed (blue) at the "
                               "worst frames" + (f", errors ×{exaggerate:g}"
                                                 if exaggerate != 1 else "")
                               + "; front: subject's left on the right")
        images[f"{basis}: error per marker and frame"] = files[f"heatmap-{basis}"]
        images[f"{basis}: mean and 95th percentile per marker"] = files[f"markers-{basis}"]
        images[f"{basis}: worst frames, front and side"] = files[f"views-{basis}"]
        if video:
            write_overlay_video(take.positions, reconstructions[basis],
                                out(f"video-{basis}", ".mp4"), neutral=neutral,
                                rate=take.rate, labels=take.labels, markerset=markerset,
                                step=video_step, exaggerate=exaggerate,
                                first_frame=take.first_frame)
    if pca is not None:
        plot_coverage(pca, out("coverage"))
        images["PCA coverage"] = files["coverage"]
    sections = []
    if cross_validation is not None:
        plot_cross_validation(cross_validation, out("cross-validation"), markerset=markerset)
        sections.append(cross_validation_section(cross_validation, markerset=markerset,
                                                 selection=selection,
                                                 image=files["cross-validation"]))
    if lip_seal is not None:
        plot_lip_seal(lip_seal, out("lip-seal"))
        sections.append(lip_seal_section(lip_seal, image=files["lip-seal"]))
    files["html"] = out_dir / f"{name}.html"
    write_report(files["html"], results, images, title=f"Reconstruction QA: {name}",
                 first_frame=take.first_frame, worst=worst, markerset=markerset,
                 ingest=ingest_stats(ingest) if ingest is not None else None,
                 notes=f"{take.n_frames} frames at {take.rate:g} Hz, "
                       f"{len(first.labels)} markers, bases: {', '.join(results)}.",
                 sections=sections)
    return files
