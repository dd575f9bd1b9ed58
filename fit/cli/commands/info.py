"""``mocap2mesh info FILE [--json]``: what a marker file holds."""

from __future__ import annotations

import json
from pathlib import Path

import mocap
from mocap.gaps import find_gaps
from mocap.io.c3d import C3DSummary, summarize_c3d

HELP = "labels, frames, rate, units and gaps of a marker file"

__all__ = ["add_parser", "run", "describe"]


def add_parser(sub) -> None:
    p = sub.add_parser("info", help=HELP,
                       description="Print labels, frames, rate, units, producer, missing "
                                   "samples per marker and the longest gap of a marker file.")
    p.add_argument("file", help="C3D, Vicon Nexus CSV, TRC or .npz take")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(run=run)


def describe(take) -> dict:
    """A JSON-ready summary of a take or a C3D summary (the ``info --json`` object)."""
    if isinstance(take, C3DSummary):
        missing, longest, analog = take.missing, take.longest_gap, None
        if take.analog_rate is not None:
            analog = {"channels": len(take.analog_labels), "rate": take.analog_rate,
                      "labels": list(take.analog_labels)}
        duration = take.n_frames / take.rate
    else:
        missing = take.missing.sum(axis=0)
        longest = find_gaps(take.missing).longest(take.n_markers)
        analog = None if take.analog is None else {
            "channels": len(take.analog.labels), "rate": take.analog.rate,
            "labels": list(take.analog.labels)}
        duration = take.duration
    src = take.source
    return {
        "file": src.path, "format": src.format, "producer": src.producer,
        "byte_order": src.byte_order, "storage": src.storage,
        "labels": list(take.labels), "frames": take.n_frames, "first_frame": take.first_frame,
        "rate": take.rate, "duration": duration,
        "units": "mm", "units_in_file": src.units,
        "missing": {label: int(n) for label, n in zip(take.labels, missing)},
        "longest_gap": {label: int(n) for label, n in zip(take.labels, longest)},
        "analog": analog,
    }


def _summary(path):
    """A C3D file's summary (its data streamed, never loaded), or the take of another file."""
    if Path(path).suffix.lower() != ".c3d":
        return mocap.read(path)
    return summarize_c3d(path)


def run(args) -> int:
    info = describe(_summary(args.file))
    if args.json:
        print(json.dumps(info, indent=1))
        return 0
    encoding = ", ".join(x for x in (info["byte_order"], info["storage"]) if x)
    print(f"file       {info['file']}")
    print(f"format     {info['format']}" + (f" ({encoding})" if encoding else "")
          + (f", producer {info['producer']}" if info["producer"] else ""))
    print(f"frames     {info['frames']} from frame {info['first_frame']}, "
          f"{info['rate']:g} Hz, {info['duration']:.2f} s")
    print(f"units      mm (file: {info['units_in_file']})")
    analog = info["analog"]
    print("analog     " + ("none" if analog is None else
                            f"{analog['channels']} channels at {analog['rate']:g} Hz"))
    total = sum(info["missing"].values())
    print(f"markers    {len(info['labels'])}, {total} missing samples")
    width = max([len(s) for s in info["labels"]] + [6])
    print(f"  {'marker':<{width}}  {'missing':>7}  {'longest gap':>11}")
    for label in info["labels"]:
        print(f"  {label:<{width}}  {info['missing'][label]:>7}  "
              f"{info['longest_gap'][label]:>11}")
    return 0
