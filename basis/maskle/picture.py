"""Front-view pictures of painted weights: one panel per channel."""

from __future__ import annotations

import numpy as np

from basis.maskle.transfer import MaskleWeights
from mocap.mesh.mesh import Mesh
from mocap.viz.figures import new_figure, save_figure

__all__ = ["save_weights_picture"]


def save_weights_picture(mesh: Mesh, result: MaskleWeights, path, *, title: str = "",
                         mask_vertices=None) -> None:
    """Write a PNG of the face seen from the front, each channel's weights in colour.

    Parameters
    ----------
    mesh : Mesh
    result : MaskleWeights
        Its ``fit`` (when present) gives the front view; else the xy plane is used.
    path : str or os.PathLike
    title : str
    mask_vertices : array_like of shape (V, 3), optional
        Fitted mask vertices drawn as dots on the first panel.

    Notes
    -----
    Vertices without weights are drawn light grey.
    """
    rot = result.fit.rotation if result.fit is not None else np.eye(3)
    xy = (mesh.vertices @ rot)[:, :2]
    k = len(result.channel_names)
    cols = min(k, 7)
    rows = -(-k // cols)
    fig = new_figure(2.1 * cols, 2.5 * rows)
    axes = fig.subplots(rows, cols, squeeze=False)
    grey = np.where(result.hit, np.nan, 1.0)
    for i, ax in enumerate(axes.ravel()):
        ax.set_axis_off()
        if i >= k:
            continue
        ax.set_aspect("equal")
        ax.tripcolor(xy[:, 0], xy[:, 1], mesh.faces, grey, cmap="Greys", vmin=0, vmax=4,
                     shading="gouraud")
        ax.tripcolor(xy[:, 0], xy[:, 1], mesh.faces, result.weights[:, i], cmap="magma",
                     vmin=0, vmax=1, shading="gouraud")
        if i == 0 and mask_vertices is not None:
            m = np.asarray(mask_vertices) @ rot
            ax.plot(m[:, 0], m[:, 1], ".", ms=1.5, color="tab:cyan")
        ax.set_title(result.channel_names[i], fontsize=8)
    if title:
        fig.suptitle(title, fontsize=9)
    save_figure(fig, path)
