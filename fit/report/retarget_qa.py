"""QA of the retargeting: held-out marker errors and the lips, as report sections.

Two checks that need no ground truth. *Cross-validation*: each face marker
predicted by the operator rebuilt without it
(:mod:`mocap.retarget.cross_validation`), per marker and region, with what
``kernel = "auto"`` tried (:mod:`mocap.retarget.selection`). *Lip seal*: the
lip gap of every mesh (the retargeted W·D and each basis's reconstruction)
against the lip markers' opening, frame by frame (:mod:`mocap.retarget.lip_seal`),
with the frames where they disagree.
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import partial

import numpy as np
import scipy.sparse as sp
from matplotlib.patches import Patch

from fit.report.drawing import DPI, label_ticks, line_envelope, report_figure
from fit.report.html import Figure, Section, Table
from fit.report.plots import bar_collection, region_colours, region_groups
from mocap.errors import InputError
from mocap.util.blas import map_on_blas_threads
from mocap.viz.figures import distinct_colours

__all__ = ["mesh_lip_gaps", "plot_lip_seal", "plot_cross_validation", "lip_seal_section",
           "cross_validation_section"]

#: Variants listed in the report's selection table (the best by score, and the choice).
_LISTED = 12
#: Frames whose lips are evaluated together (a few MB of positions).
_CHUNK_FRAMES = 1024


def mesh_lip_gaps(mouth, neutral, *, mm_per_unit: float, bases: Mapping | None = None,
                  operator=None, displacements=None) -> dict:
    """The lip gap of each mesh sequence in every frame, mm.

    Only the lips' vertices are evaluated (:attr:`mocap.mesh.mouth.MouthOpening.vertex_ids`).

    Parameters
    ----------
    mouth : mocap.mesh.mouth.MouthOpening
    neutral : array_like of shape (N, 3)
        The neutral mesh's vertices, mesh units.
    mm_per_unit : float
        Millimetres per mesh unit (the capture's: 1 / binding scale).
    bases : mapping of str to (displacements (n, N, 3), weights (T, n)), optional
        Each basis's shapes (mesh units) and fitted weights: ``v = neutral + w E``.
    operator : array_like or sparse of shape (N, M), optional
        The retargeting operator W, with `displacements` (T, M, 3) (mesh
        units): the sequence ``"W·D"``.

    Returns
    -------
    dict of str to ndarray of shape (T,)
        ``"W·D"`` first (when given), then the bases in order.

    Raises
    ------
    InputError
        Shapes that do not match the mesh.
    """
    ids = mouth.vertex_ids
    neutral = np.asarray(neutral, dtype=np.float64)
    rest = neutral[ids]
    sequences = {}                  # name: (frames, the lips' vertices of a slice of them)
    if operator is not None:
        rows = operator[ids] if not sp.issparse(operator) else sp.csr_array(operator)[ids]
        rows = rows.toarray() if sp.issparse(rows) else np.asarray(rows, dtype=np.float64)
        d = np.asarray(displacements, dtype=np.float64)
        if d.ndim != 3 or d.shape[1:] != (rows.shape[1], 3):
            raise InputError(f"displacements must have shape (T, {rows.shape[1]}, 3), got "
                             f"{d.shape}")
        sequences["W·D"] = (len(d), partial(_operator_lips, rest, rows, d))
    for name, (shapes, weights) in (bases or {}).items():
        shapes = np.asarray(shapes, dtype=np.float64)
        weights = np.asarray(weights, dtype=np.float64)
        if shapes.ndim != 3 or shapes.shape[1:] != neutral.shape or weights.ndim != 2 \
                or weights.shape[1] != len(shapes):
            raise InputError(f"basis {name!r}: shapes (n, {len(neutral)}, 3) and weights "
                             f"(T, n) expected, got {shapes.shape} and {weights.shape}")
        at_lips = shapes[:, ids].reshape(len(shapes), -1)
        sequences[name] = (len(weights), partial(_basis_lips, rest, at_lips, weights))
    gaps = {name: np.empty(n) for name, (n, _) in sequences.items()}

    def measure(block):
        name, frames = block
        gaps[name][frames] = mm_per_unit * mouth.gap(sequences[name][1](frames))
    # blocks of frames of every sequence, shared among the BLAS's threads (the products and
    # reductions of a block run without the GIL)
    map_on_blas_threads(measure, [(name, slice(first, first + _CHUNK_FRAMES))
                                  for name, (n, _) in sequences.items()
                                  for first in range(0, n, _CHUNK_FRAMES)])
    return gaps


def _operator_lips(rest, rows, displacements, frames):
    """The lips' vertices ``rest + W_lips d_t`` of `frames`, (T, n, 3)."""
    lips = np.matmul(rows, displacements[frames])
    lips += rest
    return lips


def _basis_lips(rest, at_lips, weights, frames):
    """The lips' vertices ``rest + Σ_i w_ti e_i`` of `frames`, (T, n, 3)."""
    lips = (weights[frames] @ at_lips).reshape(-1, *rest.shape)
    lips += rest
    return lips


def plot_lip_seal(check, path, *, title: str | None = None) -> None:
    """Lip opening from rest per frame: the lip markers' and each mesh's (PNG).

    Under the curves, one strip per mesh marks the frames where it stays shut
    while the markers open the mouth (solid) or opens it while they keep it
    shut (hatched). x: the capture's frame numbers.

    Parameters
    ----------
    check : mocap.retarget.lip_seal.LipSealCheck
    path : str or os.PathLike
    """
    x = check.frames
    names = list(check.mesh_gap)
    colours = distinct_colours(len(names))
    with report_figure(path, 11, 5.2) as fig:
        ax = fig.add_subplot()
        columns = int(11 * DPI)                     # the figure's pixel columns
        ax.plot(*line_envelope(x, check.marker_opening, columns), color="black", lw=1.4,
                label=f"lip markers ({check.witness})" if check.witness else "lip markers")
        for name, colour in zip(names, colours):
            ax.plot(*line_envelope(x, check.mesh_opening(name), columns), color=colour, lw=0.9,
                    label=f"{name} mesh")
        ax.axhline(check.marker_open_mm, color="grey", lw=0.8, ls="--")
        ax.annotate(f"markers open: {check.marker_open_mm:.3g} mm", (x[0], check.marker_open_mm),
                    fontsize=7, color="grey", xytext=(2, 2), textcoords="offset points")
        top = max(float(np.max(check.marker_opening, initial=0.0)),
                  max((float(np.max(check.mesh_opening(n), initial=0.0)) for n in names),
                      default=0.0), check.marker_open_mm) * 1.08
        low = min(float(np.min(check.marker_opening, initial=0.0)),
                  min((float(np.min(check.mesh_opening(n), initial=0.0)) for n in names),
                      default=0.0))
        strip = 0.05 * (top - low)
        for k, (name, colour) in enumerate(zip(names, colours)):
            y0 = low - (k + 1.2) * strip
            for mask, hatch in ((check.shut(name), None), (check.parted(name), "////")):
                ax.fill_between(x, y0, y0 + 0.8 * strip, where=mask, step="mid",
                                facecolor=colour if hatch is None else "none",
                                edgecolor=colour, hatch=hatch, lw=0)
            ax.annotate(name, (x[-1], y0 + 0.4 * strip), fontsize=7, color=colour,
                        xytext=(4, 0), textcoords="offset points", va="center")
        ax.set_ylim(low - (len(names) + 1.4) * strip, top)
        ax.set_xlim(x[0], x[-1])
        ax.set_xlabel("capture frame")
        ax.set_ylabel("opening from rest (mm)")
        ax.grid(alpha=0.3)
        handles, labels = ax.get_legend_handles_labels()
        handles += [Patch(facecolor="grey", label="strip: mesh shut, markers open"),
                    Patch(facecolor="none", edgecolor="grey", hatch="////",
                          label="strip: mesh open, markers shut")]
        fig.legend(handles=handles, loc="outside upper center", fontsize=8,
                   ncol=min(len(handles), 4), frameon=False)
        ax.set_title(title or f"Lip seal: opening from rest (mesh rest gap "
                              f"{check.rest_gap:.1f} mm); shut: opened by < "
                              f"{check.fraction:.0%} of the markers' opening", fontsize=10)


def plot_cross_validation(cv, path, *, markerset=None, title: str | None = None) -> None:
    """Held-out error and motion of each marker, grouped by region (PNG, horizontal bars).

    Parameters
    ----------
    cv : mocap.retarget.cross_validation.CrossValidation
    path : str or os.PathLike
    markerset : mocap.markerset.MarkerSet, optional
        Groups the markers by region.
    """
    order, groups = region_groups(cv.labels, markerset)
    n = len(order)
    y = np.arange(n, dtype=float)
    colours = region_colours(groups)
    with report_figure(path, 8.5, min(max(4.0, 0.2 * n + 1.6), 16.0)) as fig:
        ax = fig.add_subplot()
        # Every bar in one collection, the wide pale ones first (under the narrow ones).
        ax.add_collection(bar_collection(
            np.concatenate([y, y]),
            np.concatenate([cv.motion_rms[order], np.nan_to_num(cv.marker_rms[order])]),
            np.repeat([0.8, 0.45], n), np.concatenate([colours * [1, 1, 1, 0.25], colours]),
            horizontal=True))
        singular = np.flatnonzero(~np.isfinite(cv.marker_rms[order]))
        ax.scatter(np.zeros(len(singular)), y[singular], marker="x", color="black", zorder=3)
        label_ticks(ax, y, [cv.labels[i] for i in order],
                    fontsize=max(5, min(8, 420 // max(n, 1))))
        ax.set_ylim(n - 0.5, -0.5)
        for _, start, _ in groups[1:]:
            ax.axhline(start - 0.5, color="grey", lw=0.6, ls=":")
        sec = ax.secondary_yaxis("right")
        sec.set_yticks([(start + stop - 1) / 2 for _, start, stop in groups],
                       labels=[name.replace("_", " ") for name, _, _ in groups], fontsize=8)
        sec.tick_params(length=0)
        ax.set_xlabel("mm (RMS over the frames)")
        ax.grid(axis="x", alpha=0.3)
        fig.legend(handles=[Patch(color="grey", alpha=0.25,
                                  label="the marker's motion (wide, pale)"),
                            Patch(color="grey", label="held-out error (narrow)")],
                   loc="outside lower center", ncol=2, fontsize=8, frameon=False)
        ax.set_title(title or f"Held-out error per marker: RMS {cv.rms:.2f} mm, "
                              f"{cv.relative:.0%} of the markers' motion", fontsize=10)


def _region_of(markerset, label: str) -> str:
    if markerset is None:
        return ""
    try:
        return markerset.region_of(label)
    except ValueError:
        return "unassigned"


def cross_validation_section(cv, *, markerset=None, selection=None,
                             image=None) -> Section:
    """The report's cross-validation section: pooled, per region, per marker, and the selection.

    Parameters
    ----------
    cv : mocap.retarget.cross_validation.CrossValidation
    markerset : mocap.markerset.MarkerSet, optional
        Regions of the per-region table.
    selection : mocap.retarget.selection.RetargetSelection, optional
        What ``kernel = "auto"`` tried.
    image : path or bytes, optional
        :func:`plot_cross_validation`'s picture.
    """
    paragraphs = [
        f"Operator: {cv.variant}. Each face marker in turn is left out, the operator is "
        "rebuilt from the others, and the mesh it drives is read at the left-out marker's "
        "bound point in every frame: the distance to where the marker really was is what the "
        "retargeting gets wrong where it has no marker (computed in closed form, Rippa 1999). "
        f"Over all {len(cv.labels)} markers and {cv.n_frames} frames: RMS {cv.rms:.3g} mm, "
        f"{cv.relative:.1%} of the markers' RMS motion from rest (100 %: no better than "
        "leaving the mesh at rest). Tables below: per region, per marker"
        + (", and the variants kernel = \"auto\" scored best (with its choice)."
           if selection is not None else ".")]
    if cv.loo.singular:
        paragraphs.append("Not scored: " + "; ".join(f"{k}: {v}"
                                                     for k, v in cv.loo.singular.items()))
    tables = []
    if markerset is not None:
        regions = {name: members for name, members in markerset.regions.items()}
        rows = [[r["region"], r["markers"], r["rms_mm"], r["motion_mm"], 100 * r["relative"]]
                for r in cv.by_region(regions)]
        tables.append(("cv-regions", ["region", "markers", "held-out RMS (mm)",
                                      "motion RMS (mm)", "error / motion (%)"], rows))
    rows = [[label, _region_of(markerset, label), cv.marker_rms[i], cv.motion_rms[i],
             100 * cv.marker_rms[i] / cv.motion_rms[i] if cv.motion_rms[i] > 0 else np.nan]
            for i, label in enumerate(cv.labels)]
    tables.append(("cv-markers", ["marker", "region", "held-out RMS (mm)", "motion RMS (mm)",
                                  "error / motion (%)"], rows))
    if selection is not None:
        paragraphs.append(
            f"kernel = \"auto\" tried {len(selection.candidates)} variants (shape parameters "
            f"in units of the median marker spacing h = "
            f"{selection.spacing * selection.mm_per_unit:.1f} mm) "
            f"in {selection.seconds:.1f} s and chose {selection.best.name}: the "
            f"{selection.rule}. Lips open: the mesh's median opening over the lip markers' at "
            "those frames; shut frames: where it opens less than a quarter of theirs.")
        scores = np.array([c.score_mm for c in selection.candidates])
        ranked = [int(i) for i in np.argsort(np.where(np.isfinite(scores), scores, np.inf))]
        listed = list(dict.fromkeys([selection.chosen] + ranked[:_LISTED]))
        listed.sort(key=lambda i: ranked.index(i))
        tables.append(("cv-selection", ["rank", "variant", "held-out RMS (mm)", "lips open",
                                        "shut frames", "chosen", "note"],
                       [[ranked.index(i) + 1, selection.candidates[i].name,
                         selection.candidates[i].score_mm,
                         np.nan if selection.candidates[i].lips_open is None
                         else selection.candidates[i].lips_open,
                         "–" if selection.candidates[i].lips_shut_frames is None
                         else selection.candidates[i].lips_shut_frames,
                         "yes" if i == selection.chosen else "", selection.candidates[i].note]
                        for i in listed]))
    items = (Figure(image, "Held-out error per marker (narrow) against its motion (wide)",
                    "A marker whose narrow bar nears its wide one is predicted no better "
                    "than leaving the mesh at rest there."),) if image is not None else ()
    return Section("Retargeting: leave-one-marker-out cross-validation",
                   text=tuple(paragraphs), items=items,
                   tables=tuple(Table(tuple(header), tuple(map(tuple, rows)), table_id)
                                for table_id, header, rows in tables))


def lip_seal_section(check, *, image=None) -> Section:
    """The report's lip-seal section: the warnings, the thresholds, a row per mesh.

    Parameters
    ----------
    check : mocap.retarget.lip_seal.LipSealCheck
    image : path or bytes, optional
        :func:`plot_lip_seal`'s picture.
    """
    paragraphs = (
        f"The lip markers ({check.witness}) open the mouth by up to "
        f"{float(np.max(check.marker_opening, initial=0.0)):.1f} mm from rest. Each mesh's "
        "lip gap is the smallest distance between its upper and lower lip over the middle of "
        f"the mouth ({check.rest_gap:.1f} mm on the neutral); a frame is flagged when the "
        f"markers open by at least {check.marker_open_mm:.3g} mm (at least {check.open_mm:g} "
        "mm, more for markers far apart at rest: lips can stay sealed while the jaw drops, "
        "and markers off the lips then part anyway) and the mesh by less "
        f"than {check.fraction:.0%} of that (shut), or the mesh by at least "
        f"{check.open_mm:g} mm and the markers by less than {check.fraction:.0%} of that "
        "(parted). Frames are the capture's frame numbers.",)
    rows = []
    for name in check.mesh_gap:
        opening = check.mesh_opening(name)
        rows.append([name, float(np.max(opening, initial=0.0)), int(check.shut(name).sum()),
                     int(check.parted(name).sum())])
    tables = (Table(("mesh", "widest opening (mm)", "shut frames", "parted frames"),
                    tuple(map(tuple, rows)), "lip-seal"),)
    items = (Figure(image, "Lip opening from rest: markers and meshes",
                    "Strips mark the frames where a mesh contradicts the markers."),) \
        if image is not None else ()
    return Section("Lip seal and contact", text=paragraphs, tables=tables, items=items,
                   warnings=tuple(check.messages()))
