"""``mocap2mesh demo [-o DIR]``: generate the demo session and run the whole chain on it.

A thin layer over :func:`fit.demo.run_demo`; prints where the report is.
"""

from __future__ import annotations

from pathlib import Path

from fit.demo import run_demo

HELP = "generate the demo session and run the chain on it"

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser("demo", help=HELP,
                       description="Generate the project's own demo session (a procedural "
                                   "face, an 18-shape muscle basis, a simulated capture; "
                                   "seeded), write a run configuration for it and run the "
                                   "whole chain: exports, QA pictures, video, HTML report.")
    p.add_argument("-o", "--output", type=Path, default=Path("demo-output"),
                   help="output directory (default: demo-output)")
    p.add_argument("--seed", type=int, default=7, help="seed of the generated session")
    p.add_argument("--seconds", type=float, default=20.0, help="length of the take, s")
    p.set_defaults(run=run)


def run(args) -> int:
    outcome = run_demo(args.output, seed=args.seed, seconds=args.seconds)
    record = outcome.takes["capture"]
    if record["status"] != "ok":
        print(f"mocap2mesh demo: the take failed: {record['error']}")
        return 1
    results = outcome.manifest.parent
    print(f"report:   {results / 'capture' / 'report' / 'capture.html'}")
    print(f"manifest: {outcome.manifest}")
    return 0
