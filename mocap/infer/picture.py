"""Pictures of an inference: the markers by region, and the mesh landmarks found.

:func:`plot_inference` draws the rest pose of the kept markers (front and
side, in the face axes found), coloured by region, the head or stabilization
markers marked, every marker and every landmark named: what the user checks
before running. :func:`plot_mesh_landmarks` renders the mesh with its
landmarks named.
"""

from __future__ import annotations

import numpy as np

from mocap.infer.capture import Inference
from mocap.mesh.mesh import Mesh
from mocap.viz.figures import distinct_colours, new_figure, save_figure
from mocap.viz.render import Camera, render_mesh

__all__ = ["plot_inference", "plot_mesh_landmarks"]


def _face_view(axes) -> np.ndarray:
    """World-to-camera rotation facing a face: the subject's left on the image's right."""
    return np.array([axes.left, axes.up, axes.forward])


def plot_inference(inference: Inference, path, *, title: str = "") -> None:
    """Markers of the rest pose by region, landmarks named (PNG).

    Parameters
    ----------
    inference : Inference
    path : str or os.PathLike
        Output PNG.
    title : str
        First line of the title (e.g. the capture's name).
    """
    inf = inference
    coords = inf.axes.coordinates(inf.pose)                   # left, up, forward (mm)
    region_of = {g.label: g.region for g in inf.regions} | {x: "head" for x in inf.head}
    names = sorted(set(region_of.values()))
    bases = sorted({n.removeprefix("left_").removeprefix("right_") for n in names})
    base_colour = dict(zip(bases, distinct_colours(len(bases))))
    colour = {n: base_colour[n.removeprefix("left_").removeprefix("right_")] for n in names}
    shape = {n: "s" if n == "head" else ">" if n.startswith("left_") else
             "<" if n.startswith("right_") else "o" for n in names}
    stable = set(inf.stable.labels) if inf.stable is not None else set(inf.head)
    point_of = {p.label: p.point for p in inf.landmarks}
    p = inf.prefix
    fig = new_figure(14, 8.6)
    grid = fig.add_gridspec(1, 2, width_ratios=(1.35, 1))
    views = ((fig.add_subplot(grid[0]), 0, "front (the subject's left on the right)",
              "subject's left (mm)"),
             (fig.add_subplot(grid[1]), 2, "side (facing right)", "forward (mm)"))
    for ax, horizontal, label, xlabel in views:
        h = coords[:, horizontal]
        for region in names:
            rows = [i for i, x in enumerate(inf.kept) if region_of[x] == region]
            ax.scatter(h[rows], coords[rows, 1], s=60 if region == "head" else 46,
                       marker=shape[region], color=colour[region],
                       edgecolor="black", linewidth=0.4, label=region, zorder=3)
        rings = [i for i, x in enumerate(inf.kept) if x in stable]
        ax.scatter(h[rings], coords[rings, 1], s=150, facecolor="none", edgecolor="black",
                   linewidth=1.2, zorder=2,
                   label="head markers" if inf.head else "stabilization markers (auto)")
        for i, x in enumerate(inf.kept):
            if horizontal == 2 and x not in point_of:       # the side view: landmarks only
                continue
            short = x[len(p):] if p and x.startswith(p) else x
            text = short if x not in point_of else f"{short} [{point_of[x]}]"
            if horizontal == 2:
                text = point_of[x]
            ax.annotate(text, (h[i], coords[i, 1]), xytext=(4, 3), textcoords="offset points",
                        fontsize=6.5, color="black" if x not in point_of else "darkred")
        ax.set_aspect("equal")
        ax.set_title(label, fontsize=10)
        ax.set_xlabel(xlabel)
        ax.set_ylabel("up (mm)")
        ax.grid(alpha=0.3)
    handles, labels = views[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=min(8, len(labels)),
               fontsize=8, frameon=False)
    head = (f"head markers {len(inf.head)}" if inf.head else
            f"no head markers: {len(inf.stable.labels)} stabilization markers (auto)")
    lines = [title or "mocap2mesh init",
             f"rest pose (each marker's median in the head frame), {len(inf.face)} face "
             f"markers, {head}; {len(inf.landmarks)} landmark pairs; "
             f"{len(inf.flagged)} markers not kept; {len(inf.questions)} open questions"]
    fig.suptitle("\n".join(lines), fontsize=11)
    save_figure(fig, path)


def plot_mesh_landmarks(mesh: Mesh, inference: Inference, path, *, size=(900, 900)) -> None:
    """The mesh seen from the front with its landmarks as dots, each named (PNG)."""
    marks = inference.mesh_landmarks
    names = list(marks.landmarks)
    points = mesh.vertices[[marks.landmarks[n] for n in names]]
    view = _face_view(marks.axes)
    # frame the face: the landmarks' box, grown by 60 % each way
    local = marks.axes.coordinates(points)
    lo, hi = local.min(axis=0), local.max(axis=0)
    grow = 0.6 * (hi - lo)
    near = marks.axes.coordinates(mesh.vertices)
    inside = np.all((near[:, :2] >= (lo - grow)[:2]) & (near[:, :2] <= (hi + grow)[:2]), axis=1)
    camera = Camera.fit(mesh.vertices[inside], view=view, size=size)
    image = render_mesh(mesh.vertices, mesh.faces, camera=camera, points=points,
                        point_radius=5.0, hidden_points="show")
    xy = camera.project(points)
    fig = new_figure(size[0] / 100, size[1] / 100 + 0.5)
    ax = fig.add_subplot()
    ax.imshow(image)
    side = local[:, 0] / max(np.ptp(local[:, 0]), 1e-12)
    midline_turn = 1
    for name, (x, y, _), s in zip(names, xy, side):
        if abs(s) < 0.05:                          # midline: alternate sides, with a leader
            right = midline_turn > 0
            midline_turn = -midline_turn
        else:
            right = s > 0
        rise = 14 if ("inner" in name or name.endswith("bottom")) else \
            -14 if ("outer" in name or name.endswith("top") or "corner" in name) else 0
        ax.annotate(name, (x, y), xytext=(60 if right else -60, rise),
                    textcoords="offset points",
                    ha="left" if right else "right", va="center", fontsize=8,
                    color="darkblue", arrowprops={"arrowstyle": "-", "color": "darkblue",
                                                  "lw": 0.6},
                    bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none",
                          "alpha": 0.8})
    ax.set_axis_off()
    how = "found from the mesh (loops and symmetry plane)" if marks.found else "given"
    ax.set_title(f"mesh landmarks, {how}", fontsize=10)
    save_figure(fig, path)
