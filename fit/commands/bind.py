"""``mocap2mesh bind CAPTURE -o BINDING.json``: place a capture's markers on a face mesh."""

from __future__ import annotations

import argparse
from pathlib import Path

import mocap
from mocap._atomic import refuse_overwrite
from mocap._validation import as_int
from mocap.bind import HOLD_S, PICKED_FRAMES, bind_markers, resolve_neutral_frame
from mocap.errors import InputError
from mocap.markerset import load_markerset
from mocap.mesh import load_mesh
from mocap.mesh_landmarks import load_mesh_landmarks
from mocap.stabilize import stabilize

__all__ = ["add_parser", "run", "bind_capture", "parse_frame"]


def parse_frame(text: str):
    """``"auto"``, ``"hold"`` or a frame index >= 0 (argparse type)."""
    if text in PICKED_FRAMES:
        return text
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a frame index, 'auto' or 'hold', got {text!r}") \
            from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"a frame index is >= 0, got {value}")
    return value


def add_parser(sub) -> None:
    p = sub.add_parser(
        "bind", help="bind the markers of a neutral capture frame to a face mesh",
        description="Pick the neutral frame of a capture (or take the one given), fit the "
                    "capture-to-mesh similarity to the landmark markers, refine it by ICP and "
                    "write every marker's face, barycentric coordinates and distance to the "
                    "surface as JSON. Warns about markers far from the surface.")
    p.add_argument("capture", type=Path, help="C3D, Vicon Nexus CSV, TRC or .npz take")
    p.add_argument("--markerset", required=True, type=Path,
                   help="marker-set TOML (head markers, regions, landmarks)")
    p.add_argument("--mesh", required=True, type=Path, help="neutral face mesh")
    p.add_argument("--landmarks", required=True, type=Path,
                   help="mesh-landmark TOML (anatomical point = vertex id)")
    p.add_argument("-o", "--output", required=True, type=Path, help="binding .json")
    p.add_argument("--frame", type=parse_frame, default="auto", metavar="N|auto|hold",
                   help="0-based index of the neutral frame, 'auto' (default): the frame "
                        "closest to the median pose after head stabilization, or 'hold': "
                        f"the centre of the first still {HOLD_S:g} s of the neutral hold the take "
                        "starts with")
    p.add_argument("--no-icp", action="store_true",
                   help="keep the landmark similarity (no ICP refinement)")
    p.add_argument("--skin-offset", type=float, default=0.0, metavar="MM",
                   help="height of the marker centres off the skin (default 0)")
    p.add_argument("--stabilize", action="store_true",
                   help="bind the head-stabilized markers (for takes that are stabilized "
                        "downstream) instead of the capture's own frame")
    p.add_argument("--warn-distance", type=float, default=3.0, metavar="MM",
                   help="warn about markers this far off the expected skin offset (default 3)")
    p.add_argument("-v", "--verbose", action="store_true",
                   help="print the frame, the fit and every marker's distance to the surface")
    p.set_defaults(run=run)


def bind_capture(take: mocap.Take, markerset, mesh, mesh_landmarks, *, frame="auto",
                 icp: bool = True, skin_offset: float = 0.0, stabilized: bool = False,
                 max_distance_warn: float = 3.0):
    """Bind the marker-set markers of one frame of `take` to `mesh`.

    Parameters
    ----------
    take : Take
        Positions (n_frames, n_markers, 3), mm; markers outside the set are ignored.
    markerset : MarkerSet
    mesh : Mesh
    mesh_landmarks : mapping of str to int
    frame : int, "auto" or "hold"
        0-based index of the neutral frame, or picked on the head-stabilized
        markers: :func:`mocap.bind.resolve_neutral_frame`.
    icp, skin_offset, max_distance_warn
        As in :func:`mocap.bind.bind_markers` (skin_offset in mm).
    stabilized : bool
        Bind the markers in the head frame (:func:`mocap.stabilize.stabilize`).

    Returns
    -------
    binding : Binding
    frame : int
        The frame index bound.

    Raises
    ------
    MarkerError
        A marker of the set absent from the take, or missing in the frame.
    InputError
        A frame index beyond the take.
    """
    markerset.check_labels(take.labels, source=take.source.path or "the take")
    take = take.select(markerset.markers)
    picked = frame in PICKED_FRAMES
    if not picked:
        frame = as_int(frame, "frame", minimum=0)
    if not picked and frame >= take.n_frames:
        raise InputError(f"{take.source.path}: frame index {frame} is beyond the take's "
                         f"{take.n_frames} frames")
    if picked or stabilized:
        head_take = stabilize(take, markerset.head).take
    if picked:
        frame = resolve_neutral_frame(head_take.positions, frame, rate=take.rate)
    positions = (head_take if stabilized else take).positions[frame]
    binding = bind_markers(positions, take.labels, markerset.landmarks, mesh, mesh_landmarks,
                           icp=icp, skin_offset=skin_offset, max_distance_warn=max_distance_warn)
    return binding, frame


def run(args) -> int:
    take = mocap.read(args.capture)
    markerset = load_markerset(args.markerset)
    mesh = load_mesh(args.mesh)
    landmarks = load_mesh_landmarks(args.landmarks, mesh)
    binding, frame = bind_capture(take, markerset, mesh, landmarks, frame=args.frame,
                                  icp=not args.no_icp, skin_offset=args.skin_offset,
                                  stabilized=args.stabilize,
                                  max_distance_warn=args.warn_distance)
    refuse_overwrite(args.output, (args.capture, args.markerset, args.mesh, args.landmarks))
    binding.save(args.output)
    if args.verbose:
        print(f"frame      {frame} (index; frame number {take.first_frame + frame})")
        print(f"fit        {binding.message}; {binding.n_landmarks} landmarks, "
              f"scale {binding.scale:.6g} mesh units/mm, rms {binding.rms:.3f} mm")
        width = max(len(label) for label in binding.labels)
        print(f"  {'marker':<{width}}  {'distance (mm)':>13}")
        for label, dist in zip(binding.labels, binding.distances):
            print(f"  {label:<{width}}  {dist:>13.3f}")
    return 0
