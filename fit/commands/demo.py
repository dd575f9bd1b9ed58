"""``mocap2mesh demo [-o DIR]``: generate the demo session and run the chain on it."""

from __future__ import annotations

from pathlib import Path

from ..demo import make_demo_session
from ..ingest import IngestOptions
from .ingest import ingest_file

__all__ = ["add_parser", "run", "run_demo"]


def add_parser(sub) -> None:
    p = sub.add_parser("demo", help="generate the demo session and run the chain on it",
                       description="Generate the project's own demo session (a procedural "
                                   "face, an 18-shape muscle basis, a simulated capture; "
                                   "seeded) and run the chain on it, writing outputs and "
                                   "QA pictures.")
    p.add_argument("-o", "--output", type=Path, default=Path("demo-output"),
                   help="output directory (default: demo-output)")
    p.add_argument("--seed", type=int, default=7, help="seed of the generated session")
    p.set_defaults(run=run)


def run_demo(out: Path, *, seed: int = 7) -> dict:
    """Generate the session in ``out/session`` and process it; returns the output paths."""
    ingest_dir = out / "ingest"
    ingest_dir.mkdir(parents=True, exist_ok=True)
    session = make_demo_session(out / "session", seed=seed)
    stabilized = ingest_dir / "capture_stabilized.c3d"
    ingest_file(session.paths["capture"], stabilized,
                markerset_path=session.paths["markerset"], qa_dir=ingest_dir,
                options=IngestOptions(fill="auto", lowpass_hz=15.0, stabilize=True))
    return {**session.paths, "stabilized": stabilized, "qa": ingest_dir}


def run(args) -> int:
    paths = run_demo(args.output, seed=args.seed)
    print(f"demo session: {paths['capture']}")
    print(f"QA pictures:  {paths['qa']}/gaps.png, {paths['qa']}/head_residuals.png")
    return 0
