"""Every take of a session through the whole chain: parallel takes, a manifest, skips.

:func:`run_takes` runs the takes of a :class:`fit.pipeline.config.RunConfig`
in a process pool (one progress bar), each into a folder of its name under the
output directory, and writes ``manifest.json`` at the top
(:mod:`fit.pipeline.manifest`). A take whose inputs and parameters are
unchanged since its last successful run is skipped; a failing take is
reported (stderr and manifest) and does not stop the others.
"""

from __future__ import annotations

import sys
import time
import traceback
import warnings
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from fit.pipeline.config import RunConfig
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
from mocap.errors import InputError, Mocap2MeshError

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
    for message in record.get("warnings", ()):
        tqdm.write(f"mocap2mesh run: take {capture.stem}: warning: {message}", file=sys.stderr)
    bar.update()


