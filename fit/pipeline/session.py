"""Every take of a session through the whole chain: parallel takes, a manifest, skips.

:func:`run_takes` runs the takes of a :class:`fit.pipeline.config.RunConfig`
in a process pool (one progress bar), each committed as a unit into a folder
of its name under the output directory (:mod:`fit.pipeline.completion`), and
keeps ``manifest.json`` at the top up to date after every take
(:mod:`fit.pipeline.manifest`). A take is skipped only when its committed
folder verifies against the current capture, inputs and parameters; a failing
take is reported (stderr and manifest) and does not stop the others; a killed
run resumes with every finished take skipped. The output directory is locked
for the run, cleaned of what killed runs left, and the pool's workers die with
the run (:mod:`fit.pipeline.outdir`, :mod:`fit.pipeline.workers`). With
``[basis] scope = "session"`` the takes share one PCA/QE basis
(:mod:`fit.pipeline.session_basis`), built first; each take's warnings are
printed as it completes and recorded (:mod:`fit.pipeline.take_warnings`).
"""

from __future__ import annotations

import dataclasses
import sys
import time
import traceback
import warnings
from concurrent.futures import as_completed
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from fit.pipeline.completion import (
    Provenance,
    begin_take,
    commit_take,
    discard_stage,
    input_entries,
    plan_takes,
)
from fit.pipeline.config import RunConfig
from fit.pipeline.manifest import (
    MANIFEST_NAME,
    load_manifest,
    package_versions,
    sha256_path,
    write_manifest,
)
from fit.pipeline.outdir import clean_stale, output_lock, safe_stem, take_names
from fit.pipeline.reconstruction import Reconstruction
from fit.pipeline.session_basis import build_session_basis, session_input, uses_session_basis
from fit.pipeline.take_warnings import capture_warnings, print_warnings
from fit.pipeline.workers import local_pool, stop_pool
from mocap.errors import InputError, Mocap2MeshError
from mocap.util.atomic import refuse_overwrite

__all__ = ["RunOutcome", "process_take", "run_takes"]


@dataclass(frozen=True)
class RunOutcome:
    """What a run did: the manifest written and the fate of each take.

    Attributes
    ----------
    manifest : Path
    takes : dict of str to dict
        Each take's manifest record, by take name.
    n_failed, n_skipped : int
    reasons : dict of str to str
        Why each take was skipped or (re)done (:class:`~fit.pipeline.completion.Verdict`).
    checked : bool
        True for a check (``run --check``): nothing was run or written, and
        ``takes`` holds only ``{"skipped": bool, "reason": str}`` per take.
    """

    manifest: Path
    takes: dict
    n_failed: int
    n_skipped: int
    reasons: dict = field(default_factory=dict)
    checked: bool = False


def _provenance(capture: Path, config: RunConfig, inputs: dict | None = None) -> Provenance:
    inputs = input_entries(config.shared_inputs) if inputs is None else inputs
    return Provenance.of(capture, inputs, config.parameters())


def process_take(capture, config: RunConfig, session_basis=None, *, name: str | None = None,
                 provenance: Provenance | None = None) -> dict:
    """Run one take through the chain and commit its folder; returns its manifest record.

    Files (relative to ``config.output``): ``<name>/`` with the exports of
    :meth:`~fit.pipeline.reconstruction.ReconstructionResult.save`,
    ``<name>/report/`` with the QA pictures, videos and ``<name>.html``, and
    ``<name>/take-record.json`` (:func:`~fit.pipeline.completion.commit_take`).
    Nothing of the take is in ``<name>/`` until all of it is. The warnings of
    the chain are in the record (``"warnings"``) and the report.

    Parameters
    ----------
    capture : path
    config : RunConfig
    session_basis : fit.pipeline.session_basis.SessionBasis, optional
        The PCA shared by the session's takes (None: the take's own).
    name : str, optional
        The take's folder name (default: the capture's stem made safe,
        :func:`~fit.pipeline.outdir.safe_stem`).
    provenance : Provenance, optional
        What the outputs are made from (default: computed from `config`).
    """
    capture = Path(capture)
    name = safe_stem(capture.stem) if name is None else name
    provenance = _provenance(capture, config) if provenance is None else provenance
    start = time.perf_counter()
    stage = begin_take(config.output, name)
    try:
        with capture_warnings() as later:            # those of the exports and the report
            with capture_warnings() as caught:
                result = dataclasses.replace(Reconstruction.from_config(config).process(
                    capture, session_basis=session_basis), name=name)
            stages = dict(result.stage_seconds)
            tic = time.perf_counter()
            result.save(stage, inputs=[capture])
            stages["exports"] = time.perf_counter() - tic
            tic = time.perf_counter()
            result.report(stage / "report", warnings=caught,
                          inputs={"capture": capture, **config.shared_inputs})
            stages["report"] = time.perf_counter() - tic
        summary = {"status": "ok", "skipped": False, "error": None,
                   "seconds": round(time.perf_counter() - start, 3),
                   "stage_seconds": {k: round(v, 3) for k, v in stages.items()},
                   **result.summary(), "warnings": list(dict.fromkeys(caught + later))}
        record = commit_take(stage, config.output, name, provenance, summary=summary,
                             inputs=[capture, *config.shared_inputs.values()])
    except BaseException:
        discard_stage(stage)
        raise
    return _entry(record.summary, record, provenance)


def _entry(summary: dict, record, provenance: Provenance) -> dict:
    """A take's manifest record: its summary, where it came from and its files."""
    return {**summary, "capture": provenance.capture, "key": provenance.key,
            "files": sorted(f"{record.name}/{rel}" for rel in record.files)}


def _guarded(capture: Path, config: RunConfig, name: str, provenance: Provenance,
             session_basis=None) -> dict:
    """:func:`process_take` that turns an exception into a failed record."""
    start = time.perf_counter()
    try:
        with capture_warnings(reemit=False) as caught:
            return process_take(capture, config, session_basis, name=name,
                                provenance=provenance)
    except Exception as exc:  # noqa: BLE001 - one take's failure must not stop the others
        expected = isinstance(exc, Mocap2MeshError)
        return {"status": "failed", "skipped": False,
                "error": str(exc) if expected else f"{type(exc).__name__}: {exc}",
                "traceback": None if expected else traceback.format_exc(),
                "seconds": round(time.perf_counter() - start, 3), "warnings": caught}


def run_takes(config: RunConfig, *, workers: int | None = None, force: bool = False,
              check: bool = False, progress: bool | None = None) -> RunOutcome:
    """Run every take of `config` (skipping those already done) and keep ``manifest.json``.

    Parameters
    ----------
    config : RunConfig
    workers : int, optional
        Takes processed in parallel (default ``config.workers``); 1 runs in this process.
    force : bool
        Re-run every take, done or not.
    check : bool
        Only say what would be skipped and why (``reasons``); run and write nothing.
    progress : bool or None
        Show the progress bar (None: only on a terminal).

    Returns
    -------
    RunOutcome

    Raises
    ------
    InputError
        `workers` < 1, the output directory lies inside an input directory or
        cannot be written, or another run holds it.
    """
    workers = config.workers if workers is None else workers
    if workers < 1:
        raise InputError(f"workers must be at least 1, got {workers}")
    refuse_overwrite(config.output, [config.session, *config.shared_inputs.values()])
    names, renamed = take_names(config.captures)
    digests = {capture: sha256_path(capture) for capture in config.captures}
    inputs = input_entries(config.shared_inputs)
    if uses_session_basis(config):       # every take's basis depends on every capture
        inputs["session"] = session_input(digests)
    parameters = config.parameters()
    provenances = {names[c]: Provenance({"path": str(c), "sha256": digests[c]}, inputs,
                                        parameters) for c in config.captures}
    if check:
        verdicts = plan_takes(config.output, provenances, force=force)
        return RunOutcome(manifest=config.output / MANIFEST_NAME, n_failed=0,
                          takes={n: {"skipped": v.reusable, "reason": v.reason}
                                 for n, v in verdicts.items()},
                          n_skipped=sum(v.reusable for v in verdicts.values()),
                          reasons={n: v.reason for n, v in verdicts.items()}, checked=True)
    for message in renamed:
        warnings.warn(message, stacklevel=2)
    with output_lock(config.output):
        clean_stale(config.output)
        verdicts = plan_takes(config.output, provenances, force=force)
        manifest = _Manifest(config, names, provenances)
        todo = []
        for capture in config.captures:
            verdict = verdicts[names[capture]]
            if verdict.reusable:
                record = verdict.record
                manifest.takes[record.name] = {**_entry(record.summary, record,
                                                        provenances[record.name]),
                                               "skipped": True}
            else:
                todo.append(capture)
        shared = None
        if uses_session_basis(config):
            manifest.session_basis = (load_manifest(manifest.path) or {}).get("session_basis")
        if todo and uses_session_basis(config):
            shared, unprepared = build_session_basis(config, workers=workers, progress=progress)
            manifest.session_basis = None if shared is None else shared.record()
            for capture in [c for c in todo if c.stem in unprepared]:
                todo.remove(capture)
                manifest.collect(names[capture], capture, {
                    "status": "failed", "skipped": False, "error": unprepared[capture.stem]})
        manifest.write()
        with tqdm(total=len(config.captures), initial=len(config.captures) - len(todo),
                  desc="takes", unit="take", disable=None if progress is None else not progress,
                  file=sys.stderr) as bar:
            def collect(capture, record):
                manifest.collect(names[capture], capture, record)
                bar.update()

            if workers == 1 or len(todo) <= 1:
                for capture in todo:
                    collect(capture, _guarded(capture, config, names[capture],
                                              provenances[names[capture]], shared))
            else:
                _in_pool(todo, config, names, provenances, shared, min(workers, len(todo)),
                         collect)
        clean_stale(config.output)      # the staging folder, empty once every take is done
    takes = manifest.takes
    return RunOutcome(manifest=manifest.path, takes=takes,
                      n_failed=sum(t["status"] == "failed" for t in takes.values()),
                      n_skipped=sum(bool(t.get("skipped")) for t in takes.values()),
                      reasons={n: v.reason for n, v in verdicts.items()})


def _in_pool(todo, config, names, provenances, shared, workers: int, collect) -> None:
    """Run `todo` in a pool whose workers die with this process (and on any error here)."""
    pool = local_pool(workers)
    try:
        futures = {pool.submit(_guarded, c, config, names[c], provenances[names[c]], shared): c
                   for c in todo}
        for future in as_completed(futures):
            try:
                record = future.result()
            except Exception as exc:  # noqa: BLE001 - a worker died (memory, signal)
                record = {"status": "failed", "skipped": False,
                          "error": f"worker process failed: {type(exc).__name__}: {exc}"}
            collect(futures[future], record)
    except BaseException:
        stop_pool(pool)
        raise
    pool.shutdown()


class _Manifest:
    """``manifest.json`` of a run, rewritten atomically whenever a take ends."""

    def __init__(self, config: RunConfig, names: dict, provenances: dict):
        self.config, self.names = config, names
        self.path = config.output / MANIFEST_NAME
        self.versions = package_versions()
        self.inputs = next(iter(provenances.values())).inputs
        self.session_basis = None
        self.takes = {names[c]: {"status": "pending", "skipped": False, "error": None,
                                 "capture": provenances[names[c]].capture,
                                 "key": provenances[names[c]].key}
                      for c in config.captures}

    def collect(self, name: str, capture: Path, record: dict) -> None:
        self.takes[name] = {**self.takes[name], **record}
        print_warnings(name, record.get("warnings", ()))
        if record["status"] == "failed":
            tqdm.write(f"mocap2mesh run: take {name} ({capture}) failed: {record['error']}",
                       file=sys.stderr)
        self.write()

    def write(self) -> None:
        write_manifest(self.path, config=self.config.path, versions=self.versions,
                       parameters=self.config.parameters(), inputs=self.inputs,
                       takes=self.takes, session_basis=self.session_basis)
