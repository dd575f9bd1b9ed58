"""``mocap2mesh init CAPTURE --mesh MESH [--shapes DIR] -o DIR``: a first run's files, inferred."""

from __future__ import annotations

from pathlib import Path

from fit.cli.arguments import add_capture, add_mesh, add_units
from fit.pipeline.initialize import initialize

HELP = "infer the marker set, landmarks and run.toml of a capture never seen"

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "init", help=HELP,
        description="Read a capture and a face mesh, infer what a first run needs (subject "
                    "prefix, markers not worth keeping, head or stabilization markers, the "
                    "face's axes, regions, landmark pairs, the mesh's landmarks when it has "
                    "none) and write markerset.toml, landmarks.toml, a run.toml with every "
                    "key, its default and a comment, init.png (markers by region, landmarks "
                    "named) and mesh_landmarks.png into DIR; print what was inferred. What "
                    "cannot be decided is an open question in the files: 'run' refuses them "
                    "until it is answered.")
    add_capture(p)
    add_mesh(p, help="the neutral face mesh to bind to (OBJ, PLY, glTF)")
    add_units(p, help="units of the mesh file when it does not say (default: inferred from "
                      "the face's size)")
    p.add_argument("--shapes", type=Path,
                   help="the mesh's artist basis (OBJ folder, .glb or saved basis)")
    p.add_argument("--landmarks", type=Path,
                   help="the mesh's landmark TOML, if it has one (default: found from the "
                        "mesh: mouth and eye loops, symmetry plane)")
    p.add_argument("-o", "--output", required=True, type=Path, help="directory for the files")
    p.add_argument("--force", action="store_true",
                   help="overwrite the files of an earlier init in DIR")
    p.set_defaults(run=run)


def run(args) -> int:
    done = initialize(args.capture, args.mesh, args.output, shapes=args.shapes,
                      landmarks=args.landmarks, mesh_units=args.units, force=args.force)
    print("\n".join(done.lines))
    return 0
