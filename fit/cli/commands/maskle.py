"""``mocap2mesh maskle MESH --landmarks L.toml -o OUT.npz``: Maskle weights of a face mesh."""

from __future__ import annotations

import numpy as np

from basis.maskle import load_default_mask, load_mask, maskle_weights
from basis.maskle.picture import save_weights_picture
from mocap.errors import InputError
from mocap.mesh.landmarks import load_mesh_landmarks
from mocap.mesh.mesh import load_mesh
from mocap.util.atomic import atomic_path

HELP = "paint bone and region weights on a face mesh with the Maskle"

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "maskle", help=HELP,
        description="Place the Maskle on a face from its ten landmarks (mocap.anatomy."
                    "MASKLE_POINTS), shrink it onto the face and transfer its painted "
                    "weights to the face's vertices. Writes an .npz with channel_names, "
                    "channel_kinds, weights (N, K; NaN where no ray hit the mask), hit, "
                    "missed and region_masks (N, 7, rows summing to 1 where defined).")
    p.add_argument("mesh", help="face mesh (.obj, .ply, .gltf, .glb)")
    p.add_argument("--landmarks", required=True, help="mesh-landmark TOML with the ten "
                                                      "Maskle points")
    p.add_argument("--mask", help="mask .npz (default: the project's data/default_mask.npz)")
    p.add_argument("-o", "--output", required=True, help="output .npz")
    p.add_argument("--csv", help="also write the weights as CSV (vertex, one column per "
                                 "channel; empty where undefined)")
    p.add_argument("--picture", help="also write a front-view PNG of the weights")
    p.add_argument("--max-iterations", type=int, default=600,
                   help="shrinking iteration limit (default 600)")
    p.set_defaults(run=run)


def _write_npz(path, result, inputs) -> None:
    with atomic_path(path, inputs=inputs) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, channel_names=np.array(result.channel_names),
                                channel_kinds=np.array(result.channel_kinds),
                                weights=result.weights, hit=result.hit, missed=result.missed,
                                region_masks=result.region_masks(),
                                status=np.array(result.fit.status))


def _write_csv(path, result, inputs) -> None:
    with atomic_path(path, inputs=inputs) as tmp:
        with open(tmp, "w", encoding="ascii") as fh:
            fh.write("vertex," + ",".join(result.channel_names) + "\n")
            rows = np.column_stack([np.arange(len(result.weights)), result.weights])
            for line in rows:
                fh.write(f"{int(line[0])}," + ",".join(
                    "" if np.isnan(x) else f"{x:.6g}" for x in line[1:]) + "\n")


def run(args) -> int:
    if not args.output.endswith(".npz"):
        raise InputError(f"output {args.output!r} must be an .npz file")
    mesh = load_mesh(args.mesh)
    landmarks = load_mesh_landmarks(args.landmarks, mesh)
    mask = load_mask(args.mask) if args.mask else load_default_mask()
    result = maskle_weights(mesh, landmarks, mask, max_iterations=args.max_iterations)
    inputs = [args.mesh, args.landmarks] + ([args.mask] if args.mask else [])
    _write_npz(args.output, result, inputs)
    if args.csv:
        _write_csv(args.csv, result, inputs)
    if args.picture:
        save_weights_picture(mesh, result, args.picture, title=args.mesh,
                             mask_vertices=result.fit.vertices)
    print(f"{result.fit.message}; {int(result.hit.sum())} of {mesh.n_vertices} vertices "
          f"weighted, {len(result.missed)} inside the mask's sphere missed it")
    print(f"wrote {args.output}" + (f", {args.csv}" if args.csv else "")
          + (f", {args.picture}" if args.picture else ""))
    return 0
