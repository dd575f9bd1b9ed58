"""Kill ``mocap2mesh run`` (SIGKILL) at several points and re-run it: redone, skipped, verified.

    python bench/bench_resume.py [--takes N] [--baseline REF|none]

A demo session of N takes (default 4, 2 s each, no video) runs with 2 workers.
For each kill point the output folder starts empty, the run is killed when the
point is reached (the parent process only: its workers must die by
themselves), then run again to the end. Printed per kill point: the takes
complete at the kill, what the re-run redid and skipped, whether every output
the manifest lists loads (and nothing unlisted or temporary is left), and the
workers still alive 10 s after the kill (then killed, so that they cannot write
into the re-run). Then the issue's stale case: run A
(low-pass 15 Hz) completes, run B (10 Hz) is killed after replacing a take,
run A again: the takes whose files come from B must be redone. With a
baseline ref (default ``main``, exported to a temporary folder) its run is
measured the same way, side by side.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from _common import export_tree  # noqa: E402
from resume import (  # noqa: E402
    finish,
    kill_when,
    make_session,
    reported,
    staged_files,
    start_run,
    verify_outputs,
    write_config,
)

#: Kill points: (label, condition on the output folder, for our tree and the baseline's).
POINTS = [
    ("first output of a take written", lambda out: staged_files(out) > 0 or _any_file(out)),
    ("one take complete", lambda out: len(reported(out)) >= 1),
    ("two takes complete", lambda out: len(reported(out)) >= 2),
    ("all but one take complete", None),          # set from the number of takes
]


def _any_file(out: Path) -> bool:
    return out.is_dir() and any(p.is_file() and p.parent != out for p in out.rglob("*"))


def _end(orphans) -> None:
    """Kill the orphans counted (the baseline's), so that they cannot write into the re-run."""
    for pid in orphans:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def _manifest(out: Path) -> dict:
    return json.loads((out / "manifest.json").read_text(encoding="utf-8"))["takes"]


def _verified(out: Path) -> str:
    try:
        checked = verify_outputs(out)
    except Exception as exc:  # noqa: BLE001 - reported in the table
        return f"NO: {type(exc).__name__}: {str(exc)[:60]}"
    problems = checked["unlisted"] + checked["leftovers"]
    return f"{checked['outputs']} load" + (f", {len(problems)} stale/unlisted" if problems
                                           else ", nothing else left")


def kill_and_resume(config: Path, out: Path, condition, tree) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    killed, workers, orphans, _ = kill_when(start_run(config, tree=tree), out, condition)
    _end(orphans)
    at_kill = sorted(reported(out))
    code = finish(start_run(config, tree=tree))
    takes = _manifest(out)
    return {"killed": killed, "complete": at_kill, "workers": len(workers),
            "orphans": len(orphans), "exit": code,
            "redone": sorted(n for n, t in takes.items() if not t.get("skipped")),
            "skipped": sorted(n for n, t in takes.items() if t.get("skipped")),
            "verified": _verified(out)}


def stale_case(root: Path, out: Path, tree) -> dict:
    """Run A completes; run B (other parameters) is killed after a take is rewritten; A again."""
    shutil.rmtree(out, ignore_errors=True)
    config_a = write_config(root, lowpass=15.0)
    config_b = write_config(root, lowpass=10.0, path="run-b.toml")
    assert finish(start_run(config_a, tree=tree)) == 0
    html = {p: p.stat().st_mtime_ns for p in out.glob("*/report/*.html")}

    def rewritten(o):
        return any(p.is_file() and p.stat().st_mtime_ns != t for p, t in html.items()) or \
            any(not p.exists() for p in html)

    _end(kill_when(start_run(config_b, tree=tree), out, rewritten)[2])
    from_b = sorted(p.parent.parent.name for p, t in html.items()
                    if p.is_file() and p.stat().st_mtime_ns != t)
    code = finish(start_run(config_a, tree=tree))
    takes = _manifest(out)
    return {"from_b": from_b, "exit": code,
            "redone": sorted(n for n, t in takes.items() if not t.get("skipped")),
            "skipped": sorted(n for n, t in takes.items() if t.get("skipped")),
            "verified": _verified(out)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--takes", type=int, default=4)
    parser.add_argument("--baseline", default="main", help="git ref, or 'none'")
    args = parser.parse_args()
    POINTS[-1] = ("all but one take complete",
                  lambda out: len(reported(out)) >= args.takes - 1)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        trees = {"ours": None}
        if args.baseline != "none":
            trees["baseline"] = export_tree(args.baseline, tmp / "base")
        config = make_session(tmp / "s", args.takes)
        out = tmp / "s" / "results"
        print(f"{args.takes} takes of 2 s, 2 workers; per kill point: takes complete at the "
              "kill -> the re-run's redone / skipped takes, outputs checked, workers alive "
              "10 s after the kill")
        for label, condition in POINTS:
            for name, tree in trees.items():
                r = kill_and_resume(config, out, condition, tree)
                print(f"{label:<32} {name:<8} complete at kill {len(r['complete'])}  -> "
                      f"redone {len(r['redone'])}, skipped {len(r['skipped'])} "
                      f"(exit {r['exit']}); {r['verified']}; orphans "
                      f"{r['orphans']} of {r['workers']} workers"
                      + ("" if r["killed"] else "  [run ended before the point]"))
        print("\nstale case: A (15 Hz) done, B (10 Hz) killed after rewriting a take, A again")
        for name, tree in trees.items():
            r = stale_case(tmp / "s", out, tree)
            print(f"  {name:<8} takes with B's files {r['from_b']} -> A redid {r['redone']}, "
                  f"skipped {r['skipped']} (exit {r['exit']}); {r['verified']}")


if __name__ == "__main__":
    main()
