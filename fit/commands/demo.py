"""``mocap2mesh demo [-o DIR]``: generate the demo session and run the chain on it."""

from __future__ import annotations

from pathlib import Path

import mocap

from ..demo_session import MARKERSET_TOML, make_demo_session
from ..ingest import IngestOptions
from .ingest import ingest_file

__all__ = ["add_parser", "run", "run_demo"]


def add_parser(sub) -> None:
    p = sub.add_parser("demo", help="generate the demo session and run the chain on it",
                       description="Generate the project's own demo capture (seeded) and run "
                                   "ingestion on it, writing outputs and QA pictures.")
    p.add_argument("-o", "--output", type=Path, default=Path("demo-output"),
                   help="output directory (default: demo-output)")
    p.add_argument("--seed", type=int, default=7, help="seed of the generated session")
    p.set_defaults(run=run)


def run_demo(out: Path, *, seed: int = 7) -> dict:
    """Generate the session in ``out/session`` and process it; returns the output paths."""
    session_dir, ingest_dir = out / "session", out / "ingest"
    session_dir.mkdir(parents=True, exist_ok=True)
    ingest_dir.mkdir(parents=True, exist_ok=True)
    session = make_demo_session(seed=seed)
    capture = session_dir / "capture.c3d"
    markerset = session_dir / "markerset.toml"
    mocap.write(session.take, capture)
    markerset.write_text(MARKERSET_TOML)
    clean = ingest_dir / "capture_stabilized.c3d"
    ingest_file(capture, clean, markerset_path=markerset, qa_dir=ingest_dir,
                options=IngestOptions(fill="auto", lowpass_hz=15.0, stabilize=True))
    return {"capture": capture, "markerset": markerset, "stabilized": clean,
            "qa": ingest_dir}


def run(args) -> int:
    paths = run_demo(args.output, seed=args.seed)
    print(f"demo session: {paths['capture']}")
    print(f"QA pictures:  {paths['qa']}/gaps.png, {paths['qa']}/head_residuals.png")
    return 0
