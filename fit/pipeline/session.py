"""Every take of a session through the whole chain: parallel takes, a manifest, skips.

:func:`run_takes` runs the takes of a :class:`fit.pipeline.config.RunConfig`
on an executor (:mod:`fit.pipeline.executors`: a local process pool, a Dask
cluster, or any executor; one progress bar), each committed as a unit into a folder
of its name under the output directory (:mod:`fit.pipeline.completion`), and
keeps ``manifest.json`` at the top up to date after every take
(:mod:`fit.pipeline.manifest`). A take is skipped only when its committed
folder verifies against the current capture, inputs and parameters; a failing
take is reported (stderr and manifest) and does not stop the others; a killed
run resumes with every finished take skipped. The output directory is locked
for the run and cleaned of what killed runs left (:mod:`fit.pipeline.outdir`);
local workers die with the run (:mod:`fit.pipeline.workers`). With
``[basis] scope = "session"`` the takes share one PCA/QE basis
(:mod:`fit.pipeline.session_basis`), built first; each take's warnings are
printed as it completes and recorded (:mod:`fit.pipeline.take_warnings`).
"""

from __future__ import annotations

import dataclasses
import os
import socket
import sys
import time
import traceback
import warnings
from contextlib import nullcontext
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
from fit.pipeline.executors import TaskOutcome, open_executor
from fit.pipeline.kept_takes import kept_files, take_kept
from fit.pipeline.manifest import (
    MANIFEST_NAME,
    load_manifest,
    package_versions,
    sha256_path,
    write_manifest,
)
from fit.pipeline.outdir import clean_stale, output_lock, safe_stem, take_names
from fit.pipeline.reconstruction import Reconstruction, SharedReconstruction
from fit.pipeline.session_basis import build_session_basis, session_input, uses_session_basis
from fit.pipeline.take_warnings import capture_warnings, print_warnings, replay_warnings
from fit.report.figure_queue import FigureQueue
from mocap.errors import Mocap2MeshError
from mocap.util.atomic import refuse_overwrite
from mocap.util.optional import load_numba
from mocap.util.pretouch import release_pretouch
from mocap.util.validation import as_int

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
                 provenance: Provenance | None = None,
                 figure_helpers: int | None = None, kept=None, built=None) -> dict:
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
    figure_helpers : int, optional
        Helper processes writing the weights CSVs and drawing the report's figures
        (:class:`~fit.report.figure_queue.FigureQueue`; default one per spare core);
        0 when other takes share the machine's cores.
    kept : path, optional
        Where the session basis kept this take prepared (:mod:`fit.pipeline.kept_takes`):
        read back (and removed) instead of running ingest, bind and retarget again, with
        the warnings they raised; without a readable file there, they run.
    built : SharedReconstruction, optional
        The run's reconstruction, built once for its takes (default: built here from
        `config`).
    """
    capture = Path(capture)
    name = safe_stem(capture.stem) if name is None else name
    provenance = _provenance(capture, config) if provenance is None else provenance
    start = time.perf_counter()
    stage = begin_take(config.output, name)
    try:
        with capture_warnings() as later:            # those of the exports and the report
            with capture_warnings() as caught:
                if built is None:
                    reconstruction = Reconstruction.from_config(config)
                else:
                    reconstruction = built.reconstruction
                    replay_warnings(built.warnings)
                source = capture
                if kept is not None and (found := take_kept(kept)) is not None:
                    source, raised = found
                    replay_warnings(raised)                # as its stages raised them
                result = dataclasses.replace(reconstruction.process(
                    source, session_basis=session_basis), name=name)
            stages = dict(result.stage_seconds)
            # the helpers start with the exports (a fresh interpreter's start, or a helper
            # at work, would take a core from the chain's threaded stages), write the
            # weights CSVs while this process writes the other exports and gathers the
            # report's errors and held-out fits, then draw the figures ("exports" is then
            # the binary files, "report" the rest)
            with FigureQueue(figure_helpers) as figures:
                tic = time.perf_counter()
                result.save(stage, inputs=[capture], figures=figures, wait=False)
                stages["exports"] = time.perf_counter() - tic
                tic = time.perf_counter()
                # the inputs with the digests of the take's record (read once a run)
                result.report(stage / "report", warnings=caught, figures=figures,
                              inputs={"capture": provenance.capture, **provenance.inputs})
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


@dataclass(frozen=True)
class _TakeJob:
    """One take of a run as a task of an executor: its capture, folder name and provenance."""

    capture: Path
    name: str
    provenance: Provenance
    figure_helpers: int | None = None     # of its report: 0 when takes run side by side
    kept: Path | None = None              # where the session basis kept it prepared

    @property
    def stem(self) -> str:
        """The name Dask shows the task by."""
        return self.name


def _worker() -> dict:
    """Where a take ran: host, process, and the process's peak resident memory so far (MB)."""
    try:
        import resource
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        peak_mb = round(peak / (1e6 if sys.platform == "darwin" else 1e3), 1)
    except ImportError:                     # Windows
        peak_mb = None
    return {"host": socket.gethostname(), "pid": os.getpid(), "peak_rss_mb": peak_mb}


def _guarded(capture: Path, config: RunConfig, name: str, provenance: Provenance,
             session_basis=None, figure_helpers: int | None = None, kept=None,
             built=None) -> dict:
    """:func:`process_take` that turns an exception into a failed record."""
    start = time.perf_counter()
    try:
        with capture_warnings(reemit=False) as caught:
            return process_take(capture, config, session_basis, name=name,
                                provenance=provenance, figure_helpers=figure_helpers,
                                kept=kept, built=built)
    except Exception as exc:  # noqa: BLE001 - one take's failure must not stop the others
        expected = isinstance(exc, Mocap2MeshError)
        return {"status": "failed", "skipped": False,
                "error": str(exc) if expected else f"{type(exc).__name__}: {exc}",
                "traceback": None if expected else traceback.format_exc(),
                "seconds": round(time.perf_counter() - start, 3), "warnings": caught}


def _take_task(job: _TakeJob, shared) -> dict:
    """The task an executor runs for each take: ``shared`` is ``(config, session_basis,
    built)`` (built: the :class:`SharedReconstruction`, or None).

    Returns the take's manifest record, with where it ran (``worker``).
    """
    config, session_basis, built = shared
    record = _guarded(job.capture, config, job.name, job.provenance, session_basis,
                      job.figure_helpers, job.kept, built=built)
    return {**record, "worker": _worker()}


def _failed(outcome: TaskOutcome) -> dict:
    """The record of a take whose task never returned (timeout, dead worker)."""
    return {"status": "failed", "skipped": False, "error": outcome.error,
            "traceback": outcome.traceback, "seconds": round(outcome.seconds, 3)}


def run_takes(config: RunConfig, *, executor=None, workers: int | None = None,
              scheduler: str | None = None, timeout: float | None = None,
              force: bool = False, check: bool = False,
              progress: bool | None = None) -> RunOutcome:
    """Run every take of `config` (skipping those already done) and keep ``manifest.json``.

    Parameters
    ----------
    config : RunConfig
    executor : {"local", "dask"} or executor object, optional
        Where the takes run (default ``config.executor``): see
        :func:`fit.pipeline.executors.open_executor`; any object with
        ``submit`` (a Dask client's ``get_executor()``, a process pool) is used
        as it is and left open. The session basis is built on it too.
    workers : int, optional
        Takes processed in parallel, or LocalCluster workers (default
        ``config.workers``); local with 1 and no timeout runs in this process.
    scheduler : str, optional
        Dask scheduler address (default ``config.scheduler``).
    timeout : float, optional, s
        Longest a take may run before it is stopped and recorded as failed
        (default ``config.timeout``: none).
    force : bool
        Re-run every take, done or not.
    check : bool
        Only say what would be skipped and why (``reasons``); run and write nothing.
    progress : bool or None
        Show the progress bar, with the Dask dashboard's address when there
        is one (None: only on a terminal).

    Returns
    -------
    RunOutcome

    Raises
    ------
    InputError
        `workers` < 1, the output directory lies inside an input directory or
        cannot be written, or another run holds it.
    """
    workers = config.workers if workers is None else as_int(workers, "workers", minimum=1)
    executor = config.executor if executor is None else executor
    scheduler = config.scheduler if scheduler is None else scheduler
    timeout = config.timeout if timeout is None else timeout
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
        if uses_session_basis(config):
            manifest.session_basis = (load_manifest(manifest.path) or {}).get("session_basis")
        manifest.write()
        if todo:
            pool = open_executor(executor, workers=min(workers, len(todo)), scheduler=scheduler)
            # an executor the caller built is the caller's to close
            with nullcontext(pool) if pool is executor else pool:
                _run_on(pool, todo, config, names, provenances, manifest, timeout, progress)
        clean_stale(config.output)      # the staging folder, empty once every take is done
    takes = manifest.takes
    return RunOutcome(manifest=manifest.path, takes=takes,
                      n_failed=sum(t["status"] == "failed" for t in takes.values()),
                      n_skipped=sum(bool(t.get("skipped")) for t in takes.values()),
                      reasons={n: v.reason for n, v in verdicts.items()})


def _run_on(pool, todo, config, names, provenances, manifest, timeout, progress) -> None:
    """Build the session basis (when the takes share one) and run `todo` on `pool`."""
    shared, kept = None, {}
    here = pool.runs_here(timeout)
    # the heap's pages written while the command imported (mocap.util.pretouch): kept for
    # the take when it runs in this process, given back when it runs elsewhere
    release_pretouch(keep=here)
    if here:
        # the takes' fits load numba in this process (the speed extra's kernels): loaded
        # first, it parses the basis's shapes too (mocap.mesh.mesh.load_shape_vertices)
        load_numba()
    try:                                 # once for every task, not in each
        built = SharedReconstruction.build(config)
    except Exception:  # noqa: BLE001 - then each take builds it, and fails, on its own
        built = None
    if uses_session_basis(config):
        kept = kept_files(config.output, {c: names[c] for c in todo})   # for their run
        shared, unprepared = build_session_basis(config, executor=pool, progress=progress,
                                                 keep=kept, built=built)
        manifest.session_basis = None if shared is None else shared.record()
        for capture in [c for c in todo if c.stem in unprepared]:
            todo.remove(capture)
            manifest.collect(names[capture], capture, {
                "status": "failed", "skipped": False, "error": unprepared[capture.stem]})
        manifest.write()
    # one take at a time has the spare cores for the figures; side by side, the takes have them
    helpers = None if pool.slots() == 1 else 0
    jobs = [_TakeJob(c, names[c], provenances[names[c]], helpers, kept.get(c)) for c in todo]
    with tqdm(total=len(config.captures), initial=len(config.captures) - len(jobs),
              desc="takes", unit="take", disable=None if progress is None else not progress,
              file=sys.stderr) as bar:
        if pool.dashboard_link:
            bar.set_postfix_str(f"dashboard {pool.dashboard_link}")
        for outcome in pool.map_unordered(_take_task, jobs, shared=(config, shared, built),
                                          timeout=timeout):
            record = outcome.result if outcome.ok else _failed(outcome)
            manifest.collect(outcome.job.name, outcome.job.capture, record)
            bar.update()


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
