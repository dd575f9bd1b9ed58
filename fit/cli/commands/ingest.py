"""``mocap2mesh ingest FILE -o OUT``: clean, filter, resample and stabilize a take."""

from __future__ import annotations

from pathlib import Path

from tqdm import tqdm

import mocap
from fit.cli.arguments import add_fill, add_markerset, add_stabilize, stabilize_options
from fit.report.ingest_plots import plot_gaps, plot_head_residuals
from mocap.clean.gapfill import DEFAULT_MIN_VISIBLE
from mocap.clean.ingest import EXTRA_MARKERS, IngestOptions, ingest, save_head_motion
from mocap.markerset import load_markerset

HELP = "gap-fill, filter, resample and head-stabilize a marker file"

__all__ = ["add_parser", "run", "ingest_file"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "ingest", help=HELP,
        description="Read a capture, fill its gaps, low-pass and resample it, express it in "
                    "the head frame, and write it as .c3d, .csv or .npz (by extension).")
    p.add_argument("file", help="input C3D, Vicon Nexus CSV, TRC or .npz take")
    p.add_argument("-o", "--output", required=True, type=Path,
                   help="output .c3d, .csv or .npz (never one of the inputs)")
    add_markerset(p, required=False, help="marker-set TOML (head markers, regions)")
    p.add_argument("--fix-swaps", action="store_true",
                   help="find and undo label swaps between neighbouring markers first")
    p.add_argument("--reject-implausible", action="store_true",
                   help="remove teleports, doubly labelled markers and ghost slides before "
                        "filling (in the head frame with --markerset)")
    add_fill(p)
    p.add_argument("--min-visible", type=float, default=DEFAULT_MIN_VISIBLE, metavar="FRACTION",
                   help="markers visible in fewer of the frames are reported, not filled "
                        f"(default {DEFAULT_MIN_VISIBLE:g})")
    p.add_argument("--extra-markers", choices=EXTRA_MARKERS, default="carry",
                   help="markers outside --markerset: carried unfilled (default) or dropped")
    p.add_argument("--lowpass", type=float, metavar="HZ", help="Butterworth cut-off")
    p.add_argument("--resample", type=float, metavar="HZ", help="new frame rate")
    add_stabilize(p, default=None, const="head",
                  help="express the markers in the head frame and write OUT.head.npz: 'head' "
                       "(the marker set's head markers; also --stabilize alone, the old "
                       "spelling), 'auto' (the face markers that hold their shape best, or the "
                       "marker set's stabilization list; the choice is in OUT.head.npz and "
                       "printed with -v) or 'none' (the take is in the head frame already: "
                       "checked, with a warning when the face moves rigidly)")
    p.add_argument("--qa", type=Path, metavar="DIR", help="write QA pictures here")
    p.add_argument("-v", "--verbose", action="store_true",
                   help="print how the head frame was found: the markers, their residuals, "
                        "the frames they could not hold")
    p.set_defaults(run=run)


def ingest_file(path, output, *, markerset_path=None, options=IngestOptions(), qa_dir=None):
    """Read `path`, ingest it, write `output` (and the QA pictures); returns the result."""
    inputs = [p for p in (path, markerset_path) if p is not None]
    stages = 2 + (qa_dir is not None)
    with tqdm(total=stages, desc=f"ingest {Path(path).name}", disable=None, leave=False) as bar:
        markerset = load_markerset(markerset_path) if markerset_path else None
        take = mocap.read(path)
        result = ingest(take, markerset=markerset, options=options)
        bar.update()
        mocap.write(result.take, output, inputs=inputs)
        if result.head_frame is not None:
            save_head_motion(result.head_frame, Path(output).with_suffix(".head.npz"),
                             inputs=inputs)
        bar.update()
        if qa_dir is not None:
            qa_dir = Path(qa_dir)
            qa_dir.mkdir(parents=True, exist_ok=True)
            plot_gaps(result.cleaned, qa_dir / "gaps.png")
            if result.stabilization is not None:
                plot_head_residuals(result.stabilization, qa_dir / "head_residuals.png")
            bar.update()
    return result


def run(args) -> int:
    options = IngestOptions(fix_swaps=args.fix_swaps, reject_implausible=args.reject_implausible,
                            fill=args.fill, max_gap=args.max_gap, min_visible=args.min_visible,
                            extra_markers=args.extra_markers, lowpass_hz=args.lowpass,
                            resample_hz=args.resample, stabilize=args.stabilize,
                            **stabilize_options(args))
    result = ingest_file(args.file, args.output, markerset_path=args.markerset, options=options,
                         qa_dir=args.qa)
    if args.verbose and result.head_frame is not None:
        print("\n".join(result.head_frame.report()))
    return 0
