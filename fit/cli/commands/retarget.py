"""``mocap2mesh retarget CAPTURE -o OUT.npz|DIR``: drive a face mesh with a capture."""

from __future__ import annotations

import argparse
from pathlib import Path

import mocap
from fit.cli.arguments import (
    add_binding,
    add_capture,
    add_fill,
    add_landmarks,
    add_markerset,
    add_mesh,
    add_neutral_frame,
    add_stabilize,
    stabilize_options,
)
from mocap.bind import load_binding
from mocap.clean.ingest import IngestOptions, ingest
from mocap.markerset import load_markerset
from mocap.mesh import load_mesh
from mocap.mesh.landmarks import load_mesh_landmarks
from mocap.mesh.mouth import find_mouth
from mocap.retarget.archive import CONTENTS, save_npz, save_obj_sequence
from mocap.retarget.retargeting import DISTANCES, RETARGET_KERNELS, RetargetOptions, retarget

HELP = "retarget a capture onto a face mesh with an RBF operator"

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "retarget", help=HELP,
        description="Fill the capture's gaps, stabilize it in the head frame (--stabilize), "
                    "take the "
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
    add_landmarks(p, required=False)
    p.add_argument("--kernel", choices=RETARGET_KERNELS, default="auto",
                   help="radial kernel; auto (the default): the kernel, shape parameter, "
                        "distance and regions with the lowest leave-one-marker-out error "
                        "(whose mesh opens the mouth where the lip markers do, with "
                        "--landmarks)")
    p.add_argument("--epsilon", type=float, metavar="PER_UNIT",
                   help="shape parameter, 1/mesh units (compact kernels: 1/support radius); "
                        "required for gaussian, multiquadric, wendland_c2, ...")
    p.add_argument("--degree", type=int, help="polynomial degree (-1: none; default: the "
                                              "kernel's minimum)")
    p.add_argument("--smoothing", type=float, default=0.0,
                   help="kernel-diagonal smoothing for noisy markers (default 0)")
    p.add_argument("--distance", choices=DISTANCES,
                   help="distance the kernel is evaluated on (geodesic: heat method on "
                        "the mesh); default: both tried with auto, else euclidean")
    p.add_argument("--regions", action=argparse.BooleanOptionalAction, default=None,
                   help="each lip region drives only its own vertices; default: both tried "
                        "with auto, else none")
    p.add_argument("--region-width", type=float, metavar="UNITS",
                   help="blend width of the region weights, mesh units (default: the "
                        "median marker spacing)")
    add_neutral_frame(p, "--neutral-frame")
    add_fill(p, help="gap filling before retargeting (default auto; 'none' fails on gaps)")
    p.add_argument("--lowpass", type=float, metavar="HZ", help="Butterworth cut-off")
    add_stabilize(p)
    p.add_argument("--content", choices=CONTENTS, default="vertices",
                   help=".npz output: vertex positions (default) or displacements")
    p.set_defaults(run=run)


def run(args) -> int:
    options = RetargetOptions(kernel=args.kernel, epsilon=args.epsilon, degree=args.degree,
                              smoothing=args.smoothing, distance=args.distance,
                              use_regions=args.regions, region_width=args.region_width)
    inputs = tuple(p for p in (args.capture, args.markerset, args.mesh, args.binding,
                               args.landmarks) if p is not None)
    markerset = load_markerset(args.markerset)
    mesh = load_mesh(args.mesh)
    mouth = None if args.landmarks is None else find_mouth(
        mesh, load_mesh_landmarks(args.landmarks, mesh))
    binding = load_binding(args.binding)
    take = mocap.read(args.capture)
    ingested = ingest(take, markerset=markerset, options=IngestOptions(
        fill=args.fill, max_gap=args.max_gap, lowpass_hz=args.lowpass, stabilize=args.stabilize,
        **stabilize_options(args)))
    result = retarget(ingested.take, binding, mesh, markerset, options=options,
                      neutral_frame=ingested.take.frame_index(args.neutral_frame,
                                                              "--neutral-frame"),
                      mouth=mouth)
    if args.output.suffix.lower() == ".npz":
        save_npz(result, args.output, content=args.content, inputs=inputs)
    else:
        save_obj_sequence(result, args.output, inputs=inputs)
    return 0
