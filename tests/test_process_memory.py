"""A process's memory: freed memory kept by glibc; NumPy's huge-page advice off on a guest
that reports free pages; a user's own settings left alone."""

import os
import subprocess
import sys
import textwrap

import pytest

from mocap.util import process_memory
from mocap.util.process_memory import (
    ADVICE_VARIABLE,
    KEPT_MEMORY,
    configure_hugepage_advice,
    configure_process_memory,
    keep_freed_memory,
    reports_free_pages,
)

numpy_switch = process_memory._advice_module()
needs_switch = pytest.mark.skipif(numpy_switch is None,
                                  reason="this numpy has no huge-page switch")
on_glibc = pytest.mark.skipif(process_memory._glibc_mallopt() is None,
                              reason="glibc's allocator only")

#: A child process: 100 MB made and freed; prints how much its resident memory fell.
_FREED = textwrap.dedent("""
    import os, sys
    import numpy as np
    from mocap.util.process_memory import keep_freed_memory
    if sys.argv[1] == "here":
        assert keep_freed_memory({})
    def resident():
        return int(open("/proc/self/statm").read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    block = np.ones(100 << 17)
    before = resident()
    del block
    print((before - resident()) / 2**20)
""")


def _fall_mb(how: str, env) -> float:
    """MB the resident memory of a child fell by when it freed 100 MB."""
    out = subprocess.run([sys.executable, "-c", _FREED, how], env=env, capture_output=True,
                         text=True, check=True)
    return float(out.stdout)


def _plain_environment():
    """This environment without any setting of glibc's allocator."""
    return {k: v for k, v in os.environ.items()
            if k not in process_memory._MALLOC_SETTINGS and k != "GLIBC_TUNABLES"}


@on_glibc
def test_freed_memory_is_kept_here_and_in_the_processes_started_after():
    plain = _plain_environment()
    assert _fall_mb("plain", plain) > 90            # glibc's own: unmapped when freed
    assert _fall_mb("here", plain) < 10             # mallopt in the process itself
    environ = dict(plain)
    assert keep_freed_memory(environ)
    assert {name: environ[name] for name, _, _ in KEPT_MEMORY} == \
        {name: str(value) for name, _, value in KEPT_MEMORY}
    assert _fall_mb("plain", environ) < 10          # a process started with it


@pytest.mark.parametrize("setting", [{"MALLOC_TRIM_THRESHOLD_": "65536"},
                                     {"MALLOC_MMAP_THRESHOLD_": "131072"},
                                     {"GLIBC_TUNABLES": "glibc.malloc.trim_threshold=65536"}])
def test_a_users_allocator_settings_are_left_as_they_are(setting):
    environ = dict(setting)
    assert not keep_freed_memory(environ)
    assert environ == setting


def test_configure_says_what_it_changed():
    changed = configure_process_memory({"MALLOC_TRIM_THRESHOLD_": "65536", ADVICE_VARIABLE: "1"})
    assert changed == {"kept_freed_memory": False, "hugepage_advice_off": False}


def _device(root, name, kind, features):
    folder = root / name
    folder.mkdir()
    (folder / "device").write_text(f"{kind:#06x}\n")
    (folder / "features").write_text(features + "\n")


def _features(*bits, width=64):
    return "".join("1" if i in bits else "0" for i in range(width))


@pytest.fixture
def advice():
    """NumPy's advice for this process, on for the test and put back as it was after."""
    before = numpy_switch._get_madvise_hugepage()
    numpy_switch._set_madvise_hugepage(True)
    yield numpy_switch._get_madvise_hugepage
    numpy_switch._set_madvise_hugepage(before)


def test_a_balloon_that_reports_free_pages_is_found(tmp_path):
    _device(tmp_path, "virtio0", 0x1, _features(0, 5))          # a network card
    _device(tmp_path, "virtio1", 0x5, _features(1, 2, 5, 32))
    assert reports_free_pages(tmp_path)


@pytest.mark.parametrize("devices", [
    [("virtio0", 0x5, _features(1, 2, 32))],                    # a balloon without reporting
    [("virtio0", 0x2, _features(5))],                           # bit 5 of a block device
    [("virtio0", 0x5, "")],                                     # no features read
    [],
])
def test_no_reporting_balloon_is_not_found(tmp_path, devices):
    for device in devices:
        _device(tmp_path, *device)
    assert not reports_free_pages(tmp_path)


def test_unreadable_sysfs_is_no_reporting(tmp_path):
    assert not reports_free_pages(tmp_path / "absent")
    broken = tmp_path / "virtio0"
    broken.mkdir()
    (broken / "device").write_text("not a number\n")
    assert not reports_free_pages(tmp_path)


@needs_switch
def test_the_advice_goes_off_here_and_in_the_processes_started_after(tmp_path, advice):
    _device(tmp_path, "virtio0", 0x5, _features(5))
    environ = {k: v for k, v in os.environ.items() if k != ADVICE_VARIABLE}
    assert configure_hugepage_advice(environ, devices=tmp_path)
    assert environ[ADVICE_VARIABLE] == "0"
    assert advice() is False
    probe = f"import {numpy_switch.__name__} as m; print(m._get_madvise_hugepage())"
    def child(env):
        return subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True,
                              text=True, check=True).stdout.strip()
    assert child(environ) == "False"
    if sys.platform == "linux":     # numpy advises there by default: the variable did it
        assert child({k: v for k, v in environ.items() if k != ADVICE_VARIABLE}) == "True"


@needs_switch
@pytest.mark.parametrize("set_by_user", ["1", "0"])
def test_a_users_setting_is_left_as_it_is(tmp_path, advice, set_by_user):
    _device(tmp_path, "virtio0", 0x5, _features(5))
    environ = {ADVICE_VARIABLE: set_by_user}
    assert not configure_hugepage_advice(environ, devices=tmp_path)
    assert environ == {ADVICE_VARIABLE: set_by_user}
    assert advice() is True


@needs_switch
def test_without_reporting_nothing_changes(tmp_path, advice):
    _device(tmp_path, "virtio0", 0x5, _features(1, 2))
    environ = {}
    assert not configure_hugepage_advice(environ, devices=tmp_path)
    assert environ == {} and advice() is True


def test_the_command_sets_up_its_memory_as_it_starts():
    """The console entry point configures the memory before it runs the command: the
    command sees the allocator's variables (on glibc) and the advice's (on a reporting
    guest) that :func:`configure_process_memory` sets."""
    probe = textwrap.dedent("""
        import importlib, os, sys
        cli = importlib.import_module("fit.cli.main")
        cli.main = lambda argv: print(os.environ.get("MALLOC_TRIM_THRESHOLD_"),
                                      os.environ.get("NUMPY_MADVISE_HUGEPAGE")) or 0
        sys.argv = ["mocap2mesh", "--help"]
        cli.console()
    """)
    plain = {k: v for k, v in _plain_environment().items() if k != ADVICE_VARIABLE}
    seen = subprocess.run([sys.executable, "-c", probe], env=plain, capture_output=True,
                          text=True, check=True).stdout.split()
    # what configure_process_memory would change here, found without changing this process
    kept = process_memory._glibc_mallopt() is not None
    advice_off = numpy_switch is not None and reports_free_pages()
    assert seen == [str(KEPT_MEMORY[1][2]) if kept else "None", "0" if advice_off else "None"]
