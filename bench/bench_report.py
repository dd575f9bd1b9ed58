"""Benchmark: the QA report of the 35,000-frame take against its floor (issue 16, "Report").

The inputs are those of ``bench_chain.py``: its simulated take (the ICT face, 60 face
markers), read, ingested, bound, retargeted and fitted as the chain does. Timed:
:func:`fit.report.build_report` (figures and HTML, no video) as its default draws them,
every figure in this process; with the figure queue ``mocap2mesh run`` and
``bench_chain.py`` give it (one helper process per spare core, forked by the server this
process forks at its start, as the command does: :mod:`fit.report.forked_helpers`; where
it cannot, fresh interpreters started :data:`HELPER_LEAD_S` before, as the command starts
them with the exports: one draws once it has imported the report's modules, about 0.7 s
on 2 cores); and each figure's own time beside the time of encoding its pixels.

Floor: what the report must do however its figures are drawn, i.e. encode the pixels of
every PNG it writes (decoded from its own files beforehand, then encoded again by
:func:`mocap.viz.figures.write_png`, the report's encoder: zlib level 6) and write the
HTML page's bytes. Drawing is what lies between the two; the ratio says how far from the
floor it is. Ratios are of one run (the machine may be shared).

Usage: ``python bench/bench_report.py [--frames 35000] [--repeat 2]``.
"""

from __future__ import annotations

import argparse
import os
import time
import warnings
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from _common import REPO, report_floor, scratch_directory  # noqa: E402
from bench_chain import simulate  # noqa: E402

import fit.report.drawing  # noqa: E402
import mocap  # noqa: E402
from fit import pipeline  # noqa: E402
from fit.report import build_report  # noqa: E402
from fit.report.figure_queue import FigureQueue  # noqa: E402
from fit.report.forked_helpers import start_fork_server  # noqa: E402
from mocap.clean.ingest import IngestOptions  # noqa: E402
from mocap.mesh.landmarks import load_mesh_landmarks  # noqa: E402


def inputs(frames: int, out: Path) -> dict:
    """The arguments of the chain's build_report call."""
    artist, markerset, sim = simulate(frames, out / "take.c3d")
    landmarks = load_mesh_landmarks(REPO / "tests" / "ict_landmarks.toml", artist.neutral)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ingested = pipeline.ingest_stage(mocap.read(out / "take.c3d"), markerset,
                                         IngestOptions(fill="auto", max_gap=sim.n_frames))
        take = pipeline.complete_span(ingested.take, markerset.face_markers)
        bound = pipeline.bind_stage(take, markerset, artist.neutral, landmarks,
                                    options=pipeline.BindOptions(skin_offset=2.0))
        retargeted = pipeline.retarget_stage(take, bound, artist.neutral, markerset)
        bases = pipeline.basis_stage(retargeted, artist)
        fitted = pipeline.fit_stage(take, bound, retargeted, bases)
    face = take.select(retargeted.labels)
    return dict(take=face, reconstructions=fitted.reconstructed,
                neutral=face.positions[bound.frame], markerset=markerset, pca=bases.pca,
                ingest=ingested)


#: Seconds a figure queue is started before the report it draws (its helper's start).
HELPER_LEAD_S = 1.5


def report(args: dict, out: Path, figures: FigureQueue | None = None) -> dict:
    out.mkdir(exist_ok=True)
    return build_report(args["take"], args["reconstructions"], args["neutral"], out,
                        markerset=args["markerset"], pca=args["pca"], ingest=args["ingest"],
                        video=False, figures=figures)


def figure_seconds(args: dict, out: Path) -> dict:
    """Seconds from each report figure's creation (or its previous PNG: a figure written for
    each basis) to its PNG written, keyed by the file's name: the report once more, with
    :mod:`fit.report.drawing` timed (the coverage plot of :mod:`basis` is drawn without it)."""
    seconds, since = {}, {}
    new_figure, draw_png = fit.report.drawing.new_figure, fit.report.drawing.draw_png

    def start(*size):
        fig = new_figure(*size)
        since[id(fig)] = time.perf_counter()
        return fig

    def end(fig, path, **options):
        draw_png(fig, path, **options)
        now = time.perf_counter()
        seconds[Path(path).name] = now - since[id(fig)]
        since[id(fig)] = now

    fit.report.drawing.new_figure, fit.report.drawing.draw_png = start, end
    try:
        report(args, out)
    finally:
        fit.report.drawing.new_figure, fit.report.drawing.draw_png = new_figure, draw_png
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=35_000)
    parser.add_argument("--repeat", type=int, default=2)
    options = parser.parse_args()
    # as the command does: the figure helpers' server forked before any thread starts
    forked = start_fork_server()
    lead = 0.0 if forked else HELPER_LEAD_S
    out = scratch_directory("bench_report_")
    args = inputs(options.frames, out)
    take = args["take"]
    print(f"take: {take.n_frames} frames, {take.n_markers} face markers, bases "
          f"{', '.join(args['reconstructions'])}")
    report(args, out / "warm")                            # fonts, caches
    best = started = floor = float("inf")
    for k in range(options.repeat):                       # interleaved: one run's ratio
        tic = time.perf_counter()
        files = report(args, out / f"report-{k}")
        best = min(best, time.perf_counter() - tic)
        with FigureQueue() as figures:
            helpers = figures.helpers
            time.sleep(lead)
            tic = time.perf_counter()
            report(args, out / f"started-{k}", figures)
            started = min(started, time.perf_counter() - tic)
        total, per_png = report_floor(files.values(), out / f"floor-{k}")
        floor = min(floor, total)
    seconds = figure_seconds(args, out / "figures")
    print(f"\n{'figure':<28} {'drawn s':>8} {'encode s':>9}")
    for name, sec in sorted(seconds.items(), key=lambda item: -item[1]):
        print(f"{name:<28} {sec:>8.3f} {per_png.get(name, float('nan')):>9.3f}")
    print(f"{'figures, sum':<28} {sum(seconds.values()):>8.3f} {sum(per_png.values()):>9.3f}")
    print(f"\nfloor (PNG pixels encoded + HTML bytes written): {floor:.2f} s")
    print(f"build_report, every figure in this process (its default): {best:.2f} s = "
          f"{best / floor:.1f}× the floor; with run's figure queue ({helpers} "
          f"helper(s), {'forked by its server' if forked else 'fresh interpreters'}, "
          f"started {lead:g} s before): {started:.2f} s = "
          f"{started / floor:.1f}× (aim: 3 s; the rest beside the figures: the errors of "
          "fit.metrics, the HTML)")


if __name__ == "__main__":
    main()
