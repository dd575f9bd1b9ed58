"""``mocap2mesh synth``: simulate a facial capture with its ground truth."""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import mocap
from fit.cli.arguments import add_markerset, add_mesh, add_units
from mocap.errors import FileFormatError, InputError
from mocap.markerset import load_markerset
from mocap.mesh.layout import load_marker_layout
from mocap.mesh.mesh import load_mesh
from mocap.synth.capture import simulate_capture
from mocap.synth.performance import match_shape_names, read_performance
from mocap.synth.performance_gaps import TRACKING_FILLS, fill_tracking_gaps
from mocap.util.toml import read_toml

HELP = "simulate a facial capture (and its ground truth) from a performance"

__all__ = ["add_parser", "run", "parse_head_motion"]


def parse_head_motion(text: str) -> tuple[float, float]:
    """``"DEG,MM"`` -> (degrees, millimetres), both >= 0 (argparse type)."""
    try:
        deg, mm = (float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected DEG,MM (e.g. 15,30), got {text!r}") from None
    if not (deg >= 0 and mm >= 0):
        raise argparse.ArgumentTypeError(f"DEG and MM must be >= 0, got {text!r}")
    return deg, mm


def add_parser(sub) -> None:
    p = sub.add_parser(
        "synth", help=HELP,
        description="Drive a face mesh and its expression shapes with a weight performance, "
                    "place the markers of a layout on it, move the head, add noise and "
                    "occlusion gaps, and write the capture (.c3d or .csv) and, with --truth, "
                    "the ground truth (.npz: weights, head motion, true markers).")
    add_mesh(p, help="neutral mesh (OBJ, PLY, glTF)")
    add_units(p, help="units of the mesh (default: the layout file's 'units')")
    p.add_argument("--shapes", required=True, type=Path,
                   help="directory of expression OBJs (or a glTF/GLB with morph targets)")
    p.add_argument("--performance", required=True, type=Path,
                   help="weight performance CSV (time or Timecode column, one per shape)")
    p.add_argument("--layout", required=True, type=Path, help="marker layout TOML")
    add_markerset(p, help="marker-set TOML of the layout (its head markers stay rigid)")
    p.add_argument("-o", "--output", required=True, type=Path, help="capture .c3d or .csv")
    p.add_argument("--truth", type=Path, help="ground truth .npz")
    p.add_argument("--rate", type=float, default=100.0, metavar="HZ",
                   help="capture frame rate (default 100)")
    p.add_argument("--start", type=float, default=0.0, metavar="S",
                   help="start this far into the performance (s)")
    p.add_argument("--duration", type=float, metavar="S", help="capture length (s)")
    p.add_argument("--noise", type=float, default=0.2, metavar="MM",
                   help="marker noise, standard deviation per coordinate (default 0.2 mm)")
    p.add_argument("--gaps", type=int, default=0, metavar="N",
                   help="occlusion gaps to cut (default 0); most short, a few up to 1 s")
    p.add_argument("--neutral-lead", type=float, default=0.0, metavar="S",
                   help="start with a neutral hold this long, blending into the performance, "
                        "as a capture session does (default 0; bind it with --frame hold)")
    p.add_argument("--tracking-gaps", choices=("keep",) + TRACKING_FILLS, default="keep",
                   help="rows where the performance lost tracking: keep them as frames "
                        "with the face markers missing (default), or fill them by linear "
                        "interpolation or with the neutral face")
    p.add_argument("--seed", type=int, default=0, help="seed of head motion, noise, gaps")
    p.add_argument("--head-motion", type=parse_head_motion, default=(15.0, 30.0),
                   metavar="DEG,MM", help="peak head rotation per axis (deg) and translation "
                                          "(mm); 0,0 for none (default 15,30)")
    p.set_defaults(run=run)


def _layout_units(path: Path) -> str | None:
    """The ``units`` key of a layout file, None if absent or unreadable (the loader reports)."""
    try:
        return read_toml(path, "marker layout").get("units")
    except FileFormatError:
        return None


def _load_basis(mesh, shapes: Path, performance):
    """The artist basis; from a directory, only the shapes a performance column drives."""
    from basis.artist import load_artist_basis

    if not shapes.is_dir():
        return load_artist_basis(mesh, shapes)
    names = sorted(p.stem for p in shapes.glob("*.obj"))
    matched = match_shape_names(performance.names, names)
    if not matched:
        raise InputError(f"{performance.path}: none of its weight columns "
                         f"({', '.join(performance.names)}) names a shape of {shapes} "
                         f"({', '.join(names) or 'no OBJ files'})")
    idle = [n for n in names if n not in matched]
    if idle:
        warnings.warn(f"{performance.path}: {len(idle)} shapes of {shapes} have no weight "
                      f"column (held at 0): {', '.join(idle)}", stacklevel=2)
    return load_artist_basis(mesh, shapes, names=[n for n in names if n in matched])


def run(args) -> int:
    inputs = [args.mesh, args.shapes, args.performance, args.layout, args.markerset]
    if args.output.suffix.lower() not in (".c3d", ".csv"):
        raise InputError(f"{args.output}: the capture must be .c3d or .csv")
    units = args.units or _layout_units(args.layout)
    performance = read_performance(args.performance)
    if args.tracking_gaps != "keep":
        performance = fill_tracking_gaps(performance, args.tracking_gaps)
    markerset = load_markerset(args.markerset)
    mesh = load_mesh(args.mesh, units=units)
    layout = load_marker_layout(args.layout, mesh)
    markerset.check_labels(layout.labels, source=f"layout {args.layout}")
    basis = _load_basis(mesh, args.shapes, performance)
    deg, mm = args.head_motion
    result = simulate_capture(basis, performance, layout, markerset.head, rate=args.rate,
                              start=args.start, duration=args.duration, noise_mm=args.noise,
                              n_gaps=args.gaps, head_rotation_deg=deg, head_translation_mm=mm,
                              neutral_lead_s=args.neutral_lead, seed=args.seed)
    mocap.write(result.take, args.output, inputs=inputs)
    if args.truth is not None:
        result.truth.save(args.truth, inputs=inputs + [args.output])
    return 0
