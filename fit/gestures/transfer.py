"""Detail features moved to a target face: compact RBFs from the detail markers to the mesh.

Ju & Lee (2008), sec. 5.2: D̃_j is the RBF interpolation of the marker
movements D_j on the synthetic face, with bell-shaped cubic B-spline kernels
and no polynomial term, so that each marker's influence stays local. The
operator is linear, so the details become extra "shapes" of the face: one
displacement field per marker coordinate, whose weight is the marker's
displacement in mm. The head motion moves to the face the same way, through
the binding's similarity (:func:`head_motion_on_mesh`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from mocap.bind import Binding
from mocap.errors import InputError, MarkerError
from mocap.mesh.mesh import Mesh
from mocap.retarget.rbf import build_rbf_operator
from mocap.util.validation import as_float_array, as_positive_float

__all__ = ["DetailTransfer", "build_detail_transfer", "head_motion_on_mesh"]

#: Default support radius of the kernels, in median nearest-marker distances.
SUPPORT_SPACINGS = 3.0


@dataclass(frozen=True, eq=False)
class DetailTransfer:
    """Linear map from detail-marker displacements (mm) to mesh displacements.

    Attributes
    ----------
    groups : mapping of str to tuple of str
        Detail group to marker labels (order of the columns).
    labels : tuple of str
        All detail markers, group after group.
    matrix : ndarray or scipy.sparse array of shape (n_vertices, n_markers)
        The RBF operator (per coordinate, mesh units per mesh unit).
    axes : ndarray of shape (3, 3)
        Column a: mesh displacement of 1 mm along capture axis a (binding scale · rotation).
    support : float
        Kernel support radius, mesh units.
    """

    groups: Mapping[str, tuple]
    labels: tuple
    matrix: object
    axes: np.ndarray
    support: float

    def shapes(self) -> tuple[np.ndarray, tuple]:
        """The details as shapes: fields (3 · n_markers, n_vertices, 3) and their names.

        Field ``3 m + a`` is the mesh displacement of marker m moving 1 mm along
        capture axis a; its weight in frame t is ``D(t)[m, a]``; names are
        ``"<group>:<label>:<x|y|z>"``.
        """
        dense = self.matrix.toarray() if sp.issparse(self.matrix) else np.asarray(self.matrix)
        fields = np.einsum("vm,ca->mavc", dense, self.axes)
        group_of = {label: g for g, members in self.groups.items() for label in members}
        names = tuple(f"{group_of[label]}:{label}:{axis}" for label in self.labels
                      for axis in "xyz")
        return fields.reshape(-1, dense.shape[0], 3), names

    def weights(self, details: Mapping[str, np.ndarray]) -> np.ndarray:
        """Shape weights (n_frames, 3 · n_markers) of the details {group: (T, M_j, 3) mm}."""
        missing = [g for g in self.groups if g not in details]
        if missing:
            raise InputError(f"details lack the groups {missing}")
        return np.concatenate([np.asarray(details[g], float).reshape(len(details[g]), -1)
                               for g in self.groups], axis=1)


def build_detail_transfer(binding: Binding, mesh: Mesh, groups: Mapping[str, tuple], *,
                          support: float | None = None) -> DetailTransfer:
    """Build the RBF map of the detail markers onto `mesh`.

    Parameters
    ----------
    binding : Binding
        The capture's markers bound to `mesh` (made in the head frame, e.g.
        ``mocap2mesh bind --stabilize``, so that head-frame mm map to the mesh).
    mesh : Mesh
        The target neutral face.
    groups : mapping of str to sequence of str
        Detail group to marker labels (e.g. ``GestureSynthesis.detail_labels``).
    support : float, optional
        Kernel support radius, mesh units; default 3 median nearest-marker distances.

    Returns
    -------
    DetailTransfer

    Raises
    ------
    MarkerError
        A detail marker not in the binding.
    InputError
        No detail markers, coincident markers, a bad support.
    """
    if not isinstance(binding, Binding):
        raise InputError(f"binding must be a Binding, got {type(binding).__name__}")
    groups = {str(g): tuple(str(x) for x in members) for g, members in groups.items()
              if len(members)}
    labels = tuple(x for members in groups.values() for x in members)
    if not labels:
        raise InputError("no detail markers to transfer")
    for label in labels:
        if label not in binding.labels:
            raise MarkerError(label, "is a detail marker but not in the binding")
    points = binding.marker_points(mesh.vertices)[[binding.labels.index(x) for x in labels]]
    if support is None:
        if len(points) < 2:
            raise InputError("give the support radius: one marker has no spacing")
        spacing = cKDTree(points).query(points, k=2)[0][:, 1]
        support = SUPPORT_SPACINGS * float(np.median(spacing))
    support = as_positive_float(support, "support")
    op = build_rbf_operator(points, mesh.vertices, kernel="bspline_bell", epsilon=1.0 / support,
                            labels=labels)
    axes = binding.scale * np.asarray(binding.rotation)
    return DetailTransfer(groups=groups, labels=labels, matrix=op.matrix, axes=axes,
                          support=support)


def head_motion_on_mesh(binding: Binding, rotation, translation) -> tuple:
    """Head motion of the capture's head frame as a rigid motion of the bound mesh.

    Parameters
    ----------
    binding : Binding
        Made in the head frame (``p_mesh = s Q p_mm + b``).
    rotation : array_like of shape (n_frames, 3, 3)
        R̃(t): a head-frame point x (mm) moves to ``R̃ x + T̃``
        (:attr:`fit.gestures.GestureSynthesis.head_rotation`). No NaN.
    translation : array_like of shape (n_frames, 3), mm
        T̃(t).

    Returns
    -------
    rotation : ndarray of shape (n_frames, 3, 3)
        ``Q R̃ Qᵀ``.
    translation : ndarray of shape (n_frames, 3), mesh units
        ``b − Q R̃ Qᵀ b + s Q T̃``: a mesh point y moves to ``rotation y + translation``,
        the image of the moved head-frame point.
    """
    if not isinstance(binding, Binding):
        raise InputError(f"binding must be a Binding, got {type(binding).__name__}")
    rotation = as_float_array(rotation, "rotation", shape=(None, 3, 3), allow_nan=False)
    translation = as_float_array(translation, "translation", shape=(len(rotation), 3),
                                 allow_nan=False)
    q, b = np.asarray(binding.rotation, float), np.asarray(binding.translation, float)
    turned = q @ rotation @ q.T
    return turned, b - turned @ b + binding.scale * translation @ q.T
