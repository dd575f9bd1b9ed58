"""Figure helpers forked by a server that the command forks before it starts a thread.

Each test runs a script in a fresh interpreter: the server must be forked before any
thread starts, and the test process has threads of its own by now.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import figure_tasks
import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="the fork server is Linux's (pidfds)")

TESTS = Path(__file__).resolve().parent

#: What every script starts with: the figures' module imported before any server's fork.
PRELUDE = f"""
import json, os, sys, threading, time, warnings
sys.path.insert(0, {str(TESTS)!r})
import figure_tasks
from fit.report import forked_helpers
from fit.report.figure_queue import FigureQueue
from helpers import wait_for_file

def parent_of(pid):
    with open(f"/proc/{{pid}}/stat") as stat:
        return int(stat.read().rsplit(")", 1)[1].split()[1])
"""


def _run(script: str, tmp_path, *, prelude: str = PRELUDE) -> dict:
    """Run `script` (after `prelude`) in `tmp_path`; return the JSON it prints last."""
    done = subprocess.run([sys.executable, "-c", prelude + script], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120,
                          env={**os.environ, "OPENBLAS_NUM_THREADS": "2"})
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_forked_helpers_are_the_servers_children_and_draw_the_callers_bytes(tmp_path):
    out = _run("""
started = forked_helpers.start_fork_server()
with FigureQueue(helpers=2) as figures:
    parents = [parent_of(pid) for pid in figures.pids]
    figures.submit(figure_tasks.lines, "helper.png", seed=3)
    figures.submit(figure_tasks.collector, "gc.json")
    wait_for_file("helper.png")
    wait_for_file("gc.json")
    figures.run()
    helpers = list(figures.pids)
print(json.dumps({"started": started, "server": forked_helpers.fork_server_pid(),
                  "caller": os.getpid(), "parents": parents, "helpers": helpers}))
""", tmp_path)
    assert out["started"] and out["server"] not in (None, out["caller"])
    assert out["parents"] == [out["server"]] * 2
    state = json.loads((tmp_path / "gc.json").read_text())
    assert state["pid"] in out["helpers"]
    assert state["enabled"] and state["frozen"] > 10_000      # the imports' objects frozen
    figure_tasks.lines(tmp_path / "direct.png", seed=3)
    assert (tmp_path / "helper.png").read_bytes() == (tmp_path / "direct.png").read_bytes()


def test_a_forked_helper_finds_modules_on_the_callers_path_of_now(tmp_path):
    """The server's import path is the caller's at its fork: a helper takes the caller's as
    it is when the helper starts."""
    (tmp_path / "late").mkdir()
    (tmp_path / "late" / "late_figure.py").write_text(
        "import os\n\ndef drawn(path):\n    open(path, 'w').write(str(os.getpid()))\n")
    out = _run("""
forked_helpers.start_fork_server()
sys.path.append("late")
import late_figure
with FigureQueue(helpers=1) as figures:
    figures.submit(late_figure.drawn, "late.txt")
    wait_for_file("late.txt")
    figures.run()
print(json.dumps({"caller": os.getpid(), "drawn_by": int(open("late.txt").read())}))
""", tmp_path)
    assert out["drawn_by"] != out["caller"]


def test_a_forked_helper_that_dies_leaves_its_figure_to_the_caller_with_its_code(tmp_path):
    out = _run("""
forked_helpers.start_fork_server()
with FigureQueue(helpers=1) as figures:
    figures.submit(figure_tasks.pid, "marker.txt")
    wait_for_file("marker.txt")
    helper = figures._helpers[0].process
    figures.submit(figure_tasks.dies_in_helper, "survivor.txt", os.getpid())
    code = helper.wait(timeout=60)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        figures.run()
print(json.dumps({"caller": os.getpid(), "code": code, "survivor": int(open("survivor.txt").read()),
                  "warnings": [str(w.message) for w in caught]}))
""", tmp_path)
    assert out["code"] == 3
    assert out["survivor"] == out["caller"]
    assert any("exited with code 3 while drawing dies_in_helper" in w for w in out["warnings"])


def test_a_killed_forked_helper_is_reported_by_its_signal(tmp_path):
    out = _run("""
forked_helpers.start_fork_server()
figures = FigureQueue(helpers=1)
helper = figures._helpers[0].process
helper.kill()
code = helper.wait(timeout=60)
figures.close()
print(json.dumps({"code": code, "again": helper.poll()}))
""", tmp_path)
    assert out["code"] == out["again"] == -9


def test_no_server_once_a_thread_runs_and_helpers_are_fresh_interpreters(tmp_path):
    out = _run("""
stop = threading.Event()
threading.Thread(target=stop.wait).start()
started = forked_helpers.start_fork_server()
with FigureQueue(helpers=1) as figures:
    parents = [parent_of(pid) for pid in figures.pids]
    figures.submit(figure_tasks.pid, "drawn.txt")
    wait_for_file("drawn.txt")
    figures.run()
stop.set()
print(json.dumps({"started": started, "server": forked_helpers.fork_server_pid(),
                  "caller": os.getpid(), "parents": parents}))
""", tmp_path)
    assert out["started"] is False and out["server"] is None
    assert out["parents"] == [out["caller"]]


def test_a_forked_child_of_the_caller_does_not_use_its_server(tmp_path):
    out = _run("""
forked_helpers.start_fork_server()
child = os.fork()
if child == 0:
    with open("child.json", "w") as seen:
        json.dump({"server": forked_helpers.fork_server_pid(),
                   "helper": forked_helpers.forked_helper() is not None}, seen)
    os._exit(0)
os.waitpid(child, 0)
with FigureQueue(helpers=1) as figures:            # the caller's server still serves it
    parents = [parent_of(pid) for pid in figures.pids]
    figures.run()
print(json.dumps({"child": json.load(open("child.json")), "parents": parents,
                  "server": forked_helpers.fork_server_pid()}))
""", tmp_path)
    assert out["child"] == {"server": None, "helper": False}
    assert out["parents"] == [out["server"]]


def test_the_server_ends_with_its_caller(tmp_path):
    out = _run("""
forked_helpers.start_fork_server()
print(json.dumps({"server": forked_helpers.fork_server_pid()}))
""", tmp_path)
    stat = Path(f"/proc/{out['server']}/stat")
    deadline = time.monotonic() + 30
    while stat.exists() and stat.read_text().rsplit(")", 1)[1].split()[0] != "Z":
        assert time.monotonic() < deadline, "the fork server outlived its caller"
        time.sleep(0.05)


@pytest.mark.parametrize("command, server", [("run", True), ("info", False)])
def test_the_command_forks_a_server_when_it_draws_figures(tmp_path, command, server):
    out = _run(f"""
import json, os, sys
import fit.cli.main
cli = sys.modules["fit.cli.main"]              # (the package's "main" is the function)

def report(argv):
    helpers = sys.modules.get("fit.report.forked_helpers")
    print(json.dumps({{"server": helpers and helpers.fork_server_pid(),
                      "caller": os.getpid()}}))
    return 0

cli.main = report
sys.argv = ["mocap2mesh", {command!r}]
cli.console()
""", tmp_path, prelude="")
    assert (out["server"] not in (None, out["caller"])) is server


def test_a_server_that_cannot_fork_leaves_that_helper_to_a_fresh_interpreter(tmp_path):
    out = _run("""
caller, fork = os.getpid(), os.fork

def refused():                                  # the system refuses the server a process
    if os.getpid() != caller:
        raise BlockingIOError(11, "Resource temporarily unavailable")
    return fork()
os.fork = refused
forked_helpers.start_fork_server()
with FigureQueue(helpers=1) as figures:
    parents = [parent_of(pid) for pid in figures.pids]
    figures.submit(figure_tasks.pid, "drawn.txt")
    wait_for_file("drawn.txt")
    figures.run()
print(json.dumps({"caller": caller, "parents": parents, "drawn_by": int(open("drawn.txt").read()),
                  "server": forked_helpers.fork_server_pid()}))
""", tmp_path)
    assert out["parents"] == [out["caller"]]            # a fresh interpreter
    assert out["drawn_by"] != out["caller"]
    assert out["server"] is not None                    # kept for the next helpers


def test_no_server_when_the_system_refuses_a_process(tmp_path):
    out = _run("""
def refused():
    raise BlockingIOError(11, "Resource temporarily unavailable")
os.fork = refused
print(json.dumps({"started": forked_helpers.start_fork_server(),
                  "server": forked_helpers.fork_server_pid()}))
""", tmp_path)
    assert out == {"started": False, "server": None}
