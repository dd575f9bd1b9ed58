"""``mocap2mesh demo [-o DIR]``: generate the demo session and run the whole chain on it.

Writes ``DIR/session/`` (the generated capture session), ``DIR/run.toml`` (a
run configuration naming it) and ``DIR/results/`` (what ``mocap2mesh run
DIR/run.toml`` writes: exports, QA report, ``manifest.json``), then prints
where the report is.
"""

from __future__ import annotations

from pathlib import Path

from mocap.util.atomic import atomic_path

from fit.demo import make_demo_session
from fit.pipeline.config import load_run_config
from fit.cli.commands.run import run_takes

__all__ = ["add_parser", "run", "run_demo", "demo_config_toml"]


def add_parser(sub) -> None:
    p = sub.add_parser("demo", help="generate the demo session and run the chain on it",
                       description="Generate the project's own demo session (a procedural "
                                   "face, an 18-shape muscle basis, a simulated capture; "
                                   "seeded), write a run configuration for it and run the "
                                   "whole chain: exports, QA pictures, video, HTML report.")
    p.add_argument("-o", "--output", type=Path, default=Path("demo-output"),
                   help="output directory (default: demo-output)")
    p.add_argument("--seed", type=int, default=7, help="seed of the generated session")
    p.add_argument("--seconds", type=float, default=20.0, help="length of the take, s")
    p.set_defaults(run=run)


def demo_config_toml(session_dir: str = "session", results_dir: str = "results") -> str:
    """The run configuration of the demo session (paths relative to the TOML file)."""
    return f"""# mocap2mesh run configuration for the generated demo session
[inputs]
captures = ["{session_dir}/capture.c3d"]
markerset = "{session_dir}/markerset.toml"
mesh = "{session_dir}/neutral.obj"
mesh_units = "mm"
landmarks = "{session_dir}/landmarks.toml"
basis = "{session_dir}/shapes"

[output]
directory = "{results_dir}"

[ingest]
fill = "auto"
lowpass_hz = 15.0

[bind]
frame = "auto"
skin_offset = 2.0

[basis]
pca_coverage = 0.995

[fit]
space = "marker"

[report]
video = true
video_step = 2
"""


def run_demo(out, *, seed: int = 7, seconds: float = 20.0, progress: bool | None = None):
    """Generate the session in ``out/session``, write ``out/run.toml``, run it.

    Returns
    -------
    RunOutcome
        Of :func:`fit.cli.commands.run.run_takes` (``manifest`` under ``out/results``).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    make_demo_session(out / "session", seed=seed, seconds=seconds)
    config_path = out / "run.toml"
    with atomic_path(config_path) as tmp:
        Path(tmp).write_text(demo_config_toml(), encoding="utf-8")
    return run_takes(load_run_config(config_path), progress=progress, force=True)


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
