"""``mocap2mesh basis TAKE... --neutral N.obj --shapes DIR -o OUT``: PCA and quasi-eigen bases."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

import mocap
from basis.artist import ArtistBasis, load_artist_basis
from basis.basis_io import save_basis, shape_file_stems
from basis.comparison import comparison_image, move_table, save_move_table
from basis.gltf import write_gltf
from basis.pca import PCAModel, pca_from_operator, pca_streaming
from basis.quasi_eigen import MISSING_POLICIES, QuasiEigenBasis, quasi_eigen
from mocap.bind import load_binding
from mocap.errors import FileFormatError, InputError
from mocap.markerset import load_markerset
from mocap.viz.render import save_png

from mocap.clean.ingest import IngestOptions, ingest
from fit.report.plots import plot_coverage
from mocap.retarget.retargeting import DISTANCES, KERNELS, RetargetOptions, retarget
from fit.cli.arguments import add_binding, add_fill, add_markerset, add_neutral_frame, add_units

__all__ = ["add_parser", "run", "pca_of_retargeted", "pca_of_captures", "write_outputs",
           "COVERAGE_MARKS"]

#: Coverage thresholds marked on the coverage plot.
COVERAGE_MARKS = (0.99, 0.995)
#: Members of a ``mocap2mesh retarget`` archive (:func:`mocap.retarget.retargeting.save_npz`).
_FRAME_KEYS = ("displacements", "vertices")
_CHUNK_FRAMES = 512


def add_parser(sub) -> None:
    p = sub.add_parser(
        "basis", help="PCA and quasi-eigen bases of retargeted takes and an artist basis",
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
    add_fill(capture, max_gap=False)
    add_neutral_frame(capture, help="neutral frame of every capture: an index, 'auto' "
                                    "(default) or 'hold'")
    capture.add_argument("--kernel", choices=KERNELS, default="thin_plate_spline")
    capture.add_argument("--distance", choices=DISTANCES, default="euclidean")
    capture.add_argument("--regions", action="store_true",
                         help="each marker-set region drives only its own vertices")
    p.add_argument("-v", "--verbose", action="store_true",
                   help="print the coverage, m and the moves, largest first")
    p.set_defaults(run=run)


def _is_retargeted(path: Path) -> bool:
    if path.suffix.lower() != ".npz" or not zipfile.is_zipfile(path):
        return False
    with zipfile.ZipFile(path) as archive:
        members = set(archive.namelist())
    return "marker_displacements.npy" in members and \
        any(f"{key}.npy" in members for key in _FRAME_KEYS)


def _npy_header(member):
    """(shape, fortran_order, dtype) of an open ``.npy`` stream, left at the data."""
    version = np.lib.format.read_magic(member)
    read = np.lib.format.read_array_header_1_0 if version == (1, 0) \
        else np.lib.format.read_array_header_2_0
    return read(member)


class _RetargetedFrames:
    """Vertex displacements (t, N, 3) float64 of retargeted archives, chunk by chunk.

    Re-iterable (each pass reopens the files), as ``pca_streaming`` asks.
    """

    def __init__(self, paths, n_vertices: int, chunk_frames: int):
        self.paths, self.chunk_frames = list(paths), chunk_frames
        self.n_frames, self.n_markers = 0, 0
        for path in self.paths:
            key, shape, _ = self._header(path)
            if shape[1:] != (n_vertices, 3):
                raise FileFormatError(path, f"{key} has shape {shape}: the neutral mesh has "
                                            f"{n_vertices} vertices (retargeted onto another "
                                            "mesh?)")
            with np.load(path) as archive:
                self.n_markers = max(self.n_markers, archive["labels"].shape[0])
            self.n_frames += shape[0]

    @staticmethod
    def _header(path: Path):
        with zipfile.ZipFile(path) as archive:
            key = next(k for k in _FRAME_KEYS if f"{k}.npy" in archive.namelist())
            with archive.open(f"{key}.npy") as member:
                shape, fortran, dtype = _npy_header(member)
        if fortran or len(shape) != 3:
            raise FileFormatError(path, f"{key}.npy must be a C-order (T, N, 3) array")
        return key, shape, dtype

    def __iter__(self):
        for path in self.paths:
            key, shape, dtype = self._header(path)
            with np.load(path) as archive:
                neutral = archive["neutral"].astype(np.float64) if key == "vertices" else 0.0
            frame_bytes = dtype.itemsize * shape[1] * 3
            with zipfile.ZipFile(path) as archive, archive.open(f"{key}.npy") as member:
                _npy_header(member)
                for start in range(0, shape[0], self.chunk_frames):
                    count = min(self.chunk_frames, shape[0] - start)
                    raw = member.read(count * frame_bytes)
                    block = np.frombuffer(raw, dtype=dtype).reshape(count, shape[1], 3)
                    yield block.astype(np.float64) - neutral


def pca_of_retargeted(paths, n_vertices: int, *,
                      chunk_frames: int = _CHUNK_FRAMES) -> PCAModel:
    """PCA of the vertex displacements of ``mocap2mesh retarget`` archives, all frames pooled.

    The mesh sequence of a retargeted take has rank at most 3M (M markers),
    so a randomized PCA with 3M components is exact to rounding; the files
    are read in chunks of `chunk_frames` frames, never whole.

    Parameters
    ----------
    paths : sequence of path
        ``.npz`` archives of :func:`mocap.retarget.retargeting.save_npz` (``vertices`` or
        ``displacements``, (T, N, 3), mesh units).
    n_vertices : int
        N of the neutral mesh; an archive of another mesh is rejected.

    Returns
    -------
    PCAModel
        Method ``"randomized"``, min(3M, ΣT, 3N) components.

    Raises
    ------
    FileFormatError
        An archive of another vertex count (named).
    """
    frames = _RetargetedFrames(paths, n_vertices, chunk_frames)
    n_components = min(3 * frames.n_markers, frames.n_frames, 3 * n_vertices)
    return pca_streaming(frames, n_components=n_components, chunk_frames=chunk_frames)


def pca_of_captures(paths, binding, neutral, markerset, *, fill: str = "auto",
                    neutral_frame="auto", options: RetargetOptions = RetargetOptions()):
    """Exact PCA of the mesh motion of captures, never forming the mesh sequence.

    Each capture is gap-filled and head-stabilized (:func:`mocap.clean.ingest.ingest`),
    retargeted (:func:`mocap.retarget.retargeting.retarget`: its face-marker displacements D
    from its neutral frame, in mesh units, and the operator W), and the
    displacements of all captures are pooled: Ξ = W·D is analysed by
    :func:`basis.pca.pca_from_operator`.

    Returns
    -------
    PCAModel
        Method ``"implicit"``.

    Raises
    ------
    MarkerError
        A marker of the set absent from a capture or the binding, a gap that
        filling left.
    """
    displacements, operator = [], None
    for path in paths:
        take = mocap.read(path)
        result = ingest(take, markerset=markerset,
                        options=IngestOptions(fill=fill, stabilize=True))
        retargeted = retarget(result.take, binding, neutral, markerset, options=options,
                              neutral_frame=neutral_frame)
        displacements.append(retargeted.displacements)
        operator = retargeted.operator.matrix if operator is None else operator
    return pca_from_operator(operator, np.concatenate(displacements))


def _pca_basis(pca: PCAModel, neutral) -> ArtistBasis:
    """The mean, then each component scaled to one standard deviation."""
    sd = np.sqrt(np.maximum(pca.eigenvalues, 0.0))
    displacements = np.concatenate([pca.mean[None], pca.components * sd[:, None, None]])
    names = ("pca_mean",) + tuple(f"pc_{j:02d}" for j in range(pca.n_components))
    return ArtistBasis(names, neutral, displacements)


def _image_names(spec: str, artist: ArtistBasis) -> tuple:
    if spec == "all":
        return artist.names
    if spec == "none":
        return ()
    names = tuple(x.strip() for x in spec.split(",") if x.strip())
    for name in names:
        artist.index(name)
    return names


def write_outputs(folder, pca: PCAModel, full: PCAModel, qe: QuasiEigenBasis,
                  artist: ArtistBasis, *, images=(), inputs=()) -> None:
    """Write the bases, the coverage plot, the move table and the comparison images.

    Parameters
    ----------
    folder : path
        Output directory (created).
    pca : PCAModel
        The m components kept.
    full : PCAModel
        Every component fitted (the coverage plot).
    qe : QuasiEigenBasis
    artist : ArtistBasis
        The shapes `qe` was made from.
    images : sequence of str
        Artist shapes to draw into ``comparison/``.
    inputs : sequence of path
        Files never to replace.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{folder}: exists and is not a directory")
    folder.mkdir(parents=True, exist_ok=True)
    neutral = artist.neutral
    bases = {"pca": _pca_basis(pca, neutral),
             "qe": ArtistBasis(qe.names, neutral, qe.displacements)}
    for stem, basis in bases.items():
        save_basis(basis, folder / f"{stem}.npz", inputs=inputs)
        save_basis(basis, folder / stem, inputs=inputs)
        write_gltf(folder / f"{stem}.glb", neutral, basis.displacements, basis.names,
                   name=stem, inputs=inputs)
    plot_coverage(full, folder / "coverage.png", thresholds=COVERAGE_MARKS,
                  title=f"PCA coverage of {full.n_frames} frames ({full.method}); "
                        f"m = {pca.n_components} kept")
    save_move_table(move_table(qe, pca), folder / "moves.csv", inputs=inputs)
    if images:
        pictures = folder / "comparison"
        pictures.mkdir(exist_ok=True)
        for name, stem in zip(images, shape_file_stems(images)):
            i = artist.index(name)
            save_png(comparison_image(neutral, artist.displacements[i], qe.displacements[i],
                                      name=name), pictures / f"{stem}.png", inputs=inputs)


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
    kinds = [_is_retargeted(path) for path in args.takes]
    inputs = [*args.takes, args.neutral, args.shapes, args.binding, args.markerset]
    inputs = [x for x in inputs if x is not None]
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
                               neutral_frame=args.frame, options=options)
    m = args.components if args.components is not None else full.n_for_coverage(args.coverage)
    pca = full.truncate(m)
    qe = quasi_eigen(pca, artist.displacements, names=artist.names,
                     missing_eps=args.missing_eps, missing=args.missing)
    write_outputs(args.output, pca, full, qe, artist, images=images, inputs=inputs)
    if args.verbose:
        _summary(full, pca, qe)
    return 0
