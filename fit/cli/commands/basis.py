"""``mocap2mesh basis TAKE... --neutral N.obj --shapes DIR -o OUT``: PCA and quasi-eigen bases."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from basis.artist import ArtistBasis, load_artist_basis
from basis.outputs import COVERAGE_MARKS, write_basis_outputs
from basis.pca import PCAModel
from basis.quasi_eigen import MISSING_POLICIES, QuasiEigenBasis, quasi_eigen
from basis.take_pca import pca_of_captures, pca_of_retargeted
from fit.cli.arguments import add_binding, add_fill, add_markerset, add_neutral_frame, add_units
from mocap.bind import load_binding
from mocap.errors import InputError
from mocap.markerset import load_markerset
from mocap.retarget.archive import is_retargeted_archive
from mocap.retarget.retargeting import DISTANCES, KERNELS, RetargetOptions
from mocap.util.atomic import refuse_overwrite

HELP = "PCA and quasi-eigen bases of retargeted takes and an artist basis"

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "basis", help=HELP,
        description="Fit the PCA of the mesh motion of one or more takes, project the artist's "
                    "shapes onto its hyperplane (quasi-eigen faces, Kim & Ko 2007) and write "
                    "into OUT: pca.npz, pca/ and pca.glb (the mean 'pca_mean', then each "
                    "component scaled to one standard deviation, 'pc_00', ...), qe.npz, qe/ and "
                    "qe.glb, coverage.png, moves.csv (per-element relative move and largest "
                    "vertex move in mesh units, then the missing PCA axes) and "
                    "comparison/NAME.png (artist vs quasi-eigen shape, front view, true scale). "
                    "TAKEs are .npz archives written by 'mocap2mesh retarget' (PCA of their "
                    "vertex displacements), or captures (C3D, CSV, TRC, take .npz) with "
                    "--binding and --markerset: gap-filled, head-stabilized and retargeted "
                    "onto the neutral, then analysed exactly without forming the mesh "
                    "sequence (the path for whole takes).")
    p.add_argument("takes", nargs="+", type=Path, metavar="TAKE",
                   help="retargeted .npz, or a capture with --binding/--markerset")
    p.add_argument("--neutral", required=True, type=Path, help="neutral face mesh")
    p.add_argument("--shapes", required=True, type=Path,
                   help="artist shapes: a directory of OBJ files or a glTF/GLB file")
    add_units(p, help="units of the neutral mesh file (e.g. cm)")
    p.add_argument("-o", "--output", required=True, type=Path, help="output directory")
    size = p.add_mutually_exclusive_group()
    size.add_argument("--coverage", type=float, default=0.995, metavar="FRACTION",
                      help="keep the fewest components covering this fraction of the "
                           "variance (default 0.995)")
    size.add_argument("-m", "--components", type=int, metavar="M",
                      help="keep exactly M components")
    p.add_argument("--missing-eps", type=float, default=0.05, metavar="EPS",
                   help="PCA axis j is missing when sum_i |w_ij| < EPS * max_j sum_i |w_ij| "
                        "(default 0.05)")
    p.add_argument("--missing", choices=MISSING_POLICIES, default="report",
                   help="report the missing axes, or also append them to the QE basis")
    p.add_argument("--images", default="all", metavar="all|none|NAME,...",
                   help="artist shapes to draw in comparison/ (default all)")
    capture = p.add_argument_group("captures (implicit path)")
    add_binding(capture, required=False)
    add_markerset(capture, required=False)
    add_fill(capture)
    add_neutral_frame(capture, help="neutral frame of every capture: a frame number, 'auto' "
                                    "(default) or 'hold'")
    capture.add_argument("--kernel", choices=KERNELS, default="thin_plate_spline")
    capture.add_argument("--distance", choices=DISTANCES, default="euclidean")
    capture.add_argument("--regions", action="store_true",
                         help="each marker-set region drives only its own vertices")
    p.add_argument("-v", "--verbose", action="store_true",
                   help="print the coverage, m and the moves, largest first")
    p.set_defaults(run=run)


def _image_names(spec: str, artist: ArtistBasis) -> tuple:
    if spec == "all":
        return artist.names
    if spec == "none":
        return ()
    names = tuple(x.strip() for x in spec.split(",") if x.strip())
    for name in names:
        artist.index(name)
    return names


def _summary(full: PCAModel, pca: PCAModel, qe: QuasiEigenBasis) -> None:
    cov = full.coverage()
    print(f"PCA: {full.n_frames} frames, {full.n_components} components ({full.message})")
    print("coverage " + " ".join(f"{c:.4f}" for c in cov[:30]))
    for t in COVERAGE_MARKS:
        reached = np.nonzero(cov >= t * (1 - 1e-12))[0]
        print(f"m for {100 * t:g} %: " + (f"{reached[0] + 1}" if reached.size else "not reached"))
    print(f"kept m = {pca.n_components}; missing axes: "
          + (", ".join(str(j) for j in qe.missing_axes) or "none"))
    n = len(qe.relative_move)
    width = max(len(x) for x in qe.names[:n])
    print(f"{'shape':<{width}}  {'rel. move':>9}  {'max vertex move':>15}  vertex")
    for i in np.argsort(-qe.relative_move):
        print(f"{qe.names[i]:<{width}}  {qe.relative_move[i]:>9.4f}  "
              f"{qe.max_vertex_move[i]:>15.4g}  {qe.max_vertex[i]}")


def run(args) -> int:
    artist = load_artist_basis(args.neutral, args.shapes, units=args.units)
    images = _image_names(args.images, artist)
    kinds = [is_retargeted_archive(path) for path in args.takes]
    inputs = [*args.takes, args.neutral, args.shapes, args.binding, args.markerset]
    inputs = [x for x in inputs if x is not None]
    refuse_overwrite(args.output, inputs)
    if all(kinds):
        full = pca_of_retargeted(args.takes, artist.neutral.n_vertices)
    elif any(kinds):
        raise InputError(f"{args.takes[kinds.index(True)]} is a retargeted take but "
                         f"{args.takes[kinds.index(False)]} is not: pass one kind of take")
    elif args.binding is None or args.markerset is None:
        raise InputError(f"{args.takes[0]} is not a retargeted .npz: a capture needs "
                         "--binding and --markerset")
    else:
        options = RetargetOptions(kernel=args.kernel, distance=args.distance,
                                  use_regions=args.regions)
        full = pca_of_captures(args.takes, load_binding(args.binding), artist.neutral,
                               load_markerset(args.markerset), fill=args.fill,
                               max_gap=args.max_gap, neutral_frame=args.frame, options=options)
    m = args.components if args.components is not None else full.n_for_coverage(args.coverage)
    pca = full.truncate(m)
    qe = quasi_eigen(pca, artist.displacements, names=artist.names,
                     missing_eps=args.missing_eps, missing=args.missing)
    write_basis_outputs(args.output, pca, full, qe, artist, images=images, inputs=inputs)
    if args.verbose:
        _summary(full, pca, qe)
    return 0
