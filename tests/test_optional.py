"""Optional dependencies: numba (the speed extra, which the tests install) loaded on
request, or silently absent."""

from __future__ import annotations

import subprocess
import sys

from mocap.util.optional import load_numba


def test_load_numba_imports_it_in_a_process_without_it():
    script = ("from mocap.util.optional import load_numba, numba_loaded\n"
              "assert not numba_loaded()\n"
              "load_numba()\n"
              "assert numba_loaded()\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_load_numba_without_the_speed_extra_does_nothing(monkeypatch):
    class NoNumba:
        @staticmethod
        def find_spec(fullname, path=None, target=None):
            if fullname == "numba":
                raise ImportError("No module named 'numba'")
            return None
    monkeypatch.delitem(sys.modules, "numba", raising=False)
    monkeypatch.setattr(sys, "meta_path", [NoNumba, *sys.meta_path])
    assert load_numba() is None
    assert "numba" not in sys.modules
