"""``mocap2mesh bind CAPTURE -o BINDING.json``: place a capture's markers on a face mesh."""

from __future__ import annotations

from pathlib import Path

import mocap
from fit.cli.arguments import (
    add_capture,
    add_landmarks,
    add_markerset,
    add_mesh,
    add_neutral_frame,
    add_stabilize,
)
from mocap.bind import bind_take
from mocap.markerset import load_markerset
from mocap.mesh import load_mesh
from mocap.mesh.landmarks import load_mesh_landmarks
from mocap.util.atomic import refuse_overwrite

HELP = "bind the markers of a neutral capture frame to a face mesh"

__all__ = ["add_parser", "run", "OLD_STABILIZE"]

#: ``--stabilize`` alone, the old spelling: bind the head-stabilized markers
#: (head markers), i.e. ``--stabilize head --head-frame``.
OLD_STABILIZE = ("head", "head frame")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "bind", help=HELP,
        description="Pick the neutral frame of a capture (or take the one given), fit the "
                    "capture-to-mesh similarity to the landmark markers, refine it by ICP and "
                    "write every marker's face, barycentric coordinates and distance to the "
                    "surface as JSON. Warns about markers far from the surface.")
    add_capture(p)
    add_markerset(p)
    add_mesh(p)
    add_landmarks(p)
    p.add_argument("-o", "--output", required=True, type=Path, help="binding .json")
    add_neutral_frame(p)
    p.add_argument("--no-icp", action="store_true",
                   help="keep the landmark similarity (no ICP refinement)")
    p.add_argument("--skin-offset", type=float, default=0.0, metavar="MM",
                   help="height of the marker centres off the skin (default 0)")
    add_stabilize(p, const=OLD_STABILIZE,
                  help="how the head frame (where the neutral frame is picked) is found: "
                       "'head' (default: the marker set's head markers), 'auto' (the face "
                       "markers that hold their shape best, or the marker set's stabilization "
                       "list) or 'none' (the capture is in the head frame already). "
                       "--stabilize alone, the old spelling, means --stabilize head --head-frame")
    p.add_argument("--head-frame", action="store_true",
                   help="bind the head-stabilized markers (for takes that are stabilized "
                        "downstream) instead of the capture's own frame")
    p.add_argument("--warn-distance", type=float, default=3.0, metavar="MM",
                   help="warn about markers this far off the expected skin offset (default 3)")
    p.add_argument("-v", "--verbose", action="store_true",
                   help="print the frame, the fit and every marker's distance to the surface")
    p.set_defaults(run=run)


def run(args) -> int:
    take = mocap.read(args.capture)
    markerset = load_markerset(args.markerset)
    mesh = load_mesh(args.mesh)
    landmarks = load_mesh_landmarks(args.landmarks, mesh)
    stabilize, head_frame = args.stabilize, args.head_frame
    if stabilize is OLD_STABILIZE:
        stabilize, head_frame = "head", True
    bound = bind_take(take, markerset, mesh, landmarks, frame=take.frame_index(args.frame, "--frame"),
                      stabilize=stabilize,
                      head_frame=head_frame, icp=not args.no_icp,
                      skin_offset=args.skin_offset, max_distance_warn=args.warn_distance,
                      robust=args.robust_stabilization, guard_deg=args.robust_guard)
    refuse_overwrite(args.output, (args.capture, args.markerset, args.mesh, args.landmarks))
    binding, frame = bound.binding, bound.frame
    binding.save(args.output)
    if args.verbose:
        held = (f"; the mean of its {bound.window}-frame neutral hold window"
                if bound.window > 1 else "")
        print(f"frame      {take.first_frame + frame} (the capture's frame number{held})")
        print(f"fit        {binding.message}; {binding.n_landmarks} landmarks, "
              f"scale {binding.scale:.6g} mesh units/mm, rms {binding.rms:.3f} mm")
        width = max(len(label) for label in binding.labels)
        print(f"  {'marker':<{width}}  {'distance (mm)':>13}")
        for label, dist in zip(binding.labels, binding.distances):
            print(f"  {label:<{width}}  {dist:>13.3f}")
    return 0
