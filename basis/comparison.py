"""How far the quasi-eigen faces moved the artist's shapes: a table and pictures.

:func:`move_table` lists, for each artist shape e_i^H, the relative move
‖e_i^QE − e_i^H‖ / ‖e_i^H‖ and the largest vertex move (mesh units) of its
quasi-eigen face, then the PCA axes no artist shape covers (the paper's
"missing" axes). :func:`comparison_image` draws one element side by side,
artist shape and quasi-eigen face from the front with one shared framing, and
the per-vertex move on the artist shape as a colour map with its scale; every
mesh is drawn at true scale, nothing is exaggerated. :func:`comparison_sheet`
stacks several elements.

References
----------
Kim & Ko, "Intuitive quasi-eigen faces", GRAPHITE 2007, section 4 (eq. 3-4 and
the missing-axis post-treatment).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from basis.pca import PCAModel
from basis.quasi_eigen import QuasiEigenBasis
from mocap.errors import InputError
from mocap.mesh.mesh import Mesh
from mocap.util.atomic import atomic_path
from mocap.util.validation import as_float_array
from mocap.viz.render import Camera, colorbar, image_grid, render_mesh

__all__ = ["MOVE_COLUMNS", "ROW_KINDS", "move_table", "save_move_table", "comparison_image",
           "comparison_sheet"]

#: Columns of :func:`move_table`, in order.
MOVE_COLUMNS = ("name", "kind", "relative_move", "max_vertex_move", "max_vertex", "axis",
                "column_sum", "variance_share")
#: Kinds of rows of :func:`move_table`: an artist shape, or a PCA axis no shape covers.
ROW_KINDS = ("artist", "missing_axis")

_MOVE_CMAP = "magma_r"


def move_table(qe: QuasiEigenBasis, pca: PCAModel) -> pd.DataFrame:
    """Per-element moves of a quasi-eigen basis, and its missing PCA axes.

    Parameters
    ----------
    qe : QuasiEigenBasis
        From :func:`basis.quasi_eigen.quasi_eigen`.
    pca : PCAModel
        The model `qe` was projected on (its first ``qe.weights.shape[1]`` axes
        are the ones used).

    Returns
    -------
    pandas.DataFrame
        Columns :data:`MOVE_COLUMNS`. One ``"artist"`` row per artist shape, in
        basis order: ``relative_move`` ‖e^QE − e^H‖ / ‖e^H‖ (a fraction),
        ``max_vertex_move`` the largest ‖e^QE[v] − e^H[v]‖ (mesh units) at
        vertex ``max_vertex``. Then one ``"missing_axis"`` row per missing
        axis j (0-based ``axis``; ``name`` as given to the augmented basis),
        with ``column_sum`` Σ_i |w_ij| relative to the largest column sum and
        ``variance_share`` λ_j over the total variance. Fields that do not
        apply to a row are NaN (``max_vertex`` and ``axis`` are -1).

    Raises
    ------
    InputError
        `qe` and `pca` of different sizes.
    """
    if not isinstance(qe, QuasiEigenBasis) or not isinstance(pca, PCAModel):
        raise InputError("move_table needs a QuasiEigenBasis and the PCAModel it came from")
    n, m = qe.weights.shape
    if m > pca.n_components or qe.displacements.shape[1:] != pca.mean.shape:
        raise InputError(f"qe ({m} axes, {qe.displacements.shape[1]} vertices) was not made "
                         f"from this PCA model ({pca.n_components} axes, "
                         f"{len(pca.mean)} vertices)")
    k = len(qe.missing_axes)
    nan_k = np.full(k, np.nan)
    largest = qe.column_sums.max()
    total = pca.total_variance if pca.total_variance > 0 else np.nan
    table = pd.DataFrame({
        "name": list(qe.names[:n]) + [f"pca_axis_{j:02d}" for j in qe.missing_axes],
        "kind": [ROW_KINDS[0]] * n + [ROW_KINDS[1]] * k,
        "relative_move": np.concatenate([qe.relative_move, nan_k]),
        "max_vertex_move": np.concatenate([qe.max_vertex_move, nan_k]),
        "max_vertex": np.concatenate([qe.max_vertex, np.full(k, -1)]).astype(np.int64),
        "axis": np.concatenate([np.full(n, -1), qe.missing_axes]).astype(np.int64),
        "column_sum": np.concatenate([np.full(n, np.nan),
                                      qe.column_sums[qe.missing_axes] / largest]),
        "variance_share": np.concatenate([np.full(n, np.nan),
                                          pca.eigenvalues[qe.missing_axes] / total]),
    })
    return table[list(MOVE_COLUMNS)]


def save_move_table(table: pd.DataFrame, path, *, inputs=()) -> None:
    """Write a :func:`move_table` as CSV (empty cells for NaN), atomically.

    Parameters
    ----------
    table : pandas.DataFrame
        Columns :data:`MOVE_COLUMNS`.
    path : str or os.PathLike
    inputs : iterable of path, optional
        Files never to replace.
    """
    if not isinstance(table, pd.DataFrame) or tuple(table.columns) != MOVE_COLUMNS:
        raise InputError(f"table must be a DataFrame with columns {list(MOVE_COLUMNS)}")
    with atomic_path(path, inputs=inputs) as tmp:
        table.to_csv(Path(tmp), index=False, float_format="%.6g", na_rep="")


def _as_shape(value, name: str, n_vertices: int) -> np.ndarray:
    return as_float_array(value, name, shape=(n_vertices, 3), allow_nan=False)


def comparison_image(neutral: Mesh, artist, quasi_eigen, *, name: str = "",
                     units: str | None = None, size=(360, 420),
                     vmax: float | None = None) -> np.ndarray:
    """One element: artist shape, quasi-eigen face and their difference, from the front.

    Parameters
    ----------
    neutral : Mesh
        The neutral v0 (N vertices, mesh units), Y-up and facing +Z.
    artist, quasi_eigen : array_like of shape (N, 3), mesh units
        Displacements e^H and e^QE of the element. No NaN.
    name : str
        Element name, written in the captions.
    units : str, optional
        Unit written on the colour bar; default ``neutral.units`` (or "mesh units").
    size : (int, int)
        ``(width, height)`` of each panel, pixels.
    vmax : float, optional
        Top of the colour scale of the move, mesh units; default the largest
        vertex move of this element (the bar shows the scale either way).

    Returns
    -------
    ndarray of shape (H, W, 3), uint8
        Three panels and a colour bar: ``v0 + e^H``, ``v0 + e^QE`` (both
        framed by one camera fitted to the two, true scale), and ``v0 + e^H``
        coloured by ‖e^QE[v] − e^H[v]‖ from 0 to `vmax`.

    Raises
    ------
    InputError
        Shapes not (N, 3), NaN, a non-positive `vmax`.
    """
    if not isinstance(neutral, Mesh):
        raise InputError(f"neutral must be a Mesh, got {type(neutral).__name__}")
    n = neutral.n_vertices
    artist = _as_shape(artist, "artist", n)
    quasi_eigen = _as_shape(quasi_eigen, "quasi_eigen", n)
    units = units or neutral.units or "mesh units"
    h_vertices, qe_vertices = neutral.vertices + artist, neutral.vertices + quasi_eigen
    move = np.linalg.norm(quasi_eigen - artist, axis=1)
    top = float(move.max()) if vmax is None else float(vmax)
    if not top > 0:
        if vmax is not None:
            raise InputError(f"vmax must be positive, got {vmax!r}")
        top = 1.0      # QE equals H: an all-zero map on any scale
    camera = Camera.fit([h_vertices, qe_vertices], view="front", size=size)
    heat = render_mesh(h_vertices, neutral.faces, camera=camera, colors=move,
                       cmap=_MOVE_CMAP, vmin=0.0, vmax=top)
    bar = colorbar(vmin=0.0, vmax=top, cmap=_MOVE_CMAP, height=camera.size[1], width=80,
                   label=units)
    panels = [render_mesh(h_vertices, neutral.faces, camera=camera),
              render_mesh(qe_vertices, neutral.faces, camera=camera), np.hstack([heat, bar])]
    prefix = f"{name}: " if name else ""
    labels = [f"{prefix}artist (H)", f"{prefix}quasi-eigen (QE)",
              f"|QE - H| on H, max {move.max():.3g} {units}"]
    return image_grid(panels, labels, ncols=len(panels), font_scale=0.5)


def comparison_sheet(neutral: Mesh, artist, qe: QuasiEigenBasis, names, *,
                     size=(300, 350), shared_scale: bool = False) -> np.ndarray:
    """Several elements, one row each (see :func:`comparison_image`).

    Parameters
    ----------
    neutral : Mesh
    artist : array_like of shape (n, N, 3), mesh units
        The artist shapes `qe` was made from, in the same order.
    qe : QuasiEigenBasis
    names : sequence of str
        Elements to draw, in this order (names of ``qe.names[:n]``).
    size : (int, int)
        Panel size, pixels.
    shared_scale : bool
        One colour scale (the largest move of the drawn elements) for all rows,
        instead of one per row.

    Returns
    -------
    ndarray of shape (H, W, 3), uint8

    Raises
    ------
    InputError
        An unknown name, no name, `artist` inconsistent with `qe`.
    """
    n = qe.weights.shape[0]
    artist = as_float_array(artist, "artist", shape=(n, neutral.n_vertices, 3),
                            allow_nan=False)
    known = tuple(qe.names[:n])
    names = [names] if isinstance(names, str) else list(names)
    if not names:
        raise InputError("names is empty: name at least one element to draw")
    unknown = [x for x in names if x not in known]
    if unknown:
        raise InputError(f"no artist shape {unknown[0]!r} in the quasi-eigen basis; "
                         f"shapes: {', '.join(known)}")
    index = [known.index(x) for x in names]
    vmax = float(qe.max_vertex_move[index].max()) if shared_scale else None
    if vmax is not None and vmax <= 0:
        vmax = None
    rows = [comparison_image(neutral, artist[i], qe.displacements[i], name=x, size=size,
                             vmax=vmax) for x, i in zip(names, index)]
    return image_grid(rows, ncols=1, pad=4)
