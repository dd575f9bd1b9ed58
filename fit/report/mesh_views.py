"""Shaded renders of reconstructed meshes at chosen frames, the captured markers over them.

What a TD checks before trusting marker-space figures: the mesh itself. Each
frame is drawn from the front and from the side (:func:`mocap.viz.render.render_mesh`),
optionally coloured by a per-vertex distance (to the retargeted mesh W·D, on
one scale for every basis), with the captured markers as red dots.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from mocap.errors import InputError
from mocap.mesh.mesh import vertex_normals
from mocap.viz.render import (
    Camera,
    colorbar,
    compiled_renders,
    image_grid,
    render_mesh,
    save_png,
)

__all__ = ["MESH_VIEWS", "MeshSpace", "mesh_cameras", "plot_mesh_frames"]

#: The views of every frame, left to right.
MESH_VIEWS = ("front", "side")
#: Pixels of one rendered view (width, height): six of them fill the report's width.
_CELL = (216, 248)
#: Frames per row of the figure (each frame takes one cell per view).
_FRAMES_PER_ROW = 3
_MARKER_RGB = (0.85, 0.1, 0.1)


@dataclass(frozen=True, eq=False)
class MeshSpace:
    """What the mesh-space QA of a take needs: the mesh, each basis and its weights,
    the retargeting operator and the marker displacements.

    Attributes
    ----------
    faces : ndarray, shape (K, 3)
    neutral : ndarray, shape (N, 3), mesh units
    mm_per_unit : float
    bases : dict of str to (ndarray (n, N, 3), ndarray (T, n))
        Each basis's displacements (mesh units) and its weights per frame.
    operator : ndarray, shape (N, M)
        W, marker displacements to vertex displacements.
    displacements : ndarray, shape (T, M, 3), mesh units
        D, the marker displacements the bases were fitted to.
    to_mesh : callable
        Capture millimetres (head frame, (P, 3)) to mesh coordinates.
    """

    faces: np.ndarray
    neutral: np.ndarray
    mm_per_unit: float
    bases: dict
    operator: np.ndarray
    displacements: np.ndarray
    to_mesh: Callable

    def basis_mesh(self, name: str, frames) -> np.ndarray:
        """Vertices (F, N, 3) of basis `name` at frame indices `frames`."""
        shapes, weights = self.bases[name]
        return self.neutral + np.tensordot(np.asarray(weights)[frames], shapes, axes=1)

    def retargeted_mesh(self, frames) -> np.ndarray:
        """Vertices (F, N, 3) of W·D at frame indices `frames`."""
        d = np.asarray(self.displacements)[frames]                  # (F, M, 3)
        # a BLAS product per frame (einsum would sum in a loop of its own)
        return self.neutral + np.asarray(self.operator) @ d


def mesh_cameras(vertices, *, size=_CELL, margin: float = 0.1) -> dict:
    """One camera per view of :data:`MESH_VIEWS` framing `vertices` (e.g. the neutral, or
    a list of meshes), shared by every figure so that bases compare at one scale."""
    return {view: Camera.fit(vertices, view=view, size=size, margin=margin)
            for view in MESH_VIEWS}


def plot_mesh_frames(vertices, faces, path, *, captions, cameras: dict, markers=None,
                     colors=None, vmax: float | None = None, color_label: str = "",
                     title: str = "", cmap: str = "YlGnBu") -> None:
    """Front and side renders of a mesh at several frames, in one PNG.

    Parameters
    ----------
    vertices : array_like, shape (F, N, 3), mesh units
        The mesh at each frame to show. No NaN.
    faces : array_like, shape (K, 3), int
    path : str or os.PathLike
        Output PNG.
    captions : sequence of str, length F
        One per frame ("frame 812: mouth open", ...), under its front view.
    cameras : dict of view to Camera
        :func:`mesh_cameras`: one framing for every figure.
    markers : array_like, shape (F, M, 3), mesh units, optional
        Captured markers drawn as red dots (NaN rows skipped; markers behind the
        mesh faded).
    colors : array_like, shape (F, N), optional
        Per-vertex scalars (e.g. distances, mm) mapped through `cmap` on
        ``[0, vmax]`` for every frame; a colour bar is added. Default: clay.
    vmax : float, optional
        Top of the colour scale (default the largest finite value).
    color_label : str
        Caption of the colour bar (units).
    title : str
        A line above the renders.

    Raises
    ------
    InputError
        Shapes that disagree, no frame.
    """
    vertices = np.asarray(vertices, dtype=float)
    if vertices.ndim != 3 or vertices.shape[-1] != 3 or len(vertices) == 0:
        raise InputError(f"vertices must have shape (F, N, 3) with F >= 1, got {vertices.shape}")
    captions = [str(c) for c in captions]
    if len(captions) != len(vertices):
        raise InputError(f"captions has {len(captions)} entries for {len(vertices)} frames")
    if colors is not None:
        colors = np.asarray(colors, dtype=float)
        if colors.shape != vertices.shape[:2]:
            raise InputError(f"colors must have shape {vertices.shape[:2]}, got {colors.shape}")
        if vmax is None:
            finite = colors[np.isfinite(colors)]
            vmax = float(finite.max()) if finite.size else 1.0
        vmax = max(float(vmax), 1e-9)
    images, labels = [], []
    compiled_renders(len(vertices) * len(MESH_VIEWS), len(faces))    # when they pay for it
    for k, frame in enumerate(vertices):
        points = None if markers is None else np.asarray(markers[k], dtype=float)
        normals = vertex_normals(frame, faces)                  # once for its views
        for view in MESH_VIEWS:
            images.append(render_mesh(
                frame, faces, camera=cameras[view],
                colors=None if colors is None else colors[k], cmap=cmap, vmin=0.0, vmax=vmax,
                points=points, point_colors=_MARKER_RGB, point_radius=2.5,
                hidden_points="dim", normals=normals))
            labels.append(captions[k] if view == MESH_VIEWS[0] else view)
    grid = image_grid(images, labels, ncols=len(MESH_VIEWS) * _FRAMES_PER_ROW, pad=6,
                      font_scale=0.42)
    if colors is not None:
        bar = colorbar(vmin=0.0, vmax=vmax, cmap=cmap, height=min(grid.shape[0], 260), width=96,
                       label=color_label)
        pad = np.full((grid.shape[0], bar.shape[1], 3), 255, np.uint8)
        pad[:bar.shape[0]] = bar
        grid = np.concatenate([grid, pad], axis=1)
    if title:
        head = np.full((26, grid.shape[1], 3), 255, np.uint8)
        cv2.putText(head, title, (8, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1,
                    cv2.LINE_AA)
        grid = np.concatenate([head, grid])
    save_png(grid, path)
