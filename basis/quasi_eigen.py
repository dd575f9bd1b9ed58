"""Quasi-eigen faces: artist blendshapes projected onto the PCA hyperplane.

References
----------
Kim & Ko, "Intuitive quasi-eigen faces", GRAPHITE 2007, section 4, eq. 3-4
and the post-treatment of missing PCA axes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from basis.pca import PCAModel
from mocap.errors import InputError
from mocap.util.validation import as_choice, as_float_array

__all__ = ["QuasiEigenBasis", "MISSING_POLICIES", "quasi_eigen"]

#: What :func:`quasi_eigen` does with a PCA axis that no artist shape covers.
MISSING_POLICIES = ("report", "augment")


@dataclass(frozen=True, eq=False)
class QuasiEigenBasis:
    """A quasi-eigen basis and how far it moved the artist's shapes.

    Attributes
    ----------
    displacements : ndarray, shape (n', N, 3), mesh units
        e_i^QE for the n artist shapes, then (``missing="augment"``) the
        unit-norm eigenfaces e_j^PCA of the missing axes, n' = n + added.
    names : tuple of str, length n'
        Artist names, then ``"pca_axis_07"`` for added axis j = 7 (0-based).
    weights : ndarray, shape (n, m)
        W^{PCA→QE}: w_ij = e_j^PCA · (e_i^H - μ) (eq. 3).
    column_sums : ndarray, shape (m,)
        Σ_i |w_ij| per PCA axis.
    missing_axes : ndarray of int, shape (k,)
        Axes j with Σ_i |w_ij| < missing_eps · max_j Σ_i |w_ij| (0-based).
    augmented : bool
        True when the missing axes were appended to `displacements`.
    relative_move : ndarray, shape (n,)
        ‖e_i^QE - e_i^H‖ / ‖e_i^H‖ over all vertices.
    max_vertex_move : ndarray, shape (n,), mesh units
        Largest vertex move ‖e_i^QE[v] - e_i^H[v]‖ of each artist shape.
    max_vertex : ndarray of int, shape (n,)
        The vertex v where that largest move happens.
    """

    displacements: np.ndarray
    names: tuple
    weights: np.ndarray
    column_sums: np.ndarray
    missing_axes: np.ndarray
    augmented: bool
    relative_move: np.ndarray
    max_vertex_move: np.ndarray
    max_vertex: np.ndarray

    def __post_init__(self):
        for name in ("displacements", "weights", "column_sums", "missing_axes",
                     "relative_move", "max_vertex_move", "max_vertex"):
            getattr(self, name).flags.writeable = False


def quasi_eigen(pca: PCAModel, artist, *, n_components: int | None = None,
                missing_eps: float = 0.05, missing: str = "report",
                names=None) -> QuasiEigenBasis:
    """Quasi-eigen faces of an artist basis (Kim & Ko 2007, eq. 3-4).

    Parameters
    ----------
    pca : PCAModel
        PCA of the capture's mesh displacements (μ and e_j^PCA).
    artist : array_like, shape (n, N, 3), mesh units
        Artist shapes e_i^H as displacements from the neutral mesh (the
        expression mesh minus the neutral). NaN is rejected; a shape of zero
        norm is rejected (its relative move is undefined).
    n_components : int, optional
        Use the first m PCA axes; default all of ``pca``'s (truncate it first,
        e.g. with ``pca.n_for_coverage(0.995)``).
    missing_eps : float in [0, 1)
        Axis j is missing when Σ_i |w_ij| < missing_eps · max_j Σ_i |w_ij|.
    missing : {"report", "augment"}
        Only report the missing axes, or also append e_j^PCA to the basis; see
        :data:`MISSING_POLICIES`.
    names : sequence of str, optional
        Names of the artist shapes; default ``"e_00"``, ``"e_01"``, ...

    Returns
    -------
    QuasiEigenBasis

    Notes
    -----
    Exactly as the paper writes it:

        w_ij = e_j^PCA · (e_i^H - μ),        e_i^QE = μ + Σ_j w_ij e_j^PCA,

    i.e. e_i^QE is the orthogonal projection of e_i^H onto the affine
    hyperplane μ + span(E^PCA), the closest point of that hyperplane. So
    a shape already on the hyperplane is unchanged, and a shape whose
    offset from μ is orthogonal to every axis maps to μ itself. As every
    element carries μ, a blend Σ_i w_i e_i^QE contains (Σ_i w_i) μ: the mean
    is counted once only when the weights sum to one, and the span of the
    basis is span(μ, E^PCA) restricted to what the shapes reach. The added
    eigenfaces of ``"augment"`` are unit vectors without μ (as in the paper):
    their weights are PCA coefficients, leave them unbounded in a fit.

    Examples
    --------
    >>> from basis.pca import pca_streaming
    >>> rng = np.random.default_rng(0)
    >>> model = pca_streaming(rng.normal(size=(30, 10, 3)), n_components=4)
    >>> qe = quasi_eigen(model, rng.normal(size=(3, 10, 3)), missing="augment")
    >>> qe.weights.shape, len(qe.names) == len(qe.displacements)
    ((3, 4), True)
    """
    if not isinstance(pca, PCAModel):
        raise InputError(f"pca must be a PCAModel, got {type(pca).__name__}")
    if n_components is not None:
        pca = pca.truncate(n_components)
    n_vertices = len(pca.mean)
    artist = as_float_array(artist, "artist", shape=(None, n_vertices, 3), allow_nan=False,
                            copy=False)                     # only read
    missing = as_choice(missing, "missing", MISSING_POLICIES)
    if isinstance(missing_eps, bool) or not isinstance(missing_eps, (int, float)) \
            or not 0 <= missing_eps < 1:
        raise InputError(f"missing_eps must be a number in [0, 1), got {missing_eps!r}")
    if len(artist) == 0:
        raise InputError("artist has no shape: quasi-eigen faces need at least one")
    names = _names(names, len(artist))
    flat = artist.reshape(len(artist), -1)
    norms = np.sqrt(np.einsum("si,si->s", flat, flat))      # no (n, 3N) temporary of squares
    if not norms.all():
        raise InputError(f"artist shape {names[int(np.argmin(norms))]!r} is all zeros: "
                         "its relative move is undefined")

    comps = pca.components.reshape(pca.n_components, -1)
    weights = (artist - pca.mean).reshape(len(artist), -1) @ comps.T        # eq. 3
    qe = pca.mean + (weights @ comps).reshape(artist.shape)                  # eq. 4
    column_sums = np.abs(weights).sum(axis=0)
    missing_axes = np.nonzero(column_sums < missing_eps * column_sums.max())[0]

    moved = qe - artist
    moves = np.sqrt(np.einsum("svc,svc->sv", moved, moved))
    displacements, all_names = qe, names
    if missing == "augment" and len(missing_axes):
        added = tuple(f"pca_axis_{j:02d}" for j in missing_axes)
        if set(added) & set(names):
            raise InputError(f"names already contain one of {added}")
        displacements = np.concatenate([qe, pca.components[missing_axes]])
        all_names = names + added
    return QuasiEigenBasis(
        displacements=displacements, names=all_names, weights=weights,
        column_sums=column_sums, missing_axes=missing_axes,
        augmented=missing == "augment" and len(missing_axes) > 0,
        relative_move=np.linalg.norm(moves, axis=1) / norms,
        max_vertex_move=moves.max(axis=1), max_vertex=moves.argmax(axis=1))


def _names(names, n: int) -> tuple:
    if names is None:
        return tuple(f"e_{i:02d}" for i in range(n))
    names = tuple(names)
    if len(names) != n or not all(isinstance(x, str) and x for x in names):
        raise InputError(f"names must be {n} non-empty strings, one per artist shape, "
                         f"got {len(names)}")
    if len(set(names)) != n:
        raise InputError("names must be unique")
    return names
