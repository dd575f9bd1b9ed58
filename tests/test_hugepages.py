"""NumPy's huge-page advice: off on a guest that reports free pages, left alone elsewhere."""

import os
import subprocess
import sys

import pytest

from mocap.util import hugepages
from mocap.util.hugepages import ADVICE_VARIABLE, configure_hugepage_advice, reports_free_pages

numpy_switch = hugepages._advice_module()
pytestmark = pytest.mark.skipif(numpy_switch is None, reason="this numpy has no huge-page switch")


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


@pytest.mark.parametrize("set_by_user", ["1", "0"])
def test_a_users_setting_is_left_as_it_is(tmp_path, advice, set_by_user):
    _device(tmp_path, "virtio0", 0x5, _features(5))
    environ = {ADVICE_VARIABLE: set_by_user}
    assert not configure_hugepage_advice(environ, devices=tmp_path)
    assert environ == {ADVICE_VARIABLE: set_by_user}
    assert advice() is True


def test_without_reporting_nothing_changes(tmp_path, advice):
    _device(tmp_path, "virtio0", 0x5, _features(1, 2))
    environ = {}
    assert not configure_hugepage_advice(environ, devices=tmp_path)
    assert environ == {} and advice() is True
