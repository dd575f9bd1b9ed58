"""The marker-space basis: expression shapes sampled at the bound markers.

A fit in marker space solves ``min ‖B w − d_t‖²`` with B the motion of the
bound markers under each shape: of the bound surface points, or, for markers
whose centres sit off the skin, of those centres to first order (they turn
with the skin). :mod:`fit.solve.marker_centres` fits the exact centres.
"""

from __future__ import annotations

import numpy as np

from mocap.bind import Binding
from mocap.errors import InputError, MarkerError
from mocap.mesh import Mesh
from mocap.util.validation import as_choice, as_float_array

__all__ = ["marker_basis", "MARKER_BASIS_UNITS"]

#: Units (and axes) :func:`marker_basis` returns: the mesh's, or capture millimetres.
MARKER_BASIS_UNITS = ("mesh", "mm")
#: Largest vertex move of the central differences of :func:`marker_basis`, over the mesh size.
_NORMAL_STEP = 1e-4


def marker_basis(binding: Binding, displacements, labels=None, *, mesh: Mesh | None = None,
                 units: str = "mesh") -> np.ndarray:
    """A mesh basis sampled at the bound markers: the marker-space basis B of a fit.

    Parameters
    ----------
    binding : Binding
        The markers bound to the mesh.
    displacements : array_like of shape (n, N, 3), mesh units
        Shape displacements from the neutral mesh. No NaN.
    labels : sequence of str, optional
        The M markers to sample, in this order; default every bound marker.
    mesh : Mesh, optional
        The neutral mesh of the binding; with a binding made with
        ``skin_offset`` > 0, the marker centres are sampled instead of the
        surface points (Notes).
    units : {"mesh", "mm"}, default "mesh"
        "mesh": in mesh units and mesh axes (what a fit to the retargeted
        displacements takes); "mm": brought to capture millimetres and the
        binding's capture axes, ``d_mm = Rᵀ d_mesh / scale`` (what a fit to
        head-frame marker motion takes, as the gestures analysis does).

    Returns
    -------
    ndarray of shape (n, M, 3), mesh units or mm

    Raises
    ------
    InputError
        `binding` not a Binding, `displacements` not (n, N, 3) or with NaN,
        an unknown `units`.
    MarkerError
        A label not in the binding.

    Notes
    -----
    Without `mesh` (or with a binding of no skin offset), the motion of the
    bound surface points. With the neutral `mesh` and a binding made with
    ``skin_offset`` > 0, the motion of the marker centres that far off the
    skin along the normal, to first order: markers sit on the skin and their
    centres turn with it. The normal is the one of
    :meth:`mocap.mesh.layout.MarkerLayout.positions` (area-weighted vertex normals,
    interpolated); its change along each shape is a central difference.
    """
    if not isinstance(binding, Binding):
        raise InputError(f"binding must be a Binding, got {type(binding).__name__}")
    displacements = as_float_array(displacements, "displacements", shape=(None, None, 3),
                                   allow_nan=False)
    as_choice(units, "units", MARKER_BASIS_UNITS)
    absent = [x for x in (labels or ()) if x not in binding.labels]
    if absent:
        raise MarkerError(absent[0], "is not in the binding")
    if mesh is None or binding.skin_offset == 0:
        points = binding.marker_points(displacements)
    else:
        layout = binding.centre_layout(mesh)
        size = np.ptp(mesh.vertices, axis=0).max()
        largest = np.abs(displacements).reshape(len(displacements), -1).max(axis=1)
        h = (_NORMAL_STEP * size / np.maximum(largest, np.finfo(float).tiny))[:, None, None]
        points = (layout.positions(mesh.vertices + h * displacements)
                  - layout.positions(mesh.vertices - h * displacements)) / (2 * h)
    if labels is not None:
        points = points[:, [binding.labels.index(label) for label in labels]]
    if units == "mm":
        points = points @ np.asarray(binding.rotation) / binding.scale
    return points
