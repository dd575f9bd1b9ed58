"""FigureQueue: figures drawn by helper processes are the figures the caller would draw."""

from __future__ import annotations

import json
import os
import pickle

import figure_tasks
import matplotlib
import pytest
from helpers import wait_for_file

from fit.report.figure_queue import FigureQueue
from mocap.errors import FileFormatError, MarkerError, MissingDependencyError


def _drawn_by(path) -> int:
    with open(path) as drawn:
        return int(drawn.read())


def test_a_helper_draws_as_soon_as_a_figure_is_submitted(tmp_path):
    with FigureQueue(helpers=1) as figures:
        figures.submit(figure_tasks.pid, tmp_path / "early.txt")
        wait_for_file(tmp_path / "early.txt")
        figures.run()
    assert _drawn_by(tmp_path / "early.txt") != os.getpid()


def test_a_helper_imports_with_the_collector_off_and_draws_with_it_on(tmp_path):
    """The helper's imports are made with the collector off and then frozen: it draws with
    the collector on, its full passes skipping the imports' objects."""
    with FigureQueue(helpers=1) as figures:
        figures.submit(figure_tasks.collector, tmp_path / "gc.json")
        wait_for_file(tmp_path / "gc.json")
        figures.run()
    state = json.loads((tmp_path / "gc.json").read_text())
    assert state["pid"] != os.getpid()
    assert state["enabled"] and state["frozen"] > 10_000
    # a few collections (the interpreter's start, the figure), not hundreds (the imports)
    assert sum(state["collections"]) < 100, state


def test_the_same_png_bytes_whoever_draws_it_under_the_callers_rcparams(tmp_path):
    with matplotlib.rc_context({"lines.linewidth": 4.0, "figure.dpi": 50,
                                "savefig.dpi": 50, "font.size": 6}):
        figure_tasks.lines(tmp_path / "direct.png", seed=3)
        with FigureQueue(helpers=1) as figures:
            figures.submit(figure_tasks.pid, tmp_path / "marker.txt")
            wait_for_file(tmp_path / "marker.txt")       # the helper is up and idle
            figures.submit(figure_tasks.lines, tmp_path / "helper.png", seed=3)
            wait_for_file(tmp_path / "helper.png")
            figures.run()
    figure_tasks.lines(tmp_path / "default_rc.png", seed=3)
    direct = (tmp_path / "direct.png").read_bytes()
    assert (tmp_path / "helper.png").read_bytes() == direct
    assert (tmp_path / "default_rc.png").read_bytes() != direct     # the rc mattered


def test_without_helpers_the_caller_draws_everything_in_order(tmp_path):
    with FigureQueue(helpers=0) as figures:
        assert figures.helpers == 0
        for index in range(3):
            figures.submit(figure_tasks.pid, tmp_path / f"{index}.txt")
        assert not list(tmp_path.iterdir())          # nothing before run
        figures.run()
    assert {_drawn_by(tmp_path / f"{index}.txt") for index in range(3)} == {os.getpid()}


def test_a_helpers_error_arrives_as_itself_after_the_other_figures(tmp_path):
    with FigureQueue(helpers=1) as figures:
        figures.submit(figure_tasks.bad_file, tmp_path / "first.bin")
        figures.submit(figure_tasks.bad_file, tmp_path / "second.bin")
        figures.submit(figure_tasks.pid, tmp_path / "after.txt")
        wait_for_file(tmp_path / "after.txt")           # the helper drew all three
        with pytest.raises(FileFormatError) as raised:
            figures.run()
    assert raised.value.path == os.fspath(tmp_path / "first.bin")
    assert raised.value.offset == 7
    assert _drawn_by(tmp_path / "after.txt") != os.getpid()
    notes = getattr(raised.value, "__notes__", [])
    assert any("figure helper" in note and "bad_file" in note and "not a figure" in note
               for note in notes)


def test_a_helpers_warnings_are_warned_by_run(tmp_path):
    with FigureQueue(helpers=1) as figures:
        figures.submit(figure_tasks.warned, tmp_path / "warned.txt")
        wait_for_file(tmp_path / "warned.txt")
        with pytest.warns(UserWarning, match="careful with warned.txt"):
            figures.run()


def test_a_helper_that_dies_leaves_its_figure_to_the_caller(tmp_path):
    with FigureQueue(helpers=1) as figures:
        figures.submit(figure_tasks.pid, tmp_path / "marker.txt")
        wait_for_file(tmp_path / "marker.txt")
        helper = figures._helpers[0].process
        figures.submit(figure_tasks.dies_in_helper, tmp_path / "survivor.txt", os.getpid())
        helper.wait(timeout=60)
        with pytest.warns(RuntimeWarning, match="exited with code 3 while drawing dies_in_helper"):
            figures.run()
    assert _drawn_by(tmp_path / "survivor.txt") == os.getpid()


def test_a_figure_that_does_not_pickle_is_drawn_by_the_caller(tmp_path):
    def local_figure(path):                          # a closure: no pickle by name
        figure_tasks.pid(path)

    with FigureQueue(helpers=1) as figures:
        figures.submit(figure_tasks.pid, tmp_path / "marker.txt")
        wait_for_file(tmp_path / "marker.txt")
        figures.submit(local_figure, tmp_path / "local.txt")
        figures.run()
    assert _drawn_by(tmp_path / "local.txt") == os.getpid()


def test_a_script_folder_shadowing_the_standard_library_does_not_break_helpers(
        tmp_path, monkeypatch):
    scripts = tmp_path / "scripts"
    scripts.mkdir()
    (scripts / "re.py").write_text("raise ImportError('the script folder re.py')\n")
    monkeypatch.syspath_prepend(os.fspath(scripts))
    with FigureQueue(helpers=1) as figures:
        figures.submit(figure_tasks.pid, tmp_path / "drawn.txt")
        wait_for_file(tmp_path / "drawn.txt")
        figures.run()
    assert _drawn_by(tmp_path / "drawn.txt") != os.getpid()


def test_a_negative_helper_count_is_refused():
    with pytest.raises(ValueError, match="helpers must be 0 or more"):
        FigureQueue(helpers=-1)


@pytest.mark.parametrize("error", [
    FileFormatError("take.c3d", "truncated", offset=512),
    MarkerError("lip-upper1", "missing in frames 3-9"),
    MissingDependencyError("praat-parselmouth", "speech", "pitch tracks"),
])
def test_errors_cross_processes_as_themselves(error):
    error.add_note("a note")
    copy = pickle.loads(pickle.dumps(error))
    assert type(copy) is type(error)
    assert str(copy) == str(error) and copy.args == error.args
    assert copy.__dict__ == error.__dict__


def test_an_error_that_does_not_unpickle_is_raised_by_the_callers_own_draw(tmp_path):
    with FigureQueue(helpers=1) as figures:
        figures.submit(figure_tasks.picky, tmp_path / "picky.png")
        figures.submit(figure_tasks.pid, tmp_path / "after.txt")
        wait_for_file(tmp_path / "after.txt")           # the helper drew both
        with pytest.raises(figure_tasks.PickyError, match="picky.png: no figure"):
            figures.run()
