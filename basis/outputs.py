"""Everything ``mocap2mesh basis`` writes: the bases in three formats, and pictures to check them."""

from __future__ import annotations

from pathlib import Path

from basis.artist import ArtistBasis
from basis.basis_io import save_basis, shape_file_stems
from basis.comparison import comparison_image, move_table, save_move_table
from basis.coverage import plot_coverage
from basis.gltf import write_gltf
from basis.pca import PCAModel
from basis.quasi_eigen import QuasiEigenBasis
from mocap.errors import InputError
from mocap.viz.render import save_png

__all__ = ["write_basis_outputs", "COVERAGE_MARKS"]

#: Coverage thresholds marked on the coverage plot.
COVERAGE_MARKS = (0.99, 0.995)


def write_basis_outputs(folder, pca: PCAModel, full: PCAModel, qe: QuasiEigenBasis,
                        artist: ArtistBasis, *, images=(), inputs=()) -> None:
    """Write the bases, the coverage plot, the move table and the comparison images.

    Files in `folder`: ``pca.npz``, ``pca/`` and ``pca.glb`` (the mean, then
    each component scaled to one standard deviation: :meth:`PCAModel.shapes`),
    ``qe.npz``, ``qe/``, ``qe.glb``, ``coverage.png``, ``moves.csv``
    (:func:`basis.comparison.move_table`) and ``comparison/NAME.png``.

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
    names, shapes = pca.shapes()
    bases = {"pca": ArtistBasis(names, neutral, shapes),
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
