"""What made a take's results, for the head of its QA report, and the grades of the stages.

Inputs with their SHA-256, versions, every stage's options, the frames (the
capture's numbers), the neutral frame and its window, the binding (RMS, the
markers over the warning distance) and the head stabilization (residuals,
slips): what a TD needs to trust, or to reproduce, what the report shows.
"""

from __future__ import annotations

import dataclasses
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from fit.pipeline.config import STAGE_TABLES
from fit.pipeline.manifest import package_versions, sha256_path
from fit.report.html import Table
from mocap.util.order_statistics import percentile

__all__ = ["take_provenance", "stage_grades"]


def _inputs(result, inputs) -> Table:
    if inputs is None:
        recon = result.reconstruction
        inputs = {"capture": result.ingested.raw.source.path, "mesh": recon.mesh.path,
                  "markerset": recon.markerset.path}
    rows = []
    for role, given in inputs.items():
        # a manifest entry carries the digest the run's record has: no second read
        path, digest = ((given.get("path"), given.get("sha256")) if isinstance(given, dict)
                        else (given, None))
        if path is None:
            continue
        path = Path(path)
        if digest is None:
            digest = sha256_path(path) if path.exists() else "(not found)"
        rows.append([role, str(path), digest])
    return Table(("role", "path", "SHA-256"), tuple(rows), "provenance-inputs")


def _parameters(result) -> Table:
    recon = result.reconstruction
    rows = []
    for table in STAGE_TABLES:
        options = getattr(recon, "basis_options" if table == "basis" else table)
        rows.append([f"[{table}]", "; ".join(f"{key} = {value!r}" for key, value
                                            in dataclasses.asdict(options).items())])
    return Table(("run.toml table", "options"), tuple(rows), "provenance-parameters")


def _slips(stab, first_frame: int) -> Table:
    rows = [[k, s.marker, f"{first_frame + s.start}–{first_frame + s.stop - 1}",
             s.max_residual] for k, s in enumerate(stab.slips, start=1)]
    return Table(("slip", "head marker", "frames", "max residual (mm)"), tuple(rows),
                 "provenance-slips")


def take_provenance(result, *, inputs=None) -> dict:
    """The provenance blocks of a :class:`fit.pipeline.reconstruction.ReconstructionResult`.

    Parameters
    ----------
    result : ReconstructionResult
    inputs : mapping of role to path or to ``{"path", "sha256"}``, optional
        The files the take read (default the capture, the mesh and the marker
        set as the result knows them); a path is hashed, an entry with its
        digest (the run's record of it) is shown as it is.

    Returns
    -------
    dict of heading to mapping or Table
        For :func:`fit.report.html.render_report`.
    """
    take, stab, bound = result.take, result.ingested.stabilization, result.bound
    binding = bound.binding
    first = take.first_frame
    versions = package_versions()
    run = {"generated (UTC)": datetime.now(timezone.utc).isoformat(timespec="seconds"),
           "mocap2mesh": versions.get("mocap2mesh") or "unknown",
           "versions": ", ".join(f"{k} {v}" for k, v in versions.items()
                                 if k != "mocap2mesh" and v)}
    raw = result.ingested.raw
    frames = {"capture frames": f"{raw.first_frame}–{raw.first_frame + raw.n_frames - 1}",
              "frames reconstructed": f"{first}–{first + take.n_frames - 1} "
                                      f"({take.n_frames} frames; the ends without every face "
                                      "marker are cut)",
              "rate (Hz)": take.rate,
              "neutral frame": first + bound.frame,
              "neutral window (frames)": bound.window,
              "frame numbers": "the capture's own, in every table, file and option"}
    warn = result.reconstruction.bind.max_distance_warn
    excess = np.abs(np.asarray(binding.distances) - binding.skin_offset)
    far = [f"{label} {d:.1f} mm" for label, d, e in
           zip(binding.labels, binding.distances, excess) if e > warn]
    bind = {"RMS off the skin (mm)": binding.rms, "skin offset (mm)": binding.skin_offset,
            "warning distance (mm)": warn,
            f"markers off the skin by more than {warn:g} mm": ", ".join(far) or "none",
            "fit": binding.message}
    blocks = {"Run": run, "Inputs": _inputs(result, inputs), "Parameters": _parameters(result),
              "Frames": frames, "Binding": bind}
    if stab is not None:
        res = np.asarray(stab.head_residuals)
        finite = res[np.isfinite(res)]
        blocks["Head stabilization"] = {
            "head markers": ", ".join(stab.head_markers),
            "noise (mm)": stab.noise,
            "residual median / 95th percentile / max (mm)":
                " / ".join(f"{v:.3f}" for v in percentile(finite, [50, 95, 100]))
                if finite.size else "–",
            "frames without a head fit": int((~np.asarray(stab.valid)).sum()),
            "slips": len(stab.slips)}
        if stab.slips:
            blocks["Head-marker slips"] = _slips(stab, stab.take.first_frame)
    return blocks


def stage_grades(result) -> list:
    """Graded figures of the stages before the fit: (what, grade key, value)."""
    stab = result.ingested.stabilization
    grades = [("binding RMS off the skin (mm)", "binding_rms_mm", result.binding.rms)]
    if stab is not None:
        grades += [("head-fit noise (mm)", "head_noise_mm", stab.noise),
                   ("head-marker slips", "head_slips", len(stab.slips))]
    return grades
