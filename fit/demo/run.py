"""The demo end to end: its session generated, a run configuration written, the chain run.

Writes ``DIR/session/`` (the generated capture session), ``DIR/run.toml`` (a
run configuration naming it) and ``DIR/results/`` (what ``mocap2mesh run
DIR/run.toml`` writes: exports, QA report, ``manifest.json``).
"""

from __future__ import annotations

from pathlib import Path

from fit.demo.session import make_demo_session
from fit.pipeline.config import load_run_config
from fit.pipeline.session import run_takes
from mocap.util.atomic import atomic_path

__all__ = ["run_demo", "demo_config_toml", "DEMO_MAX_GAP"]

#: The longest gap the demo's run fills, frames: its simulated occlusions last up
#: to 1 s (120 frames at 120 Hz) each and overlapping ones merge, far beyond the
#: default maximum gap, so the demo asks for them to be filled.
DEMO_MAX_GAP = 240


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
max_gap = {DEMO_MAX_GAP}        # the demo's occlusions last up to 1 s each, overlapping ones longer: fill them all
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
video_step = 4
"""


def run_demo(out, *, seed: int = 7, seconds: float = 20.0, progress: bool | None = None):
    """Generate the session in ``out/session``, write ``out/run.toml``, run it.

    Returns
    -------
    RunOutcome
        Of :func:`fit.pipeline.session.run_takes` (``manifest`` under ``out/results``).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    make_demo_session(out / "session", seed=seed, seconds=seconds)
    config_path = out / "run.toml"
    with atomic_path(config_path) as tmp:
        Path(tmp).write_text(demo_config_toml(), encoding="utf-8")
    return run_takes(load_run_config(config_path), progress=progress, force=True)
