"""``mocap2mesh run CONFIG.toml``: every take of a session through the whole chain.

ingest → clean → stabilize → bind → retarget → PCA / quasi-eigen → fit →
exports and QA report, takes in parallel (a process pool, one progress bar),
into the configured output directory, one folder per take, and
``manifest.json`` at the top. A take whose inputs and parameters are
unchanged since its last successful run is skipped; a failing take is
reported (stderr and manifest, exit code 1) and does not stop the others.
"""

from __future__ import annotations

import math
import sys
import time
import traceback
import warnings
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

import mocap
from basis.artist import ArtistBasis, load_artist_basis
from basis.basis_io import load_basis, save_basis
from basis.gltf import write_gltf
from mocap.errors import InputError, Mocap2MeshError
from mocap.markerset import load_markerset
from mocap.mesh.mesh import load_mesh
from mocap.mesh.landmarks import load_mesh_landmarks

from fit.exports import write_mesh_sequence, write_weights_csv
from mocap.clean.ingest import save_head_motion
from fit.report.ingest_plots import plot_gaps, plot_head_residuals
from fit.pipeline.manifest import (MANIFEST_NAME, load_manifest, package_versions, reusable_record,
                        sha256_path, take_key, write_manifest)
from fit.metrics import reconstruction_errors
from fit.pipeline.stages import (basis_stage, bind_stage, complete_span, fit_stage, ingest_stage,
                        retarget_stage)
from fit.report import build_report
from fit.pipeline.config import RunConfig, load_run_config

__all__ = ["add_parser", "run", "run_takes", "process_take", "load_artist", "RunOutcome"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "run", help="run the whole chain on every take of a configuration",
        description="Ingest, stabilize, bind, retarget, build the PCA and quasi-eigen bases, "
                    "fit the weights of every basis and write exports and QA reports for "
                    "every take named by CONFIG.toml; manifest.json records inputs (SHA-256), "
                    "parameters, versions and metrics. Unchanged takes are skipped.")
    p.add_argument("config", type=Path, help="run configuration (TOML)")
    p.add_argument("-j", "--workers", type=int, metavar="N",
                   help="parallel takes (default: output.workers, else min(2, takes))")
    p.add_argument("--force", action="store_true", help="re-run takes even if unchanged")
    p.set_defaults(run=run)


@dataclass(frozen=True)
class RunOutcome:
    """What a run did: the manifest written and the fate of each take."""

    manifest: Path
    takes: dict
    n_failed: int
    n_skipped: int


def load_artist(path, mesh) -> ArtistBasis:
    """The artist basis at `path` on `mesh`'s topology.

    A :func:`basis.basis_io.save_basis` archive or directory (with
    ``basis.json``), a folder of OBJ shapes, or a glTF/GLB with morph targets.
    """
    path = Path(path)
    if path.suffix.lower() == ".npz" or (path / "basis.json").is_file():
        artist = load_basis(path, units=mesh.units)
    else:
        artist = load_artist_basis(mesh, path)
    if artist.neutral.n_vertices != mesh.n_vertices:
        raise InputError(f"{path}: the basis has {artist.neutral.n_vertices} vertices, the "
                         f"mesh {mesh.n_vertices}: they must share a topology")
    return artist


def _finite(summary: dict) -> dict:
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
            for k, v in summary.items()}


def process_take(capture, config: RunConfig) -> dict:
    """Run one take through the chain and write its folder; returns its manifest record.

    Files (relative to ``config.output``): ``<take>/take.c3d`` (cleaned,
    head-stabilized), ``head_motion.npz``, ``binding.json``, and per basis B in
    H, QE, PCA: ``basis-B.npz``, ``weights-B.csv``, ``mesh-B.npz`` (compact
    sequence), ``face-B.glb`` (morph targets, weight animation at the take's
    rate); ``report/`` with the QA pictures, videos and ``<take>.html``.
    """
    capture = Path(capture)
    start = time.perf_counter()
    out = config.output / capture.stem
    qa = out / "report"
    qa.mkdir(parents=True, exist_ok=True)
    markerset = load_markerset(config.markerset)
    mesh = load_mesh(config.mesh, units=config.mesh_units)
    landmarks = load_mesh_landmarks(config.landmarks, mesh)
    artist = load_artist(config.basis, mesh)
    stages = {}
    tic = time.perf_counter()
    ingested = ingest_stage(mocap.read(capture), markerset, config.ingest)
    take = complete_span(ingested.take, markerset.face_markers)
    stages["ingest"] = time.perf_counter() - tic
    tic = time.perf_counter()
    bound = bind_stage(take, markerset, mesh, landmarks, options=config.bind)
    stages["bind"] = time.perf_counter() - tic
    tic = time.perf_counter()
    retargeted = retarget_stage(take, bound, mesh, markerset, config.retarget)
    stages["retarget"] = time.perf_counter() - tic
    tic = time.perf_counter()
    bases = basis_stage(retargeted, artist, options=config.basis_options)
    stages["basis"] = time.perf_counter() - tic
    tic = time.perf_counter()
    fitted = fit_stage(take, bound, retargeted, bases, options=config.fit)
    stages["fit"] = time.perf_counter() - tic

    tic = time.perf_counter()
    files = [out / "take.c3d", out / "head_motion.npz", out / "binding.json"]
    mocap.write(take, files[0], inputs=[capture])
    save_head_motion(ingested.stabilization, files[1], inputs=[capture])
    bound.binding.save(files[2])
    timing = dict(rate=take.rate, first_frame=take.first_frame)
    for name, basis in bases.bases.items():
        weights = fitted.weights[name]
        paths = [out / f"basis-{name}.npz", out / f"weights-{name}.csv",
                 out / f"mesh-{name}.npz", out / f"face-{name}.glb"]
        save_basis(ArtistBasis(basis.names, mesh, basis.displacements), paths[0],
                   dtype="float32")
        write_weights_csv(paths[1], weights, basis.names, **timing)
        write_mesh_sequence(paths[2], mesh, basis.displacements, weights, names=basis.names,
                            **timing)
        write_gltf(paths[3], mesh, basis.displacements, basis.names, weights=weights,
                   rate=take.rate, name=f"{capture.stem}-{name}")
        files += paths
    stages["exports"] = time.perf_counter() - tic

    tic = time.perf_counter()
    face = take.select(retargeted.labels)
    neutral = bound.neutral_pose(face.positions)
    plot_gaps(ingested.cleaned, qa / "gaps.png")
    plot_head_residuals(ingested.stabilization, qa / "head_residuals.png")
    files += [qa / "gaps.png", qa / "head_residuals.png"]
    files += build_report(face, fitted.reconstructed, neutral, qa, markerset=markerset,
                          pca=bases.pca, ingest=ingested, video=config.report.video,
                          pictures={"gaps: present, missing, filled by method": qa / "gaps.png",
                                    "head-marker residuals": qa / "head_residuals.png"},
                          video_step=config.report.video_step, n_worst=config.report.n_worst,
                          exaggerate=config.report.exaggerate, name=capture.stem).values()
    stages["report"] = time.perf_counter() - tic
    metrics = {name: _finite(reconstruction_errors(face.positions, rec, neutral,
                                                   labels=face.labels, name=name).summary()
                             | {"smoothness": fitted.solutions[name].smoothness})
               for name, rec in fitted.reconstructed.items()}
    return {"status": "ok", "skipped": False, "error": None,
            "seconds": round(time.perf_counter() - start, 3),
            "stage_seconds": {k: round(v, 3) for k, v in stages.items()},
            "frames": {"first": take.first_frame, "count": take.n_frames,
                       "trimmed": ingested.take.n_frames - take.n_frames,
                       "neutral": take.first_frame + bound.frame,
                       "neutral_window": bound.window, "rate": take.rate},
            "binding_rms_mm": bound.binding.rms, "pca_components": bases.n_components,
            "qe_missing_axes": bases.qe.missing_axes.tolist(),
            "fit": {name: {"status": s.status, "message": s.message}
                    for name, s in fitted.solutions.items()},
            "metrics": metrics,
            "files": sorted(str(Path(f).relative_to(config.output)) for f in files)}


def _guarded(capture: Path, config: RunConfig) -> dict:
    """:func:`process_take` that turns an exception into a failed record."""
    start = time.perf_counter()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            record = process_take(capture, config)
        record["warnings"] = sorted({str(w.message) for w in caught})
        return record
    except Exception as exc:  # noqa: BLE001 - one take's failure must not stop the others
        expected = isinstance(exc, Mocap2MeshError)
        return {"status": "failed", "skipped": False,
                "error": str(exc) if expected else f"{type(exc).__name__}: {exc}",
                "traceback": None if expected else traceback.format_exc(),
                "seconds": round(time.perf_counter() - start, 3)}


def run_takes(config: RunConfig, *, workers: int | None = None, force: bool = False,
              progress: bool | None = None) -> RunOutcome:
    """Run every take of `config` (skipping unchanged ones) and write ``manifest.json``.

    Parameters
    ----------
    config : RunConfig
    workers : int, optional
        Takes processed in parallel (default ``config.workers``); 1 runs in this process.
    force : bool
        Re-run takes even when unchanged.
    progress : bool or None
        Show the progress bar (None: only on a terminal).

    Returns
    -------
    RunOutcome
    """
    workers = config.workers if workers is None else workers
    if workers < 1:
        raise InputError(f"workers must be at least 1, got {workers}")
    config.output.mkdir(parents=True, exist_ok=True)
    manifest_path = config.output / MANIFEST_NAME
    previous = None if force else load_manifest(manifest_path)
    inputs = {role: {"path": str(p), "sha256": sha256_path(p)}
              for role, p in config.shared_inputs.items()}
    parameters = config.parameters()
    takes, todo = {}, []
    for capture in config.captures:
        digest = sha256_path(capture)
        key = take_key(digest, inputs, parameters)
        base = {"capture": {"path": str(capture), "sha256": digest}, "key": key}
        old = reusable_record(previous, capture.stem, key, config.output)
        if old is not None:
            takes[capture.stem] = {**old, **base, "skipped": True}
        else:
            takes[capture.stem] = base
            todo.append(capture)
    with tqdm(total=len(config.captures), initial=len(config.captures) - len(todo),
              desc="takes", unit="take", disable=None if progress is None else not progress,
              file=sys.stderr) as bar:
        if workers == 1 or len(todo) <= 1:
            results = ((c, _guarded(c, config)) for c in todo)
            for capture, record in results:
                _collect(takes, capture, record, bar)
        else:
            with ProcessPoolExecutor(max_workers=min(workers, len(todo))) as pool:
                futures = {pool.submit(_guarded, c, config): c for c in todo}
                for future in as_completed(futures):
                    try:
                        record = future.result()
                    except Exception as exc:  # noqa: BLE001 - a worker died (memory, signal)
                        record = {"status": "failed", "skipped": False,
                                  "error": f"worker process failed: {type(exc).__name__}: {exc}"}
                    _collect(takes, futures[future], record, bar)
    write_manifest(manifest_path, config=config.path, versions=package_versions(),
                   parameters=parameters, inputs=inputs,
                   takes={c.stem: takes[c.stem] for c in config.captures})
    failed = sum(t["status"] == "failed" for t in takes.values())
    skipped = sum(bool(t.get("skipped")) for t in takes.values())
    return RunOutcome(manifest=manifest_path, takes=takes, n_failed=failed, n_skipped=skipped)


def _collect(takes: dict, capture: Path, record: dict, bar) -> None:
    takes[capture.stem] = {**takes[capture.stem], **record}
    if record["status"] == "failed":
        tqdm.write(f"mocap2mesh run: take {capture.stem} ({capture}) failed: {record['error']}",
                   file=sys.stderr)
    bar.update()


def run(args) -> int:
    config = load_run_config(args.config)
    outcome = run_takes(config, workers=args.workers, force=args.force)
    return 1 if outcome.n_failed else 0
