"""The heap touched on an idle core while ``run`` imports (mocap.util.pretouch), and the
block's size from the run's configuration (fit.cli.run_heap).

The block's own tests run in fresh interpreters: it is process-wide, and a fork must see
no other thread. Page faults counted by the kernel (``getrusage``) are the oracle.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import textwrap

import pytest

from fit.cli.run_heap import HEAP_PER_CAPTURE_BYTE, expected_run_heap
from mocap.util import pretouch
from mocap.util.process_memory import KEPT_MEMORY


def _huge_pages_always() -> bool:
    """Whether Linux backs large anonymous memory by huge pages unasked (then a fresh
    array faults once per 2 MB, and the faults cannot tell the block's pages apart)."""
    try:
        with open("/sys/kernel/mm/transparent_hugepage/enabled", encoding="ascii") as mode:
            return "[always]" in mode.read()
    except OSError:
        return False


can_pretouch = pytest.mark.skipif(
    not (sys.platform.startswith("linux") and platform.machine() in pretouch._MACHINES
         and os.confstr("CS_GNU_LIBC_VERSION").startswith("glibc")
         and len(os.sched_getaffinity(0)) >= 2),
    reason="the block is taken on Linux (x86-64, AArch64) with glibc and two cores only")
counts_pages = pytest.mark.skipif(_huge_pages_always(),
                                  reason="transparent huge pages are always on here")

#: A child's start: freed memory kept, a block of 64 MB taken and written, and the
#: faults of an array of 48 MB made and written after it.
_CHILD = textwrap.dedent("""
    import json, os, resource, sys
    import numpy as np
    from mocap.util import pretouch
    from mocap.util.process_memory import keep_freed_memory
    assert keep_freed_memory()
    PAGE = os.sysconf("SC_PAGE_SIZE")
    def faults():
        return resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    def resident():
        return int(open("/proc/self/statm").read().split()[1]) * PAGE
    def written(nbytes):
        before = faults()
        array = np.empty(nbytes, np.uint8)
        array.fill(7)
        return faults() - before, array
    taken = pretouch.start_pretouch(64 << 20) if sys.argv[1] != "none" else False
    if taken:
        pretouch._block.thread.join()            # all written, as the imports' time allows
    pretouch.finish_pretouch()
    block = pretouch._block
    span = (block.address, block.address + block.size) if taken else (0, 0)
    out = {"taken": taken, "touched": pretouch.pretouched_bytes(), "pages": (48 << 20) // PAGE}
""")


def _child(script: str, mode: str) -> dict:
    done = subprocess.run([sys.executable, "-c", _CHILD + textwrap.dedent(script), mode],
                          capture_output=True, text=True, timeout=120,
                          env={**{k: v for k, v in os.environ.items()
                                  if not k.startswith("MALLOC_")},
                               "NUMPY_MADVISE_HUGEPAGE": "0"})    # a fault per 4 KB page
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


_REUSED = """
    if sys.argv[1] == "fork":                # a child holding its copy of the heap
        read_end, write_end = os.pipe()
        child = os.fork()
        if child == 0:
            os.read(read_end, 1)
            os._exit(0)
    pretouch.release_pretouch(keep=True)
    out["faults"], array = written(48 << 20)
    out["inside"] = span[0] <= array.ctypes.data < span[1]
    if sys.argv[1] == "fork":
        os.write(write_end, b"x")
        os.waitpid(child, 0)
    print(json.dumps(out))
"""


@can_pretouch
@counts_pages
def test_an_array_made_after_the_block_reuses_its_written_pages():
    plain = _child(_REUSED, "none")
    assert plain["faults"] > 0.9 * plain["pages"]          # a fault per fresh page
    out = _child(_REUSED, "here")
    assert out["taken"] and out["touched"] >= (64 << 20) - (2 << 12) and out["inside"]
    assert out["faults"] < 0.1 * out["pages"]


@can_pretouch
@counts_pages
def test_a_child_forked_while_the_block_is_held_shares_none_of_its_pages():
    """Shared copy-on-write, each page the array writes would fault again, to be copied
    (the figure helpers' server is forked while the block is held)."""
    out = _child(_REUSED, "fork")
    assert out["taken"] and out["inside"]
    assert out["faults"] < 0.1 * out["pages"]


@can_pretouch
def test_once_freed_the_block_is_shared_with_children_as_any_memory():
    out = _child("""
    pretouch.release_pretouch(keep=True)
    _, array = written(48 << 20)
    out["inside"] = span[0] <= array.ctypes.data < span[1]
    child = os.fork()
    if child == 0:                  # the child reads what the parent wrote there
        os._exit(0 if (array[::PAGE] == 7).all() else 3)
    out["child"] = os.waitstatus_to_exitcode(os.waitpid(child, 0)[1])
    print(json.dumps(out))
    """, "here")
    assert out["taken"] and out["inside"] and out["child"] == 0


@can_pretouch
@counts_pages
def test_a_block_not_kept_gives_its_pages_back():
    out = _child("""
    before = resident()
    pretouch.release_pretouch(keep=False)
    out["fell"] = before - resident()
    out["faults"], array = written(48 << 20)
    print(json.dumps(out))
    """, "here")
    assert out["taken"] and out["fell"] > 0.9 * out["touched"]
    assert out["faults"] > 0.9 * out["pages"]


@can_pretouch
def test_a_second_start_keeps_the_first_block_and_release_is_once():
    out = _child("""
    first = pretouch._block
    out["again"] = pretouch.start_pretouch(128 << 20) and pretouch._block is first
    pretouch.release_pretouch()
    pretouch.release_pretouch()
    out["left"] = pretouch._block is None and pretouch.pretouched_bytes() == 0
    print(json.dumps(out))
    """, "here")
    assert out["taken"] and out["again"] and out["left"]


def _kept_environment(monkeypatch):
    for name, _, value in KEPT_MEMORY:
        monkeypatch.setenv(name, str(value))


@pytest.mark.parametrize("why", ["memory not kept", "too small", "one core", "no memory"])
def test_no_block_where_it_would_not_pay(monkeypatch, why):
    _kept_environment(monkeypatch)
    nbytes = 256 << 20
    if why == "memory not kept":        # glibc would give the freed block back
        monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_")
    elif why == "too small":
        nbytes = pretouch._MIN_PRETOUCH - 1
    elif why == "one core":             # no idle core to write it
        monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0}, raising=False)
    else:                               # a quarter of what the system has available
        monkeypatch.setattr(pretouch, "_available_bytes", lambda: 4 * nbytes // 10)
    monkeypatch.setattr(pretouch, "_block", None)
    assert pretouch.start_pretouch(nbytes) is False and pretouch._block is None
    pretouch.release_pretouch()                     # nothing to free: no error
    assert pretouch.pretouched_bytes() == 0


def test_the_block_is_at_most_three_quarters_of_the_kept_trim_threshold():
    assert pretouch.MAX_PRETOUCH == 3 * dict(
        (name, value) for name, _, value in KEPT_MEMORY)["MALLOC_TRIM_THRESHOLD_"] // 4


def _config(tmp_path, inputs: str, name: str = "run.toml"):
    path = tmp_path / name
    path.write_text(f"[inputs]\n{inputs}\nmarkerset = 'm.toml'\n", encoding="utf-8")
    return path


def test_the_run_heap_is_its_one_capture_s_bytes_times_the_factor(tmp_path, monkeypatch):
    (tmp_path / "takes").mkdir()
    (tmp_path / "takes" / "a.c3d").write_bytes(bytes(3000))
    config = _config(tmp_path, "captures = ['takes/a.c3d']")
    expected = HEAP_PER_CAPTURE_BYTE * 3000
    assert expected_run_heap([str(config)]) == expected
    assert expected_run_heap(["-j", "1", str(config), "--force"]) == expected
    monkeypatch.chdir(tmp_path / "takes")         # relative to the file, not the directory
    assert expected_run_heap([os.path.relpath(config)]) == expected
    single = _config(tmp_path, f"captures = '{tmp_path / 'takes' / 'a.c3d'}'", "one.toml")
    assert expected_run_heap([str(single)]) == expected


@pytest.mark.parametrize("inputs", [
    "captures = ['a.c3d', 'b.c3d']",        # takes that may run in other processes
    "session = '.'",
    "captures = ['missing.c3d']",
    "captures = [3]",
    "captures = []",
    "mesh = 'x.obj'",
    "captures = [",                          # not TOML
])
def test_no_run_heap_without_one_readable_capture(tmp_path, inputs):
    for name in ("a.c3d", "b.c3d"):
        (tmp_path / name).write_bytes(bytes(100))
    config = _config(tmp_path, inputs)
    assert expected_run_heap([str(config)]) == 0


def test_no_run_heap_without_one_configuration(tmp_path):
    assert expected_run_heap([]) == 0
    if hasattr(os, "mkfifo"):
        os.mkfifo(tmp_path / "piped.toml")      # not read: its text is the command's
        assert expected_run_heap([str(tmp_path / "piped.toml")]) == 0
    assert expected_run_heap(["--check"]) == 0
    assert expected_run_heap([str(tmp_path / "a.toml"), str(tmp_path / "b.toml")]) == 0
    assert expected_run_heap([str(tmp_path / "missing.toml")]) == 0


@can_pretouch
def test_the_run_command_writes_its_block_while_it_imports(tmp_path):
    """``mocap2mesh run`` takes the block its configuration asks for and has written it
    by the time its imports are done, its thread stopped so that the figure helpers'
    server is forked."""
    capture = tmp_path / "take.c3d"
    with open(capture, "wb") as file:               # only its size is read
        file.truncate(4 << 20)
    config = _config(tmp_path, f"captures = ['{capture.name}']")
    command = textwrap.dedent(f"""
        import json, os, sys
        import fit.cli.main
        from mocap.util import pretouch
        cli = sys.modules["fit.cli.main"]          # (the package's "main" is the function)
        def report(argv):
            helpers = sys.modules["fit.report.forked_helpers"]
            block = pretouch._block
            print(json.dumps({{"size": block.size, "touched": pretouch.pretouched_bytes(),
                              "thread": block.thread is not None,
                              "server": helpers.fork_server_pid() is not None}}))
            return 0
        cli.main = report
        sys.argv = ["mocap2mesh", "run", {str(config)!r}]
        cli.console()
    """)
    done = subprocess.run([sys.executable, "-c", command], capture_output=True, text=True,
                          timeout=120, env={k: v for k, v in os.environ.items()
                                            if not k.startswith("MALLOC_")})
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert out["size"] == HEAP_PER_CAPTURE_BYTE * (4 << 20)
    assert out["touched"] >= out["size"] - (2 << 12)      # whole pages inside the block
    assert not out["thread"] and out["server"]
