"""NumPy's huge-page advice, turned off where a fresh huge page costs more than small ones.

On Linux NumPy asks for transparent huge pages for every array of 4 MB and more
(``madvise(MADV_HUGEPAGE)``). On a machine of its own that pays: one fault maps 2 MB. In
a virtual machine whose balloon device reports free memory to the hypervisor (virtio's
free page reporting, ``VIRTIO_BALLOON_F_REPORTING``), it does not. The free blocks the
guest reports are the large ones, the blocks huge pages are cut from, and the host takes
their memory back. So each fresh huge page of a large array must be backed by the host
again, page by page, while small pages mostly come from memory the guest keeps. On such a
2-core guest (a Firecracker VM) a fresh 512 MB array took 1.15 s to touch with the advice
and 0.20 s without. Its huge pages, freed and taken again by the same process, took 0.07 s.
``mocap2mesh run`` on a 35,000-frame take spent 3.7 s in the kernel with the advice and
1.7 s without. NumPy's issue 31590 describes the same trade with compaction stalls on
bare metal.

:func:`configure_hugepage_advice` turns the advice off for this process and for the
processes it starts, on a guest that reports free pages. The ``mocap2mesh`` command calls
it as it starts; a user's own ``NUMPY_MADVISE_HUGEPAGE`` is left as it is.
"""

from __future__ import annotations

import importlib
import os
from pathlib import Path

__all__ = ["reports_free_pages", "configure_hugepage_advice", "ADVICE_VARIABLE"]

#: NumPy's environment variable for the advice, read when numpy is imported.
ADVICE_VARIABLE = "NUMPY_MADVISE_HUGEPAGE"
#: Where Linux lists the virtio devices (each with its type and negotiated features).
VIRTIO_DEVICES = Path("/sys/bus/virtio/devices")
_BALLOON = 0x5                  # virtio device type of a memory balloon
_F_REPORTING = 5                # feature bit: the guest reports free pages to the host


def reports_free_pages(devices: Path = VIRTIO_DEVICES) -> bool:
    """Whether this Linux guest reports its free memory to its hypervisor.

    True when a virtio balloon device under `devices` has negotiated free page
    reporting; False on other systems and when sysfs cannot be read.
    """
    try:
        entries = list(Path(devices).iterdir())
    except OSError:
        return False
    for entry in entries:
        try:
            kind = int((entry / "device").read_text().strip(), 16)
            features = (entry / "features").read_text().strip()
        except (OSError, ValueError):
            continue
        if kind == _BALLOON and features[_F_REPORTING:_F_REPORTING + 1] == "1":
            return True
    return False


def configure_hugepage_advice(environ=None, *, devices: Path = VIRTIO_DEVICES) -> bool:
    """Turn NumPy's huge-page advice off on a guest that reports free pages.

    Parameters
    ----------
    environ : mutable mapping, optional
        The environment the processes started from here inherit (default
        ``os.environ``); ``NUMPY_MADVISE_HUGEPAGE=0`` is set in it so that they import
        numpy with the advice off. When it already names the variable, nothing changes.
    devices : Path
        The virtio devices' folder (see :func:`reports_free_pages`).

    Returns
    -------
    bool
        True when this call turned the advice off.
    """
    environ = os.environ if environ is None else environ
    numpy_switch = _advice_module()
    if ADVICE_VARIABLE in environ or numpy_switch is None or not reports_free_pages(devices):
        return False
    numpy_switch._set_madvise_hugepage(False)
    environ[ADVICE_VARIABLE] = "0"
    return True


def _advice_module():
    """NumPy's module that holds the advice's switch (numpy 2, then 1.26), None if none does."""
    for name in ("numpy._core.multiarray", "numpy.core.multiarray"):
        try:
            module = importlib.import_module(name)
        except ImportError:
            continue
        if hasattr(module, "_set_madvise_hugepage"):
            return module
    return None
