"""A 9,409-vertex take of the ICT face through ``mocap2mesh run``, for the export checks.

The ICT face (53 shapes, cm) driven by the real ARKit performance
``alex_rom_4.csv`` is captured by the 66-marker layout of the tests
(``mocap2mesh synth``: head motion, 0.2 mm noise, gaps, a 2 s neutral hold at
the start), then run through the whole chain (``bind.frame = "hold"``) into
``OUT/results/<take>/``: the ``face-B.glb`` and ``mesh-B.npz`` of every basis,
which ``bench/blender_check.py`` opens in Blender (``make blender-check-ict``).

Usage: ``python bench/ict_take.py OUT [--duration S]``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from _common import REPO, shared_data

from fit.cli.main import main as mocap2mesh

TESTS = REPO / "tests"


def run_toml(capture: Path, ict: Path, results: Path) -> str:
    """The run configuration of the take (absolute paths)."""
    return f"""[inputs]
captures = ["{capture}"]
markerset = "{TESTS / 'ict_markerset.toml'}"
mesh = "{ict / 'generic_neutral_mesh.obj'}"
mesh_units = "cm"
landmarks = "{TESTS / 'ict_landmarks.toml'}"
basis = "{ict / 'expressions'}"

[output]
directory = "{results}"

# the simulated gaps last up to ~0.7 s: filled, as the export check needs every frame
[ingest]
max_gap = 60

[bind]
frame = "hold"
skin_offset = 2.0

[report]
video = false
"""


def main(argv) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--duration", type=float, default=12.0, help="seconds of performance")
    args = parser.parse_args(argv)
    data = shared_data()
    ict = data / "ict-face"
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    capture = out / "ict-take.c3d"
    code = mocap2mesh(["synth", "--mesh", str(ict / "generic_neutral_mesh.obj"), "--units", "cm",
                       "--shapes", str(ict / "expressions"), "--performance",
                       str(data / "arkit-performances" / "alex_rom_4.csv"),
                       "--layout", str(TESTS / "ict_marker_layout.toml"),
                       "--markerset", str(TESTS / "ict_markerset.toml"), "-o", str(capture),
                       "--rate", "60", "--duration", str(args.duration), "--gaps", "10",
                       "--neutral-lead", "2", "--seed", "3"])
    if code:
        return code
    config = out / "run.toml"
    config.write_text(run_toml(capture.resolve(), ict, (out / "results").resolve()),
                      encoding="utf-8")
    return mocap2mesh(["run", str(config), "--force"])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
