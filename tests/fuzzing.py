"""Seeded fuzzing of every reader and configuration loader, each case under a memory limit.

Used by ``tests/test_fuzz.py`` (in ``make test``) and ``bench/bench_fuzz.py`` (the
figures). A *target* is a reader, the seed files it starts from (derived from
the real data or written by our writers) and a mutator; its cases run in a
forked worker whose address space is limited with ``resource.setrlimit`` to
what it had after reading one seed plus :data:`HEADROOM_BYTES`, with a timer
per case. Each case ends in one of:

- ``valid``: the reader returned;
- ``error``: it raised a :class:`~mocap.errors.Mocap2MeshError`;
- ``other``: anything else (a ``MemoryError`` under the limit, a bare
  ``ValueError``, a numpy ``RuntimeWarning``): a bug;
- ``hang``: it ran past :data:`CASE_SECONDS`.

The worker also measures each case's peak resident memory above what it held
before the case (``VmHWM`` reset through ``/proc/self/clear_refs``).
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import multiprocessing
import os
import re
import resource
import signal
import time
import traceback
import warnings
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from mocap.errors import Mocap2MeshError

#: Address space a case may add to what the worker holds after its warm-up read.
HEADROOM_BYTES = 256 << 20
#: A case running longer than this is a hang.
CASE_SECONDS = 10.0
OUTCOMES = ("valid", "error", "other", "hang")


@dataclass
class Target:
    """A reader under fuzz.

    Attributes
    ----------
    name : str
    suffix : str
        Extension of the case file.
    read : callable
        ``read(path)``: the reader.
    seeds : list of bytes
    mutate : callable
        ``mutate(seed, index, rng) -> bytes``.
    n_cases : int
    folder : Path
        Where the case file is written (a run configuration's relative paths
        resolve there).
    """

    name: str
    suffix: str
    read: Callable
    seeds: list
    mutate: Callable
    n_cases: int
    folder: Path = None


@dataclass
class Summary:
    """The outcomes of one target's cases."""

    name: str
    counts: dict = field(default_factory=lambda: dict.fromkeys(OUTCOMES, 0))
    failures: list = field(default_factory=list)      # (case, outcome, message)
    worst_peak: tuple = (0, 0, -1)                    # (peak bytes, file bytes, case)
    over_budget: list = field(default_factory=list)   # (case, peak, file bytes)
    seconds: float = 0.0


# ----------------------------------------------------------------- mutations

def flip_bytes(buf: bytes, rng, lo: int = 0, hi: int | None = None) -> bytes:
    """1-8 random bytes of ``buf[lo:hi]`` set to random values."""
    hi = len(buf) if hi is None else hi
    if hi <= lo:
        return buf
    out = np.frombuffer(buf, dtype=np.uint8).copy()
    n = int(rng.integers(1, 9))
    out[rng.integers(lo, hi, size=n)] = rng.integers(0, 256, size=n)
    return out.tobytes()


def truncate(buf: bytes, rng) -> bytes:
    return buf[:int(rng.integers(0, len(buf) + 1))]


#: Cells that have broken text readers: quotes, huge and special numbers, NUL,
#: other encodings, separators in bulk, dates.
TEXT_TOKENS = (b'"', b'"1', b"'", b"1e999", b"-1e999", b"1e308", b"99999999999999999999",
               b"9223372036854775808", b"2000000", b"100000000", b"-1", b"0", b"nan", b"NaN",
               b"inf", b"NA", b"True", b"0x10", b"1_000", b"\x00", b"\xff\xfe", b"\xe9",
               b"\r", b"\n", b"\n\n", b"\t", b",", b" ", b"", b"$\\frac{a}{$", b"..",
               b"../../etc/passwd", b"1.5", b"-0", b"1e-320", b"#", b"2024-01-01")


def _cells(line: bytes, sep: bytes) -> list:
    return (line.split(sep) if sep else line.split()) or [b""]


def text_mutation(buf: bytes, rng, *, sep: bytes = b",", tokens=TEXT_TOKENS) -> bytes:
    """1-3 edits of a text file: cells replaced, numbers scaled, lines cut or
    repeated, runs of separators, tokens inserted, bytes flipped, truncation."""
    for _ in range(int(rng.integers(1, 4))):
        lines = buf.split(b"\n")
        kind = int(rng.integers(0, 9))
        i = int(rng.integers(0, len(lines)))
        if kind == 0 or kind == 1:                      # a cell replaced or scaled
            cells = _cells(lines[i], sep)
            j = int(rng.integers(0, len(cells)))
            if kind == 0:
                cells[j] = tokens[int(rng.integers(0, len(tokens)))]
            else:
                try:
                    value = float(cells[j]) * 10.0 ** int(rng.integers(1, 25))
                    cells[j] = repr(-value if rng.random() < 0.3 else value).encode()
                except ValueError:
                    cells[j] = b"1" + b"0" * int(rng.integers(1, 25))
            lines[i] = (sep or b" ").join(cells)
        elif kind == 2:                                 # a line removed
            del lines[i]
        elif kind == 3:                                 # a line repeated
            lines[i:i] = [lines[i]] * int(rng.integers(1, 50))
        elif kind == 4:                                 # a run of separators or blanks
            run = (sep or b" ") * int(rng.integers(1, 20000))
            lines[i] = lines[i] + run
        elif kind == 5:                                 # a token inserted anywhere
            at = int(rng.integers(0, len(buf) + 1))
            token = tokens[int(rng.integers(0, len(tokens)))]
            buf = buf[:at] + token + buf[at:]
            continue
        elif kind == 6:
            buf = flip_bytes(buf, rng)
            continue
        elif kind == 7:
            buf = truncate(buf, rng)
            continue
        else:                                           # two lines swapped
            k = int(rng.integers(0, len(lines)))
            lines[i], lines[k] = lines[k], lines[i]
        buf = b"\n".join(lines)
    return buf


#: TOML values of every type, and hostile ones.
TOML_VALUES = ("[]", "{}", '""', '"x"', "0", "-1", "3", "9223372036854775807", "1e308",
               "inf", "nan", "-inf", "true", "false", "[1, 2]", '["a", 1]', "[[1], [2]]",
               "{ a = 1 }", "{ vertex = 1 }", '{ face = 0, bary = [0.2, 0.3, 0.5] }',
               '{ face = 0, bary = [1e308, -1e308, 1] }', '"$\\\\frac{a}{$"',
               '"../../etc/x"', '"\\u0000"', '"a\\nb"', "1979-05-27", "[" * 40 + "]" * 40,
               '"' + "x" * 300 + '"', '["root-1", "root-2"]', "0.5")
_ASSIGN = re.compile(rb"^(\s*)([^=\[#]+?)\s*=\s*(.+)$")


def toml_mutation(buf: bytes, rng, *, keys=()) -> bytes:
    """A value replaced by one of another type, a key added or removed, a table
    header moved, or a text edit."""
    lines = buf.split(b"\n")
    kind = int(rng.integers(0, 6))
    value = TOML_VALUES[int(rng.integers(0, len(TOML_VALUES)))].encode()
    assigned = [i for i, line in enumerate(lines) if _ASSIGN.match(line)]
    if kind <= 1 and assigned:                          # a value of another type
        i = assigned[int(rng.integers(0, len(assigned)))]
        m = _ASSIGN.match(lines[i])
        lines[i] = m[1] + m[2] + b" = " + value
    elif kind == 2 and keys:                            # a known key, at the top
        key = keys[int(rng.integers(0, len(keys)))].encode()
        lines.insert(0, key + b" = " + value)
    elif kind == 3 and assigned:                        # a key removed
        del lines[assigned[int(rng.integers(0, len(assigned)))]]
    elif kind == 4:                                     # a table header inserted
        table = (keys[int(rng.integers(0, len(keys)))] if keys else "x").encode()
        lines.insert(int(rng.integers(0, len(lines) + 1)), b"[" + table + b"]")
    else:
        return text_mutation(buf, rng, sep=b"")
    return b"\n".join(lines)


JSON_VALUES = ([], {}, "", "x", 0, -1, 1e30, -1e30, 2 ** 70, 1.5, True, None, [1, 2],
               [[1, 2, 3]], ["a"], {"a": 1}, [0.1, 0.2, 0.7] * 3, list(range(9)))


def _json_paths(doc, prefix=()):
    yield prefix
    if isinstance(doc, dict):
        for key, value in doc.items():
            yield from _json_paths(value, prefix + (key,))
    elif isinstance(doc, list) and doc:
        for k in {0, len(doc) - 1}:
            yield from _json_paths(doc[k], prefix + (k,))


def json_mutation(buf: bytes, rng) -> bytes:
    """A value of the document replaced by one of another type, or a text edit."""
    if rng.random() < 0.3:
        if rng.random() < 0.2:
            depth = int(rng.integers(1, 200000))
            return b"[" * depth + b"]" * depth
        return text_mutation(buf, rng, sep=b",")
    doc = json.loads(buf)
    paths = [p for p in _json_paths(doc) if p]
    path = paths[int(rng.integers(0, len(paths)))]
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    if rng.random() < 0.15 and isinstance(parent, dict):
        del parent[path[-1]]
    else:
        parent[path[-1]] = JSON_VALUES[int(rng.integers(0, len(JSON_VALUES)))]
    return json.dumps(doc).encode()


_NPY_DTYPES = ("<f8", "<f4", ">f8", "<i8", "|b1", "<U8", "<U100000000", "|V100000000",
               "<c16", "|O", "<f8")


def npz_mutation(buf: bytes, rng) -> bytes:
    """An archive rebuilt with one member's header lying (shape, dtype, order),
    its meta JSON changed, a member dropped, truncated or renamed; or bytes flipped."""
    if rng.random() < 0.25:
        return flip_bytes(buf, rng) if rng.random() < 0.6 else truncate(buf, rng)
    with zipfile.ZipFile(io.BytesIO(buf)) as archive:
        members = {info.filename: archive.read(info) for info in archive.infolist()}
    names = sorted(members)
    name = names[int(rng.integers(0, len(names)))]
    array = np.lib.format.read_array(io.BytesIO(members[name]), allow_pickle=False)
    kind = int(rng.integers(0, 6))
    if kind <= 1:                                       # the header lies
        shape = list(array.shape) or [1]
        k = int(rng.integers(0, len(shape)))
        shape[k] = int(shape[k] * 10 ** int(rng.integers(1, 12))) + int(rng.integers(0, 3))
        if rng.random() < 0.3:
            shape.append(int(rng.integers(1, 10 ** 6)))
        dtype = _NPY_DTYPES[int(rng.integers(0, len(_NPY_DTYPES)))]
        header = {"descr": dtype, "fortran_order": bool(rng.random() < 0.2),
                  "shape": tuple(shape)}
        out = io.BytesIO()
        np.lib.format.write_array_header_1_0(out, header)
        data = array.tobytes()
        members[name] = out.getvalue() + data[:int(rng.integers(0, len(data) + 1))]
    elif kind == 2 and name == "meta.npy":              # meta: other JSON
        doc = json.loads(str(array))
        doc = json.loads(json_mutation(json.dumps(doc).encode(), rng)) \
            if rng.random() < 0.8 else JSON_VALUES[int(rng.integers(0, len(JSON_VALUES)))]
        out = io.BytesIO()
        np.save(out, np.array(json.dumps(doc)))
        members[name] = out.getvalue()
    elif kind == 2 or kind == 3:                        # an array of another shape or type
        other = [np.zeros((0, 3)), np.array("x"), np.ones(5), np.arange(7.0).reshape(7, 1, 1),
                 np.array([True]), np.full((2, 4, 3), np.nan)]
        out = io.BytesIO()
        np.save(out, other[int(rng.integers(0, len(other)))])
        members[name] = out.getvalue()
    elif kind == 4:
        del members[name]
    else:
        data = members.pop(name)
        members[name.replace(".npy", ".bin") if rng.random() < 0.5 else name] = \
            data[:int(rng.integers(0, len(data) + 1))]
    method = zipfile.ZIP_DEFLATED if rng.random() < 0.5 else zipfile.ZIP_STORED
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", method) as archive:
        for key, value in members.items():
            archive.writestr(key, value)
    return out.getvalue()


def ply_mutation(buf: bytes, rng) -> bytes:
    """An element count or property type changed in the header, or bytes of the body."""
    end = buf.find(b"end_header") + len(b"end_header\n")
    if rng.random() < 0.6:
        header = buf[:end].split(b"\n")
        i = int(rng.integers(0, len(header)))
        words = header[i].split(b" ")
        if words[0] == b"element" and len(words) == 3:
            words[2] = str(int(words[2]) * 10 ** int(rng.integers(1, 10))
                           + int(rng.integers(0, 3))).encode()
        elif words[0] == b"property":
            words[1] = [b"char", b"uchar", b"int", b"double", b"list", b"float128"][
                int(rng.integers(0, 6))]
        else:
            return text_mutation(buf, rng, sep=b" ")
        header[i] = b" ".join(words)
        return b"\n".join(header) + buf[end:]
    return flip_bytes(buf, rng, end) if rng.random() < 0.7 else truncate(buf, rng)


# ------------------------------------------------------------------ the worker

def _status_kb(field_name: str) -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(field_name):
                return int(line.split()[1])
    return 0


def _reset_peak() -> None:
    with open("/proc/self/clear_refs", "w") as fh:
        fh.write("5")


class _Hang(Exception):
    pass


def _on_alarm(signum, frame):
    raise _Hang


def _run_target(target: Target, conn, progress) -> None:
    """In the forked worker: every case of `target`; sends a Summary."""
    path = target.folder / f"fuzz{target.suffix}"
    summary = Summary(target.name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        path.write_bytes(target.seeds[0])
        target.read(path)                       # warm-up: imports, caches
    vm = _status_kb("VmSize") * 1024
    resource.setrlimit(resource.RLIMIT_AS, (vm + HEADROOM_BYTES, resource.RLIM_INFINITY))
    signal.signal(signal.SIGALRM, _on_alarm)
    start = time.perf_counter()
    for case in range(target.n_cases):
        progress.value = case
        rng = np.random.default_rng([case, sum(target.name.encode())])
        seed = target.seeds[case % len(target.seeds)]
        try:
            data = target.mutate(seed, case, rng)
        except (ValueError, KeyError, IndexError, RecursionError):  # a mutation that
            data = flip_bytes(seed, rng)                          # does not apply here
        path.write_bytes(data)
        _reset_peak()
        before = _status_kb("VmRSS")
        outcome, message = "valid", ""
        signal.setitimer(signal.ITIMER_REAL, CASE_SECONDS)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)
                warnings.simplefilter("error", RuntimeWarning)
                target.read(path)
        except Mocap2MeshError:
            outcome = "error"
        except _Hang:
            outcome, message = "hang", f"over {CASE_SECONDS:g} s"
        except BaseException as exc:  # noqa: BLE001 - the point of fuzzing
            outcome = "other"
            message = f"{type(exc).__name__}: {str(exc)[:300]}\n" + \
                "".join(traceback.format_tb(exc.__traceback__)[-3:])
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
        peak = max(0, _status_kb("VmHWM") - before) * 1024
        summary.counts[outcome] += 1
        if outcome in ("other", "hang") and len(summary.failures) < 20:
            summary.failures.append((case, outcome, message))
        if peak > summary.worst_peak[0]:
            summary.worst_peak = (peak, len(data), case)
        if peak > 2 * len(data) + (4 << 20):
            summary.over_budget.append((case, peak, len(data)))
    summary.seconds = time.perf_counter() - start
    conn.send(summary)


def run_targets(targets, *, processes: int = 2, timeout_s: float = 900.0) -> dict:
    """Run every target in its own forked, memory-limited worker, `processes` at a time.

    Returns
    -------
    dict of str to Summary
        A worker that died or overran `timeout_s` gives a Summary whose
        failures name the case it was on.
    """
    ctx = multiprocessing.get_context("fork")
    pending, running, done = list(targets), [], {}
    while pending or running:
        while pending and len(running) < processes:
            target = pending.pop(0)
            parent, child = ctx.Pipe(duplex=False)
            progress = ctx.Value("l", -1)
            worker = ctx.Process(target=_run_target, args=(target, child, progress),
                                 daemon=True)
            worker.start()
            child.close()
            running.append((target, worker, parent, progress, time.monotonic()))
        time.sleep(0.05)
        for item in list(running):
            target, worker, parent, progress, started = item
            summary = None
            if parent.poll():
                try:
                    summary = parent.recv()
                except EOFError:         # the worker died without a word
                    pass
            elif worker.is_alive() and time.monotonic() - started < timeout_s:
                continue
            if summary is not None:
                done[target.name] = summary
            else:
                worker.kill()
                lost = Summary(target.name)
                how = "hang" if worker.is_alive() or worker.exitcode == -9 else "other"
                lost.counts[how] = 1
                lost.failures.append((progress.value, how,
                                      f"worker ended (exit code {worker.exitcode}) at this case"))
                done[target.name] = lost
            worker.join(timeout=10)
            running.remove(item)
    return done


def format_table(summaries: dict) -> str:
    """One line per target: cases, outcomes, worst peak, time."""
    rows = [f"{'reader':<12} {'cases':>6} {'valid':>6} {'error':>6} {'other':>6} {'hang':>5} "
            f"{'worst peak':>11} {'its file':>9} {'>2x+4MB':>8} {'s':>6}"]
    for name, s in summaries.items():
        peak, size, _ = s.worst_peak
        rows.append(f"{name:<12} {sum(s.counts.values()):>6} {s.counts['valid']:>6} "
                    f"{s.counts['error']:>6} {s.counts['other']:>6} {s.counts['hang']:>5} "
                    f"{peak / 1e6:>8.1f} MB {size / 1e3:>6.0f} kB {len(s.over_budget):>8} "
                    f"{s.seconds:>6.1f}")
    return "\n".join(rows)


# -------------------------------------------------------------------- targets

def _c3d_target(shared_data: Path, folder: Path, n_cases: int) -> Target:
    from mocap import Take
    from mocap.io.c3d import read_c3d, write_c3d
    from mocap.take import Analog

    names = ["c3d-samples/sample_16/basketball.c3d", "c3d-samples/sample_02/pc_int.c3d",
             "c3d-samples/sample_02/dec_real.c3d", "c3d-samples/sample_02/sgi_int.c3d"]
    seeds = [(shared_data / n).read_bytes() for n in names]
    rng = np.random.default_rng(0)
    positions = rng.uniform(-500, 500, size=(40, 4, 3))
    positions[5:9, 2] = np.nan
    analog = Analog(rng.normal(size=(80, 3)), 200.0, ("a", "b", "c"), ("V", "V", "V"))
    write_c3d(Take(("m1", "m2", "m3", "m4"), positions, 100.0, analog=analog),
              folder / "ours.c3d")
    seeds.append((folder / "ours.c3d").read_bytes())
    offsets = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for k, seed in enumerate(seeds):
            (folder / "seed.c3d").write_bytes(seed)
            offsets.append(read_c3d(folder / "seed.c3d").source.extra["data_offset"])

    def mutate(seed, case, rng):
        k = case % len(seeds)
        start = (seed[0] - 1) * 512
        kind = (case // len(seeds)) % 6
        if kind == 0:
            return flip_bytes(seed, rng, 0, 512)
        if kind == 1:
            return flip_bytes(seed, rng, start, offsets[k])
        if kind == 2:
            return flip_bytes(seed, rng, offsets[k])
        if kind == 3:
            return truncate(seed, rng)
        if kind == 4:                       # a parameter's dimensions claim much more
            out = bytearray(seed)
            at = int(rng.integers(start + 4, offsets[k] - 8))
            out[at:at + 4] = bytes([int(rng.integers(0, 8))]) + bytes(
                rng.choice([0, 1, 255], size=3).tolist())
            return bytes(out)
        return flip_bytes(seed, rng)

    return Target("c3d", ".c3d", read_c3d, seeds, mutate, n_cases, folder)


def _head_lines(path: Path, n: int) -> bytes:
    with open(path, "rb") as fh:
        return b"".join(fh.readline() for _ in range(n))


def _small_take(shared_data: Path):
    """20 frames of the real facial capture, with its gaps."""
    import mocap

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        take = mocap.read(shared_data / "captures" / "facial-sing.c3d")
    return take.replace(positions=take.positions[100:120], filled=take.filled[100:120],
                        analog=None)


def _table_target(kind: str, shared_data: Path, folder: Path, n_cases: int) -> Target:
    import mocap
    from mocap.io.trc import read_trc
    from mocap.io.vicon_csv import read_vicon_csv

    source = shared_data / "vicon-nexus" / f"markers.{kind}"
    seeds = [_head_lines(source, 5 + 30 if kind == "csv" else 7 + 30)]
    take = _small_take(shared_data)
    mocap.write(take, folder / f"ours.{kind}")
    seeds.append((folder / f"ours.{kind}").read_bytes())
    sep = b"," if kind == "csv" else b"\t"

    def mutate(seed, case, rng):
        return text_mutation(seed, rng, sep=b"," if case % 2 == 0 else sep)

    reader = read_vicon_csv if kind == "csv" else read_trc
    return Target(kind, f".{kind}", reader, seeds, mutate, n_cases, folder)


def _mesh_patch(shared_data: Path, n_vertices: int = 400):
    """The first vertices of the ICT face and the polygons that use only them."""
    lines = (shared_data / "ict-face" / "generic_neutral_mesh.obj").read_bytes().splitlines()
    vertices = [line for line in lines if line.startswith(b"v ")][:n_vertices]
    faces = []
    for line in lines:
        if line.startswith(b"f "):
            ids = [int(tok.split(b"/")[0]) for tok in line.split()[1:]]
            if max(ids) <= n_vertices:
                faces.append(line)
    return vertices, faces


def _obj_target(shared_data: Path, folder: Path, n_cases: int) -> Target:
    from mocap.mesh.mesh import load_mesh

    vertices, faces = _mesh_patch(shared_data)
    plain = b"\n".join(vertices + faces) + b"\n"
    slashed = b"\n".join(vertices + [b"vt 0.5 0.5"] + [
        b"f " + b" ".join(tok + b"/1" for tok in f.split()[1:]) for f in faces]) + b"\n"
    relative = b"\n".join(vertices + [b"f -1 -2 -3", b"f\t1\t2\t3"]) + b"\n"

    def mutate(seed, case, rng):
        return text_mutation(seed, rng, sep=b" ")

    return Target("obj", ".obj", load_mesh, [plain, slashed, relative], mutate, n_cases, folder)


def _ply_target(shared_data: Path, folder: Path, n_cases: int) -> Target:
    import trimesh

    from mocap.mesh.mesh import load_mesh

    vertices, faces = _mesh_patch(shared_data, 200)
    v = np.array([line.split()[1:4] for line in vertices], dtype=float)
    f = [[int(t.split(b"/")[0]) - 1 for t in line.split()[1:]] for line in faces]
    tris = np.array([[p[0], p[k], p[k + 1]] for p in f for k in range(1, len(p) - 1)])
    mesh = trimesh.Trimesh(v, tris, process=False)
    seeds = [trimesh.exchange.ply.export_ply(mesh, encoding=e) for e in ("ascii", "binary")]
    return Target("ply", ".ply", load_mesh, seeds, lambda s, c, r: ply_mutation(s, r),
                  n_cases, folder)


def _reproducible_zip(data: bytes) -> bytes:
    """An archive with its members' times fixed, so that the cases made from it are the same
    on every machine and at every time (numpy stamps members with the time of writing)."""
    out = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(data)) as source, zipfile.ZipFile(out, "w") as target:
        for info in source.infolist():
            fixed = zipfile.ZipInfo(info.filename, date_time=(1980, 1, 1, 0, 0, 0))
            fixed.compress_type = info.compress_type
            target.writestr(fixed, source.read(info))
    return out.getvalue()


def _npz_target(shared_data: Path, folder: Path, n_cases: int) -> Target:
    import mocap
    from mocap.io.take_npz import read_take_npz

    take = _small_take(shared_data)
    # paths as relative names: the archives hold their source's path
    take = take.replace(source=dataclasses.replace(take.source, path="facial-sing.c3d"))
    mocap.write(take, folder / "plain.npz")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        trial = mocap.read(shared_data / "vicon-nexus" / "markers.c3d")
    trial = trial.replace(positions=trial.positions[:10], filled=trial.filled[:10],
                          analog=type(trial.analog)(trial.analog.values[:100],
                                                    trial.analog.rate, trial.analog.labels,
                                                    trial.analog.units),
                          source=dataclasses.replace(trial.source, path="markers.c3d"))
    mocap.write(trial, folder / "analog.npz")
    seeds = [_reproducible_zip((folder / n).read_bytes()) for n in ("plain.npz", "analog.npz")]
    return Target("take-npz", ".npz", read_take_npz, seeds,
                  lambda s, c, r: npz_mutation(s, r), n_cases, folder)


def _toml_target(name, read, seeds, keys, folder, n_cases) -> Target:
    return Target(name, ".toml", read, seeds,
                  lambda s, c, r: toml_mutation(s, r, keys=keys), n_cases, folder)


def _binding_target(folder: Path, n_cases: int) -> Target:
    from mocap.bind import Binding, load_binding

    rng = np.random.default_rng(1)
    m = 6
    bary = rng.dirichlet(np.ones(3), size=m)
    binding = Binding(labels=tuple(f"m{i}" for i in range(m)), scale=0.1,
                      rotation=np.eye(3), translation=np.array([1.0, 2.0, 3.0]),
                      face_ids=np.arange(m), vertex_ids=np.arange(3 * m).reshape(m, 3),
                      barycentric=bary, distances=rng.uniform(0, 2, m), rms=1.0,
                      skin_offset=2.0, n_landmarks=5, n_iterations=12, converged=True,
                      message="converged")
    binding.save(folder / "seed.json")
    return Target("binding", ".json", load_binding, [(folder / "seed.json").read_bytes()],
                  lambda s, c, r: json_mutation(s, r), n_cases, folder)


def _run_config_target(folder: Path, n_cases: int) -> Target:
    from fit.demo import demo_config_toml, make_demo_session
    from fit.pipeline.config import load_run_config

    make_demo_session(folder / "session", seconds=0.5)
    text = demo_config_toml().encode()
    keys = ("inputs", "output", "ingest", "bind", "retarget", "basis", "fit", "report",
            "captures", "session", "directory", "workers", "smoothness", "space")
    return _toml_target("run-config", load_run_config, [text], keys, folder, n_cases)


def build_targets(shared_data: Path, root: Path, counts: dict) -> list:
    """Every reader and loader as a Target, with its number of cases from `counts`."""
    from helpers import (
        FACIAL_SING_MARKERSET_TOML,
        ICT_LANDMARKS_TOML,
        ICT_LAYOUT_TOML,
        ICT_MARKERSET_TOML,
    )

    from mocap.markerset import load_markerset
    from mocap.mesh.landmarks import load_mesh_landmarks
    from mocap.mesh.layout import load_marker_layout
    from mocap.mesh.mesh import load_mesh

    def folder(name):
        path = root / name
        path.mkdir(parents=True, exist_ok=True)
        return path

    ict = load_mesh(shared_data / "ict-face" / "generic_neutral_mesh.obj", units="cm")
    markerset_seeds = [ICT_MARKERSET_TOML.read_bytes(), FACIAL_SING_MARKERSET_TOML.read_bytes()]
    targets = [
        _c3d_target(shared_data, folder("c3d"), counts["c3d"]),
        _table_target("csv", shared_data, folder("csv"), counts["csv"]),
        _table_target("trc", shared_data, folder("trc"), counts["trc"]),
        _obj_target(shared_data, folder("obj"), counts["obj"]),
        _ply_target(shared_data, folder("ply"), counts["ply"]),
        _npz_target(shared_data, folder("npz"), counts["take-npz"]),
        _toml_target("markerset", load_markerset, markerset_seeds,
                     ("name", "head", "regions", "clusters", "landmarks", "description",
                      "nose_tip", "upper_lip"), folder("markerset"), counts["markerset"]),
        _toml_target("landmarks", lambda p: load_mesh_landmarks(p, ict),
                     [ICT_LANDMARKS_TOML.read_bytes()],
                     ("mesh", "n_vertices", "landmarks", "description", "nose_tip"),
                     folder("landmarks"), counts["landmarks"]),
        _toml_target("layout", lambda p: load_marker_layout(p, ict),
                     [ICT_LAYOUT_TOML.read_bytes()],
                     ("name", "n_vertices", "units", "offset", "markers", "description"),
                     folder("layout"), counts["layout"]),
        _binding_target(folder("binding"), counts["binding"]),
        _run_config_target(folder("run"), counts["run-config"]),
    ]
    assert math.fsum(t.n_cases for t in targets) == sum(counts.values())
    return targets


#: Cases per target in ``make test`` (10,500 in all).
TEST_COUNTS = {"c3d": 2000, "csv": 1500, "trc": 1500, "obj": 1000, "ply": 500,
               "take-npz": 800, "markerset": 800, "landmarks": 500, "layout": 500,
               "binding": 500, "run-config": 900}


def environment_ok() -> bool:
    """Whether this system lets the worker limit and measure itself (Linux /proc)."""
    return os.path.exists("/proc/self/clear_refs") and hasattr(resource, "RLIMIT_AS")
