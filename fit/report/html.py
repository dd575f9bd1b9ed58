"""One self-contained HTML page per take: figures and videos as base64 data
URIs and the tables behind them (provenance, graded summary per basis, worst
frames, per-marker errors, ingestion figures). No external resources: the file
can be mailed or archived.

The page is a list of :class:`Section` s after the fixed head (title,
provenance, grades, summary, glossary): a new kind of QA adds a section
(:func:`fit.report.build_report` takes extra ones), nothing else changes.

Every numeric cell carries its full-precision value in a ``data-value``
attribute, so scripts (and the tests) can read the page back exactly.
"""

from __future__ import annotations

import base64
import html
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from fit.metrics import ReconstructionErrors
from fit.report.drawing import FIGURE_MARGIN_PX, PAGE_WIDTH_PX
from fit.report.grades import GRADES
from fit.report.video import VIDEO_MIME
from fit.report.warning_list import warnings_section
from mocap.errors import InputError
from mocap.util.atomic import atomic_path

__all__ = ["Figure", "Video", "Table", "Section", "GLOSSARY", "render_report", "write_report",
           "ingest_stats"]

#: One sentence on each basis and on α, shown at the top of every report.
GLOSSARY = {
    "α": "α = 100·‖v* − v‖/‖v*‖ over all markers of a frame (the quasi-eigen paper's eq. 6): the "
         "reconstruction error relative to the markers' distance from the origin stated in the "
         "summary, so it depends on that origin; read it with the RMS in mm.",
    "H": "H, the artist's (hand-made) basis: the fitted weights are the rig's own controls, "
         "bounded to [0, 1]; its error says what the rig cannot express.",
    "QE": "QE, quasi-eigen faces: each artist shape projected onto the span of the take's "
          "principal components (eq. 3-4), so the rig's names with the capture's motion; weights "
          "are unbounded and may be negative.",
    "PCA": "PCA, the principal components of this take's retargeted mesh motion W·D "
           "(weights in standard deviations of the take); the best any linear basis of that "
           "size does on these frames, so it flatters itself in-sample.",
    "W·D": "W·D, the retargeted mesh: the RBF operator W applied to the marker displacements "
           "D, the mesh motion every basis is fitted to and the reference of the mesh renders.",
}


@dataclass(frozen=True)
class Figure:
    """A PNG of the report, with its caption and a sentence on how to read it."""

    source: object
    caption: str
    read: str = ""


@dataclass(frozen=True)
class Video(Figure):
    """A browser-playable video (VP9 WebM) embedded in a ``<video>`` element."""


@dataclass(frozen=True)
class Table:
    """A table: a header and rows of cells (numbers keep their exact value)."""

    header: tuple
    rows: tuple
    table_id: str = ""


@dataclass(frozen=True)
class Section:
    """One section of the page, in order: text, tables, then figures and videos.

    Attributes
    ----------
    title : str
    text : str or sequence of str
        A paragraph, or several (escaped).
    tables : sequence of Table
    items : sequence of Figure or Video
    anchor : str
        The section's id (default from the title).
    warnings : sequence of str
        Shown highlighted above the text.
    """

    title: str
    text: str | tuple = ""
    tables: tuple = ()
    items: tuple = ()
    anchor: str = ""
    warnings: tuple = ()

_STYLE = f"""
body {{ font-family: sans-serif; margin: 2em; color: #222; max-width: {PAGE_WIDTH_PX}px; }}
figure {{ margin: 1em {FIGURE_MARGIN_PX}px; }}
table {{ border-collapse: collapse; margin: 0.5em 0 1.5em; font-size: 0.85em; }}
th, td {{ border: 1px solid #ccc; padding: 2px 8px; }}
td.num {{ text-align: right; font-variant-numeric: tabular-nums; }}
th {{ background: #f0f0f0; }}
img, video {{ max-width: 100%; border: 1px solid #eee; margin: 0.5em 0; }}
figcaption {{ font-size: 0.85em; color: #555; max-width: 1100px; }}
.badge {{ display: inline-block; padding: 0 6px; border-radius: 3px; font-weight: bold;
         color: white; font-size: 0.85em; }}
.pass {{ background: #2e7d32; }} .warn {{ background: #ef8f00; }} .fail {{ background: #c62828; }}
.na {{ background: #888; }}
dl.glossary dt {{ font-weight: bold; float: left; width: 3em; }}
dl.glossary dd {{ margin: 0 0 0.4em 3.5em; }}
p.warning {{ background: #fff3cd; border-left: 4px solid #e0a800; padding: 4px 8px; }}
"""


_SUMMARY_COLUMNS = {"alpha": "α take (%)", "alpha_mean": "α mean (%)",
                    "alpha_max": "α max (%)", "displacement_error": "‖d*−d‖/‖d*‖ (%)",
                    "rms_mm": "RMS (mm)", "mean_mm": "mean (mm)", "p95_mm": "p95 (mm)",
                    "max_mm": "max (mm)", "worst_frame": "worst frame",
                    "n_samples": "samples", "n_missing": "excluded"}


def _cell(value) -> str:
    """A table cell; numbers right-aligned with their exact value in data-value."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)):
        return f"<td>{html.escape(str(value))}</td>"
    if isinstance(value, (int, np.integer)):
        return f'<td class="num" data-value="{int(value)}">{int(value)}</td>'
    value = float(value)
    shown = "–" if math.isnan(value) else f"{value:.4g}"
    return f'<td class="num" data-value="{value!r}">{shown}</td>'


def _table(header, rows, *, table_id: str) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    head = f"<thead><tr>{head}</tr></thead>" if any(header) else ""
    body = "".join("<tr>" + "".join(_cell(v) for v in row) + "</tr>" for row in rows)
    return f'<table id="{table_id}">{head}<tbody>{body}</tbody></table>'


def _image(source) -> str:
    """A data URI of a PNG given as a path or as bytes."""
    data = source if isinstance(source, bytes) else Path(source).read_bytes()
    if not data.startswith(b"\x89PNG"):
        raise InputError(f"image {source if not isinstance(source, bytes) else '<bytes>'} "
                         "is not a PNG")
    return "data:image/png;base64," + base64.b64encode(data).decode("ascii")


def ingest_stats(result) -> dict:
    """Headline figures of an ingestion (:class:`mocap.clean.ingest.IngestResult`), a dict.

    Samples missing in the raw take, filled (in total and per method), still
    missing, and, when stabilized, the head-fit noise, slips and frames
    without a fit.
    """
    raw = result.raw
    stats = {"frames": raw.n_frames, "markers": raw.n_markers, "rate (Hz)": raw.rate,
             "raw missing samples": int(raw.missing.sum())}
    if result.fill is not None:
        stats["filled samples"] = int(result.fill.n_filled)
        stats["still missing samples"] = int(result.fill.n_missing)
    if result.stabilization is not None:
        stab = result.stabilization
        stats["head frame"] = (f"{result.head_frame.method}: {', '.join(stab.head_markers)}"
                               if stab.head_markers else result.head_frame.method)
        stats["head-fit noise (mm)"] = float(stab.noise)
        stats["head-marker slips"] = len(stab.slips)
        stats["frames without a head fit"] = int((~np.asarray(stab.valid)).sum())
    return stats


def _badge(verdict: str) -> str:
    return f'<span class="badge {"na" if verdict == "n/a" else verdict}">{verdict}</span>'


def _media(item) -> str:
    """A figure or a video as HTML, caption and how-to-read under it."""
    caption = html.escape(item.caption)
    read = f" {html.escape(item.read)}" if item.read else ""
    if isinstance(item, Video):
        data = Path(item.source).read_bytes()
        src = f"data:video/webm;base64,{base64.b64encode(data).decode('ascii')}"
        body = (f'<video controls preload="metadata" title="{caption}">'
                f'<source src="{src}" type=\'{VIDEO_MIME}\'></video>')
    else:
        body = f'<img alt="{caption}" src="{_image(item.source)}">'
    return f"<figure>{body}<figcaption><b>{caption}.</b>{read}</figcaption></figure>"


def _section(section: Section) -> str:
    anchor = section.anchor or "-".join(section.title.lower().split())
    parts = [f'<h2 id="{html.escape(anchor)}">{html.escape(section.title)}</h2>']
    parts += [f'<p class="warning">{html.escape(w)}</p>' for w in section.warnings]
    texts = (section.text,) if isinstance(section.text, str) else section.text
    parts += [f"<p>{html.escape(text)}</p>" for text in texts if text]
    for table in section.tables:
        parts.append(_table(table.header, table.rows, table_id=table.table_id))
    parts += [_media(item) for item in section.items]
    return "\n".join(parts)


def _provenance(provenance: Mapping) -> str:
    """Headed two-column tables (mappings) or :class:`Table` s."""
    parts = ['<h2 id="provenance">Provenance</h2>']
    for heading, block in provenance.items():
        parts.append(f"<h3>{html.escape(heading)}</h3>")
        if isinstance(block, Table):
            parts.append(_table(block.header, block.rows, table_id=block.table_id))
        else:
            parts.append(_table(["", ""], list(block.items()),
                                table_id="provenance-" + "-".join(heading.lower().split())))
    return "\n".join(parts)


def _grades(grades) -> str:
    """The graded figures: what, value, badge, thresholds, what a failure means."""
    rows = "".join(
        f"<tr><td>{html.escape(what)}</td>{_cell(value)}<td>{_badge(GRADES[key].of(value))}"
        f"</td><td>{html.escape(GRADES[key].rule())}</td>"
        f"<td>{html.escape(GRADES[key].why)}</td></tr>"
        for what, key, value in grades)
    head = "".join(f"<th>{h}</th>" for h in ("figure", "value", "grade", "thresholds",
                                             "a failure means"))
    return (f'<h2 id="grades">Grades</h2><table id="grades-table"><thead><tr>{head}</tr>'
            f"</thead><tbody>{rows}</tbody></table>")


def render_report(results, images: Mapping, *, title: str, first_frame: int = 0,
                  worst: Mapping | None = None, markerset=None,
                  ingest: Mapping | None = None, notes: str = "",
                  provenance: Mapping | None = None, grades=(), sections=(),
                  held_out: Mapping | None = None, held_out_label: str = "",
                  warnings=()) -> str:
    """The report page as a string.

    Parameters
    ----------
    results : mapping of name to ReconstructionErrors, or a sequence of them
        One per basis (same take, same markers), in-sample.
    images : mapping of caption to PNG path or bytes, or to Figure / Video
        Figures (a section "Figures"), embedded in order as data URIs.
    title : str
    first_frame : int
        Added to frame indices in the tables (the take's frame numbers).
    worst : mapping of basis name to frame indices, optional
        Worst frames to list per basis (default each result's 5 worst by RMS).
    markerset : mocap.markerset.MarkerSet, optional
        Adds a region column to the per-marker table.
    ingest : mapping of str to number or str, optional
        Ingestion figures (see :func:`ingest_stats`).
    notes : str
        A paragraph of text under the title (escaped).
    provenance : mapping of heading to mapping or Table, optional
        What made the take's results (inputs, versions, parameters, frames,
        binding, stabilization), first on the page.
    grades : sequence of (what, key of fit.report.grades.GRADES, value)
        Graded figures, each with its badge and thresholds.
    sections : sequence of Section
        The page's sections after the summary and the glossary, in order.
    held_out : mapping of basis name to ReconstructionErrors, optional
        Out-of-sample errors of the bases built from the take itself, shown in
        the summary beside the in-sample ones, labelled with `held_out_label`.
    warnings : sequence of str
        Warnings of the run, in a section of their own under the summary
        (:func:`fit.report.warning_list.warnings_section`).
    """
    if isinstance(results, ReconstructionErrors):
        results = [results]
    results = dict(results) if isinstance(results, Mapping) else {r.name: r for r in results}
    if not results:
        raise InputError("results is empty: give at least one ReconstructionErrors")
    held_out = dict(held_out or {})
    parts = [f"<h1>{html.escape(title)}</h1>"]
    if notes:
        parts.append(f"<p>{html.escape(notes)}</p>")
    if provenance:
        parts.append(_provenance(provenance))
    if grades:
        parts.append(_grades(grades))
    first = next(iter(results.values()))
    origin = ", ".join(f"{v:.1f}" for v in first.origin)
    parts.append(f"<h2>Summary per basis</h2><p>α (eq. 6) with the origin at ({origin}) mm; "
                 "the take-wide α pools all samples of the take. <b>In-sample</b>: the basis "
                 "scored on the frames it was built from (QE and PCA come from this take). "
                 + (f"<b>Out-of-sample</b>: {html.escape(held_out_label)}." if held_out else "")
                 + " Frames are the capture's own frame numbers.</p>")
    rows = []
    for name, r in results.items():
        scored = [("in-sample" if name in held_out else "", r)]
        if name in held_out:
            scored.append(("out-of-sample", held_out[name]))
        rows += [[name, kind, *(e.totals[k] + (first_frame if k == "worst_frame" else 0)
                                for k in _SUMMARY_COLUMNS)] for kind, e in scored]
    parts.append(_table(["basis", "frames scored", *_SUMMARY_COLUMNS.values()], rows,
                        table_id="summary"))
    parts.append(warnings_section(warnings))
    parts.append('<h2 id="glossary">How to read this report</h2><dl class="glossary">'
                 + "".join(f"<dt>{html.escape(k)}</dt><dd>{html.escape(v)}</dd>"
                           for k, v in GLOSSARY.items() if k in ("α", "W·D") or k in results)
                 + "</dl>")
    if ingest:
        parts.append("<h2>Ingestion</h2>")
        parts.append(_table(["quantity", "value"], list(ingest.items()), table_id="ingest"))
    parts.append("<h2>Worst frames</h2>")
    rows = []
    for name, r in results.items():
        frames = r.worst_frames(5) if worst is None or name not in worst else worst[name]
        rows += [[name, rank, int(t) + first_frame, r.alpha[t],
                  r.displacement_error[t], r.rms[t], r.max_error[t], int(r.n_valid[t])]
                 for rank, t in enumerate(frames, start=1)]
    header = ["basis", "rank", "frame", "α (%)", "‖d*−d‖/‖d*‖ (%)", "RMS (mm)", "max (mm)",
              "markers"]
    parts.append(_table(header, rows, table_id="worst"))
    if images:
        items = tuple(v if isinstance(v, Figure) else Figure(v, k)
                      for k, v in images.items())
        sections = (Section("Figures", items=items), *sections)
    parts += [_section(section) for section in sections]
    parts.append("<h2>Per-marker errors (mm)</h2>")
    header = ["marker"] + (["region"] if markerset is not None else [])
    for name in results:
        header += [f"{name} mean", f"{name} p95", f"{name} max"]
    header.append("frames excluded")
    rows = []
    for j, label in enumerate(first.labels):
        row = [label] + ([_region(markerset, label)] if markerset is not None else [])
        for r in results.values():
            row += [r.marker_mean[j], r.marker_p95[j], r.marker_max[j]]
        rows.append(row + [int(first.n_missing[j])])
    parts.append(_table(header, rows, table_id="markers"))
    body = "\n".join(parts)
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head>"
            f"<body>\n{body}\n</body></html>\n")


def _region(markerset, label: str) -> str:
    try:
        return markerset.region_of(label)
    except ValueError:
        return "unassigned"


def write_report(path, results, images: Mapping, **options) -> None:
    """Write :func:`render_report` to `path` (UTF-8, atomically).

    Parameters
    ----------
    path : str or os.PathLike
        Output ``.html``.
    results, images, **options
        As :func:`render_report`.
    """
    page = render_report(results, images, **options)
    with atomic_path(path) as tmp:
        Path(tmp).write_text(page, encoding="utf-8")
