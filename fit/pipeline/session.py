"""Every take of a session through the whole chain: parallel takes, a manifest, skips.

:func:`run_takes` runs the takes of a :class:`fit.pipeline.config.RunConfig`
on an executor (:mod:`fit.pipeline.executors`: a local process pool, a Dask
cluster, or any executor; one progress bar), each into a folder of its name
under the output directory, and keeps ``manifest.json`` at the top up to date
as each take ends (:mod:`fit.pipeline.manifest`). A take whose inputs and parameters are
unchanged since its last successful run is skipped; a failing take is
reported (stderr and manifest) and does not stop the others.
"""

from __future__ import annotations

import os
import socket
import sys
import time
import traceback
import warnings
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from fit.pipeline.config import RunConfig
from fit.pipeline.executors import TaskOutcome, open_executor
from fit.pipeline.manifest import (
    MANIFEST_NAME,
    load_manifest,
    package_versions,
    reusable_record,
    sha256_path,
    take_key,
    write_manifest,
)
from fit.pipeline.reconstruction import Reconstruction
from mocap.errors import Mocap2MeshError
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
    """

    manifest: Path
    takes: dict
    n_failed: int
    n_skipped: int


def process_take(capture, config: RunConfig) -> dict:
    """Run one take through the chain and write its folder; returns its manifest record.

    Files (relative to ``config.output``): ``<take>/`` with the exports of
    :meth:`~fit.pipeline.reconstruction.ReconstructionResult.save` and
    ``<take>/report/`` with the QA pictures, videos and ``<take>.html``.
    """
    capture = Path(capture)
    start = time.perf_counter()
    out = config.output / capture.stem
    result = Reconstruction.from_config(config).process(capture)
    stages = dict(result.stage_seconds)
    tic = time.perf_counter()
    files = result.save(out, inputs=[capture])
    stages["exports"] = time.perf_counter() - tic
    tic = time.perf_counter()
    files += result.report(out / "report")
    stages["report"] = time.perf_counter() - tic
    return {"status": "ok", "skipped": False, "error": None,
            "seconds": round(time.perf_counter() - start, 3),
            "stage_seconds": {k: round(v, 3) for k, v in stages.items()},
            **result.summary(),
            "files": sorted(str(Path(f).relative_to(config.output)) for f in files)}


def _worker() -> dict:
    """Where a take ran: host, process, and the process's peak resident memory so far (MB)."""
    try:
        import resource
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        peak_mb = round(peak / (1e6 if sys.platform == "darwin" else 1e3), 1)
    except ImportError:                     # Windows
        peak_mb = None
    return {"host": socket.gethostname(), "pid": os.getpid(), "peak_rss_mb": peak_mb}


def _guarded(capture: Path, config: RunConfig) -> dict:
    """:func:`process_take` that turns an exception into a failed record (the per-take task).

    It runs on a worker (:mod:`fit.pipeline.executors`) and returns the take's
    manifest record, with where it ran (``worker``).
    """
    start = time.perf_counter()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            record = process_take(capture, config)
        record["warnings"] = sorted({str(w.message) for w in caught})
    except Exception as exc:  # noqa: BLE001 - one take's failure must not stop the others
        expected = isinstance(exc, Mocap2MeshError)
        record = {"status": "failed", "skipped": False,
                  "error": str(exc) if expected else f"{type(exc).__name__}: {exc}",
                  "traceback": None if expected else traceback.format_exc(),
                  "seconds": round(time.perf_counter() - start, 3)}
    record["worker"] = _worker()
    return record


def _failed(outcome: TaskOutcome) -> dict:
    """The record of a take whose task never returned (timeout, dead worker)."""
    return {"status": "failed", "skipped": False, "error": outcome.error,
            "traceback": outcome.traceback, "seconds": round(outcome.seconds, 3)}


def run_takes(config: RunConfig, *, executor=None, workers: int | None = None,
              scheduler: str | None = None, timeout: float | None = None,
              force: bool = False, progress: bool | None = None) -> RunOutcome:
    """Run every take of `config` (skipping unchanged ones) and write ``manifest.json``.

    The manifest is rewritten (atomically) as each take ends, so a driver
    killed mid-session leaves a valid manifest, and a re-run skips every take
    that finished.

    Parameters
    ----------
    config : RunConfig
    executor : {"local", "dask"} or executor object, optional
        Where the takes run (default ``config.executor``): see
        :func:`fit.pipeline.executors.open_executor`; any object with
        ``submit`` (a Dask client's ``get_executor()``, a process pool) is used
        as it is and left open.
    workers : int, optional
        Takes processed in parallel, or LocalCluster workers (default
        ``config.workers``); local with 1 and no timeout runs in this process.
    scheduler : str, optional
        Dask scheduler address (default ``config.scheduler``).
    timeout : float, optional, s
        Longest a take may run before it is stopped and recorded as failed
        (default ``config.timeout``: none).
    force : bool
        Re-run takes even when unchanged.
    progress : bool or None
        Show the progress bar, with the Dask dashboard's address when there
        is one (None: only on a terminal).

    Returns
    -------
    RunOutcome
    """
    workers = config.workers if workers is None else as_int(workers, "workers", minimum=1)
    executor = config.executor if executor is None else executor
    scheduler = config.scheduler if scheduler is None else scheduler
    timeout = config.timeout if timeout is None else timeout
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
            takes[capture.stem] = {**base, "status": "pending", "skipped": False}
            todo.append(capture)

    def write():
        write_manifest(manifest_path, config=config.path, versions=package_versions(),
                       parameters=parameters, inputs=inputs,
                       takes={c.stem: takes[c.stem] for c in config.captures})

    write()
    with tqdm(total=len(config.captures), initial=len(config.captures) - len(todo),
              desc="takes", unit="take", disable=None if progress is None else not progress,
              file=sys.stderr) as bar:
        if todo:
            pool = open_executor(executor, workers=min(workers, len(todo)),
                                 scheduler=scheduler)
            # an executor the caller built is the caller's to close
            with nullcontext(pool) if pool is executor else pool:
                if pool.dashboard_link:
                    bar.set_postfix_str(f"dashboard {pool.dashboard_link}")
                for outcome in pool.map_unordered(_guarded, todo, shared=config,
                                                  timeout=timeout):
                    record = outcome.result if outcome.ok else _failed(outcome)
                    _collect(takes, outcome.job, record, bar)
                    write()
    failed = sum(t["status"] == "failed" for t in takes.values())
    skipped = sum(bool(t.get("skipped")) for t in takes.values())
    return RunOutcome(manifest=manifest_path, takes=takes, n_failed=failed, n_skipped=skipped)


def _collect(takes: dict, capture: Path, record: dict, bar) -> None:
    takes[capture.stem] = {**takes[capture.stem], **record}
    if record["status"] == "failed":
        tqdm.write(f"mocap2mesh run: take {capture.stem} ({capture}) failed: {record['error']}",
                   file=sys.stderr)
    bar.update()


