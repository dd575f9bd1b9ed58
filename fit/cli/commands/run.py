"""``mocap2mesh run CONFIG.toml``: every take of a session through the whole chain.

A thin layer over :func:`fit.pipeline.session.run_takes`.
"""

from __future__ import annotations

from pathlib import Path

from fit.pipeline.config import load_run_config
from fit.pipeline.executors import EXECUTORS
from fit.pipeline.session import run_takes

HELP = "run the whole chain on every take of a configuration"

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "run", help=HELP,
        description="Ingest, stabilize, bind, retarget, build the PCA and quasi-eigen bases, "
                    "fit the weights of every basis and write exports and QA reports for "
                    "every take named by CONFIG.toml; manifest.json records inputs (SHA-256), "
                    "parameters, versions and metrics, rewritten as each take ends. Each "
                    "take's folder is committed whole with a record of what made it; a take is "
                    "skipped when that record matches the capture, inputs and parameters and "
                    "every output it lists is intact, so a killed run resumes where it "
                    "stopped. Takes run in a local process pool or on a Dask cluster (pip "
                    "install 'mocap2mesh[dask]'); the exit code is 1 when any take failed.")
    p.add_argument("config", type=Path, help="run configuration (TOML)")
    p.add_argument("--executor", choices=EXECUTORS,
                   help="where the takes run: a local process pool, or a Dask cluster "
                        "(default: run.executor, else local)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="Dask scheduler address, e.g. tcp://host:8786 (default: run.scheduler,"
                        " else a LocalCluster started and stopped by this command)")
    p.add_argument("-j", "--workers", type=int, metavar="N",
                   help="parallel takes, or LocalCluster workers (default: run.workers, "
                        "else min(2, takes))")
    p.add_argument("--timeout", type=float, metavar="S",
                   help="stop a take after S seconds and record it as failed "
                        "(default: run.timeout, else no limit)")
    p.add_argument("--force", action="store_true", help="redo every take, even those done")
    p.add_argument("--check", action="store_true",
                   help="only print, per take, whether a run would skip it and why; run and "
                        "write nothing")
    p.set_defaults(run=run)


def run(args) -> int:
    config = load_run_config(args.config)
    executor = args.executor
    if args.scheduler is not None and executor is None:
        executor = "dask"
    outcome = run_takes(config, executor=executor, workers=args.workers,
                        scheduler=args.scheduler, timeout=args.timeout, force=args.force,
                        check=args.check)
    if outcome.checked:
        width = max(len(name) for name in outcome.takes)
        for name, take in outcome.takes.items():
            print(f"{'skip' if take['skipped'] else 'run '}  {name:<{width}}  {take['reason']}")
        return 0
    return 1 if outcome.n_failed else 0
