"""One self-contained HTML page per take: figures as base64 data URIs and the
tables behind them (summary per basis, worst frames, per-marker errors,
ingestion figures). No external resources: the file can be mailed or archived.

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
from mocap.errors import InputError
from mocap.util.atomic import atomic_path

__all__ = ["render_report", "write_report", "ingest_stats", "ReportSection"]

_STYLE = """
body { font-family: sans-serif; margin: 2em; color: #222; max-width: 1400px; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; font-size: 0.85em; }
th, td { border: 1px solid #ccc; padding: 2px 8px; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
th { background: #f0f0f0; }
img { max-width: 100%; border: 1px solid #eee; margin: 0.5em 0; }
figcaption { font-size: 0.85em; color: #555; }
p.warning { background: #fff3cd; border-left: 4px solid #e0a800; padding: 4px 8px; }
"""


@dataclass(frozen=True)
class ReportSection:
    """A section made elsewhere: heading, warnings, paragraphs, tables, figures, in that order.

    Attributes
    ----------
    title : str
    paragraphs : tuple of str
        Plain text (escaped).
    tables : tuple of (table_id, header, rows)
        As the page's own tables: numbers carry their exact value in ``data-value``.
    images : tuple of (caption, PNG path or bytes)
    warnings : tuple of str
        Shown highlighted above the paragraphs.
    """

    title: str
    paragraphs: tuple = ()
    tables: tuple = ()
    images: tuple = ()
    warnings: tuple = ()

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
    body = "".join("<tr>" + "".join(_cell(v) for v in row) + "</tr>" for row in rows)
    return f'<table id="{table_id}"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>'


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
        stats["head-fit noise (mm)"] = float(stab.noise)
        stats["head-marker slips"] = len(stab.slips)
        stats["frames without a head fit"] = int((~np.asarray(stab.valid)).sum())
    return stats


def render_report(results, images: Mapping, *, title: str, first_frame: int = 0,
                  worst: Mapping | None = None, markerset=None,
                  ingest: Mapping | None = None, notes: str = "",
                  sections=()) -> str:
    """The report page as a string.

    Parameters
    ----------
    results : mapping of name to ReconstructionErrors, or a sequence of them
        One per basis (same take, same markers).
    images : mapping of caption to PNG path or bytes
        Figures, embedded in order as data URIs.
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
    sections : sequence of ReportSection
        Appended at the end of the page, in order.
    """
    if isinstance(results, ReconstructionErrors):
        results = [results]
    results = dict(results) if isinstance(results, Mapping) else {r.name: r for r in results}
    if not results:
        raise InputError("results is empty: give at least one ReconstructionErrors")
    parts = [f"<h1>{html.escape(title)}</h1>"]
    if notes:
        parts.append(f"<p>{html.escape(notes)}</p>")
    first = next(iter(results.values()))
    origin = ", ".join(f"{v:.1f}" for v in first.origin)
    parts.append(f"<h2>Summary per basis</h2><p>α (eq. 6) with the origin at ({origin}) mm; "
                 "the take-wide α pools all samples of the take.</p>")
    parts.append(_table(["basis", *_SUMMARY_COLUMNS.values()],
                        [[name, *(r.totals[k] + (first_frame if k == "worst_frame" else 0)
                                  for k in _SUMMARY_COLUMNS)]
                         for name, r in results.items()], table_id="summary"))
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
    parts.append("<h2>Figures</h2>")
    parts += [_figure(caption, source) for caption, source in images.items()]
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
    parts += [_section(section) for section in sections]
    body = "\n".join(parts)
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head>"
            f"<body>\n{body}\n</body></html>\n")


def _figure(caption: str, source) -> str:
    return (f'<figure><img alt="{html.escape(caption)}" src="{_image(source)}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def _section(section: ReportSection) -> str:
    parts = [f"<h2>{html.escape(section.title)}</h2>"]
    parts += [f'<p class="warning">{html.escape(w)}</p>' for w in section.warnings]
    parts += [f"<p>{html.escape(p)}</p>" for p in section.paragraphs]
    parts += [_table(header, rows, table_id=table_id) for table_id, header, rows in section.tables]
    parts += [_figure(caption, source) for caption, source in section.images]
    return "\n".join(parts)


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
