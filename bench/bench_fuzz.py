"""Fuzz every reader and loader, and read the probe's hostile files: ours against a baseline.

    python bench/bench_fuzz.py [--scale S] [--baseline REF|none]

Runs the seeded cases of tests/fuzzing.py (TEST_COUNTS x S, each in a forked
worker limited with setrlimit to its warm-up size + 256 MB) with this tree's
readers and with those of git ref REF (default ``main``, exported to a
temporary folder), and prints per reader: cases, outcomes (valid / our error /
other / hang), the worst case's peak resident memory above the worker's and
its file size, and how many cases exceed 2x their file + 4 MB. Then it reads
each hostile file of the reliability issue's probe in a fresh process (limited
to its start-up size + 2 GB, so a bomb ends in a MemoryError instead of
swapping) and prints the peak RSS and the outcome for both trees.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
import zipfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import REPO, export_tree, shared_data  # noqa: E402

CAP_BYTES = 2 << 30


def _python(tree: Path | None, code: str) -> subprocess.CompletedProcess:
    """Run `code` with the package of `tree` (None: this one) first on the path.

    It runs in the temporary folder: ``python -c`` puts its working folder first on
    the path, and this checkout must not shadow the baseline tree.
    """
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1", OPENBLAS_NUM_THREADS="1",
               MPLBACKEND="Agg")
    paths = ([str(tree)] if tree else []) + [str(REPO / "tests")]
    env["PYTHONPATH"] = os.pathsep.join(paths)
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, check=False, cwd=tempfile.gettempdir())


def fuzz(tree: Path | None, scale: float, work: Path) -> dict:
    code = textwrap.dedent(f"""
        import json, sys
        from pathlib import Path
        import fuzzing
        counts = {{k: max(1, int(v * {scale})) for k, v in fuzzing.TEST_COUNTS.items()}}
        targets = fuzzing.build_targets(Path({str(shared_data())!r}), Path({str(work)!r}),
                                        counts)
        out = fuzzing.run_targets(targets)
        print(json.dumps({{n: dict(counts=s.counts, worst=s.worst_peak,
                                    over=len(s.over_budget), seconds=s.seconds,
                                    failures=[f[2].splitlines()[0] for f in s.failures[:3]])
                          for n, s in out.items()}}))
        """)
    done = _python(tree, code)
    if done.returncode != 0:
        raise SystemExit(f"fuzz run failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _hostile_files(folder: Path) -> dict:
    """The probe's hostile inputs, written from the real data: name -> call (Python code)."""
    data = shared_data()
    files = {}
    trc = (data / "vicon-nexus" / "markers.trc").read_bytes().rstrip(b"\r\n").split(b"\n")
    last = trc[-1].split(b",", 1)
    (folder / "frame2e6.trc").write_bytes(b"\n".join(trc[:-1] + [b"2000000," + last[1]])
                                          + b"\n")
    files["TRC, last frame 2,000,000 (128 kB)"] = folder / "frame2e6.trc"
    csv = (data / "vicon-nexus" / "markers.csv").read_bytes().rstrip(b"\r\n").split(b"\r\n")
    last = csv[-1].split(b",", 1)
    (folder / "frame2e6.csv").write_bytes(b"\r\n".join(csv[:-1] + [b"2000000," + last[1]])
                                          + b"\r\n")
    files["CSV, last frame 2,000,000 (703 kB)"] = folder / "frame2e6.csv"
    head = b"Trajectories\n100\n,,a,,\nFrame,Sub Frame,X,Y,Z\n,,mm,mm,mm\n"
    rows = b"".join(b"%d,0,1,2,3\n" % i for i in range(1, 300))
    (folder / "commas.csv").write_bytes(head + rows + b"300,0,1,2,3" + b"," * 1_000_000
                                        + b"\n")
    files["CSV, a row of 1M commas (1 MB)"] = folder / "commas.csv"
    text = "{'descr': '<f8', 'fortran_order': False, 'shape': (1000000000, 3, 3), }"
    text = text.ljust(117) + "\n"
    npy = b"\x93NUMPY\x01\x00" + len(text).to_bytes(2, "little") + text.encode()
    with zipfile.ZipFile(folder / "claims.npz", "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("positions.npy", npy + b"\0" * 720)
    files["take npz, header of 1e9 frames (1 kB)"] = folder / "claims.npz"
    _python(None, "import numpy as np, mocap; mocap.write(mocap.Take(('a', 'b'), "
                  f"np.zeros((5, 2, 3)), 100.0), {str(folder / 'w0.c3d')!r})")
    buf = bytearray((folder / "w0.c3d").read_bytes())
    body = buf.find(b"LABELS") + len(b"LABELS") + 2
    buf[body + 1:body + 6] = bytes([4, 0, 255, 255, 255])
    (folder / "width0.c3d").write_bytes(buf)
    files["C3D, char parameter 0x255x255x255 (1.5 kB)"] = folder / "width0.c3d"
    calls = {name: f"mocap.read({str(path)!r})" for name, path in files.items()}
    calls["ingest --resample 1e7 (2-frame take)"] = (
        f"__import__('fit.cli.main', fromlist=['main']).main(['ingest', "
        f"{str(folder / 'w0.c3d')!r}, '-o', {str(folder / 'r.npz')!r}, '--resample', '1e7'])")
    return calls


def hostile(tree: Path | None, calls: dict) -> dict:
    """Peak RSS above start-up (MB) and outcome of each call, in a fresh, capped process."""
    out = {}
    for name, call in calls.items():
        code = textwrap.dedent(f"""
            import resource, warnings
            warnings.simplefilter("ignore")
            import mocap, fit.cli.main, fit.cli.commands.ingest, mocap.clean.ingest
            import mocap.io.c3d, mocap.io.trc, mocap.io.vicon_csv, mocap.io.take_npz
            from mocap.errors import Mocap2MeshError
            with open("/proc/self/status") as fh:
                vm = next(int(l.split()[1]) for l in fh if l.startswith("VmSize")) * 1024
            resource.setrlimit(resource.RLIMIT_AS, (vm + {CAP_BYTES}, resource.RLIM_INFINITY))
            start = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
            try:
                result = {call}
                outcome = "read" if not isinstance(result, int) else f"exit code {{result}}"
            except Mocap2MeshError as exc:
                outcome = "our error: " + str(exc).split(": ", 1)[-1][:90]
            except BaseException as exc:
                outcome = "OTHER " + type(exc).__name__ + ": " + str(exc)[:80]
            print((resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - start) / 1024)
            print(outcome)
            """)
        done = _python(tree, code)
        lines = done.stdout.strip().splitlines()
        out[name] = (float(lines[-2]), lines[-1]) if len(lines) >= 2 else \
            (float("nan"), "crashed: " + (done.stderr.strip().splitlines() or ["?"])[-1][:80])
    return out


def _table(ours: dict, base: dict | None) -> str:
    head = (f"{'reader':<11} {'cases':>6} {'valid':>6} {'error':>6} {'other':>6} {'hang':>5} "
            f"{'worst peak':>11} {'its file':>9} {'>2x+4MB':>8}")
    rows = [head]
    for label, result in (("ours", ours), ("baseline", base)):
        if result is None:
            continue
        rows.append(f"-- {label}")
        total = dict.fromkeys(("valid", "error", "other", "hang"), 0)
        for name, s in result.items():
            c = s["counts"]
            for k in total:
                total[k] += c[k]
            peak, size, _ = s["worst"]
            rows.append(f"{name:<11} {sum(c.values()):>6} {c['valid']:>6} {c['error']:>6} "
                        f"{c['other']:>6} {c['hang']:>5} {peak / 1e6:>8.1f} MB "
                        f"{size / 1e3:>6.1f} kB {s['over']:>8}")
        rows.append(f"{'all':<11} {sum(total.values()):>6} {total['valid']:>6} "
                    f"{total['error']:>6} {total['other']:>6} {total['hang']:>5}")
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=1.0, help="cases x TEST_COUNTS")
    parser.add_argument("--baseline", default="main", help="git ref, or 'none'")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        base_tree = None if args.baseline == "none" else export_tree(args.baseline, tmp / "base")
        print(f"fuzz: {args.scale:g} x tests/fuzzing.TEST_COUNTS, each case capped at its "
              "worker's warm-up size + 256 MB (setrlimit)")
        ours = fuzz(None, args.scale, tmp / "ours")
        base = fuzz(base_tree, args.scale, tmp / "base-work") if base_tree else None
        print(_table(ours, base))
        for label, result in (("ours", ours), ("baseline", base)):
            for name, s in (result or {}).items():
                for failure in s["failures"]:
                    print(f"  {label} {name}: {failure}")
        print(f"\nhostile files of the probe (fresh process, capped at start-up + "
              f"{CAP_BYTES >> 30} GB): peak RSS above start-up, MB; outcome")
        (tmp / "hostile").mkdir()
        files = _hostile_files(tmp / "hostile")
        mine = hostile(None, files)
        theirs = hostile(base_tree, files) if base_tree else {}
        for name in files:
            print(f"{name}\n  ours     {mine[name][0]:7.0f}  {mine[name][1]}")
            if theirs:
                print(f"  baseline {theirs[name][0]:7.0f}  {theirs[name][1]}")


if __name__ == "__main__":
    main()
