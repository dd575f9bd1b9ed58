"""``mocap2mesh retarget CAPTURE -o OUT.npz|DIR``: drive a face mesh with a capture."""

from __future__ import annotations

from pathlib import Path

import mocap
from fit.cli.arguments import (
    add_binding,
    add_capture,
    add_fill,
    add_markerset,
    add_mesh,
    add_neutral_frame,
)
from mocap.bind import load_binding
from mocap.clean.ingest import IngestOptions, ingest
from mocap.markerset import load_markerset
from mocap.mesh import load_mesh
from mocap.retarget.archive import CONTENTS, save_npz, save_obj_sequence
from mocap.retarget.retargeting import DISTANCES, KERNELS, RetargetOptions, retarget

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "retarget", help="retarget a capture onto a face mesh with an RBF operator",
        description="Fill the capture's gaps, stabilize it in the head frame, take the "
                    "face-marker displacements from the neutral frame into the mesh's units "
                    "with the binding, and interpolate them over the mesh with radial basis "
                    "functions. Writes OUT.npz (float32 vertex positions or displacements, "
                    "neutral, faces; streamed chunk by chunk) or, for any other OUT, a "
                    "directory with one OBJ per frame.")
    add_capture(p)
    add_markerset(p, help="marker-set TOML (head markers, regions)")
    add_mesh(p)
    add_binding(p)
    p.add_argument("-o", "--output", required=True, type=Path,
                   help="OUT.npz, or a directory for an OBJ sequence")
    p.add_argument("--kernel", choices=KERNELS, default="thin_plate_spline",
                   help="radial kernel (default thin_plate_spline)")
    p.add_argument("--epsilon", type=float, metavar="PER_UNIT",
                   help="shape parameter, 1/mesh units (compact kernels: 1/support radius); "
                        "required for gaussian, multiquadric, wendland_c2, ...")
    p.add_argument("--degree", type=int, help="polynomial degree (-1: none; default: the "
                                              "kernel's minimum)")
    p.add_argument("--smoothing", type=float, default=0.0,
                   help="kernel-diagonal smoothing for noisy markers (default 0)")
    p.add_argument("--distance", choices=DISTANCES, default="euclidean",
                   help="distance the kernel is evaluated on (geodesic: heat method on "
                        "the mesh)")
    p.add_argument("--regions", action="store_true",
                   help="each marker-set region drives only its own vertices")
    p.add_argument("--region-width", type=float, metavar="UNITS",
                   help="blend width of the region weights, mesh units (default: the "
                        "median marker spacing)")
    add_neutral_frame(p, "--neutral-frame")
    add_fill(p, help="gap filling before retargeting (default auto; 'none' fails on gaps)")
    p.add_argument("--lowpass", type=float, metavar="HZ", help="Butterworth cut-off")
    p.add_argument("--content", choices=CONTENTS, default="vertices",
                   help=".npz output: vertex positions (default) or displacements")
    p.set_defaults(run=run)


def run(args) -> int:
    options = RetargetOptions(kernel=args.kernel, epsilon=args.epsilon, degree=args.degree,
                              smoothing=args.smoothing, distance=args.distance,
                              use_regions=args.regions, region_width=args.region_width)
    inputs = (args.capture, args.markerset, args.mesh, args.binding)
    markerset = load_markerset(args.markerset)
    mesh = load_mesh(args.mesh)
    binding = load_binding(args.binding)
    take = mocap.read(args.capture)
    ingested = ingest(take, markerset=markerset, options=IngestOptions(
        fill=args.fill, max_gap=args.max_gap, lowpass_hz=args.lowpass, stabilize=True))
    result = retarget(ingested.take, binding, mesh, markerset, options=options,
                      neutral_frame=ingested.take.frame_index(args.neutral_frame,
                                                              "--neutral-frame"))
    if args.output.suffix.lower() == ".npz":
        save_npz(result, args.output, content=args.content, inputs=inputs)
    else:
        save_obj_sequence(result, args.output, inputs=inputs)
    return 0
