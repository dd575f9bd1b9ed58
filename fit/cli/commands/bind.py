"""``mocap2mesh bind CAPTURE -o BINDING.json``: place a capture's markers on a face mesh."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import mocap
from mocap.util.atomic import refuse_overwrite
from mocap.util.validation import as_int
from mocap.bind import HOLD_S, PICKED_FRAMES, bind_markers, hold_window, resolve_neutral_frame
from mocap.errors import InputError, MarkerError
from mocap.markerset import load_markerset
from mocap.mesh.mesh import load_mesh
from mocap.mesh.landmarks import load_mesh_landmarks
from mocap.rigid import apply_transform
from mocap.stabilize import stabilize

from mocap.retarget.retargeting import neutral_pose

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
                        f"the mean pose of the first still {HOLD_S:g} s of the neutral hold the "
                        "take starts with (averaged in the head frame)")
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
        markers: :func:`mocap.bind.resolve_neutral_frame`. With "hold" the
        bound pose is the mean over the hold's window
        (:func:`mocap.bind.hold_window` frames centred on the picked frame),
        taken in the head frame (the head may move during the hold) and, unless
        `stabilized`, carried to the capture frame by the centre frame's head
        pose: one frame's noise is not bound into every displacement.
    icp, skin_offset, max_distance_warn
        As in :func:`mocap.bind.bind_markers` (skin_offset in mm).
    stabilized : bool
        Bind the markers in the head frame (:func:`mocap.stabilize.stabilize`).

    Returns
    -------
    binding : Binding
    frame : int
        The frame index bound (the window's centre for "hold").

    Raises
    ------
    MarkerError
        A marker of the set absent from the take, or missing in the frame.
    InputError
        A frame index beyond the take.
    """
    markerset.check_labels(take.labels, source=take.source.path or "the take")
    take = take.select(markerset.markers)
    hold = frame == "hold"
    picked = frame in PICKED_FRAMES
    if not picked:
        frame = as_int(frame, "frame", minimum=0)
    if not picked and frame >= take.n_frames:
        raise InputError(f"{take.source.path}: frame index {frame} is beyond the take's "
                         f"{take.n_frames} frames")
    if picked or stabilized:
        head = stabilize(take, markerset.head)
    if picked:
        frame = resolve_neutral_frame(head.take.positions, frame, rate=take.rate)
    if hold:
        positions = _hold_pose(take, head, frame, carry=not stabilized)
    else:
        positions = (head.take if stabilized else take).positions[frame]
    binding = bind_markers(positions, take.labels, markerset.landmarks, mesh, mesh_landmarks,
                           icp=icp, skin_offset=skin_offset, max_distance_warn=max_distance_warn)
    return binding, frame


def _hold_pose(take, head, frame, *, carry):
    """Mean head-frame pose (M, 3), mm, of the hold window centred on `frame`.

    With `carry`, mapped to the capture frame by the head pose of `frame`.
    """
    window = hold_window(take.rate)
    pose = neutral_pose(head.take.positions, frame, window)
    missing = np.flatnonzero(np.isnan(pose).any(axis=1))
    if missing.size:
        raise MarkerError(take.labels[missing[0]],
                          f"is missing in the {window} frames of the neutral hold around frame "
                          f"{take.first_frame + frame} (index {frame}) of "
                          f"{take.source.path or 'the take'}: the bound pose is their mean")
    if not carry:
        return pose
    return apply_transform(head.rotation[frame], head.translation[frame], pose)


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
        held = (f"; the mean of its {hold_window(take.rate)}-frame neutral hold window"
                if args.frame == "hold" else "")
        print(f"frame      {frame} (index; frame number {take.first_frame + frame}{held})")
        print(f"fit        {binding.message}; {binding.n_landmarks} landmarks, "
              f"scale {binding.scale:.6g} mesh units/mm, rms {binding.rms:.3f} mm")
        width = max(len(label) for label in binding.labels)
        print(f"  {'marker':<{width}}  {'distance (mm)':>13}")
        for label, dist in zip(binding.labels, binding.distances):
            print(f"  {label:<{width}}  {dist:>13.3f}")
    return 0
