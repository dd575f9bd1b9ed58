"""How a process of the chain gets its memory: freed memory kept, huge pages where they pay.

A take's stages make and drop many large arrays (a 35,000-frame take's positions are
55 MB), and the first touch of fresh memory is a page fault per 4 KB page. Two settings of
the allocators decide how often a process pays for it; :func:`configure_process_memory`
sets both for the ``mocap2mesh`` command, for itself and the processes it starts. Settings
a user made (in the environment) are left as they are.

**glibc keeps freed memory** (:func:`keep_freed_memory`). glibc maps an array above its
mmap threshold (128 KB, rising to at most 32 MB as such arrays are freed) afresh, and
unmaps it when it is freed, so the next array of that size faults its pages in again.
With the mmap and trim thresholds at 1 GiB, freed memory stays with the process and is
handed out again.
Two 55 MB arrays made, filled and dropped took 49-55 ms a time, and 17 ms once the memory
was kept. ``mocap2mesh run`` of a 35,000-frame take, three alternated pairs: 9.7-9.8 ->
9.3-9.5 s, its time in the kernel 1.3-1.6 -> 1.1-1.2 s, its peak memory 1.14 -> 1.16-1.17 GB.
Three such takes in one process, two pairs: 32.0-32.4 -> 29.9-30.4 s, the kernel's time
5.9-6.3 -> 3.1-3.4 s, the peak 1.19-1.21 -> 1.21-1.23 GB: the kept memory serves take after
take.

**NumPy's huge-page advice** (:func:`configure_hugepage_advice`). On Linux NumPy asks for
transparent huge pages for every array of 4 MB and more (``madvise(MADV_HUGEPAGE)``). On
a machine of its own that pays: one fault maps 2 MB. In a virtual machine whose balloon
device reports free memory to the hypervisor (virtio's free page reporting,
``VIRTIO_BALLOON_F_REPORTING``), it does not. The free blocks the guest reports are the
large ones, the blocks huge pages are cut from, and the host takes their memory back. So
each fresh huge page of a large array must be backed by the host again, page by page,
while small pages mostly come from memory the guest keeps. On such a 2-core guest (a
Firecracker VM) a fresh 512 MB array took 1.15 s to touch with the advice and 0.20 s
without. Its huge pages, freed and taken again by the same process, took 0.07 s.
``mocap2mesh run`` on a 35,000-frame take spent 3.7 s in the kernel with the advice and
1.7 s without. NumPy's issue 31590 describes the same trade with compaction stalls on
bare metal. The advice is turned off on a guest that reports free pages only.
"""

from __future__ import annotations

import ctypes
import importlib
import os
from pathlib import Path

__all__ = ["configure_process_memory", "keep_freed_memory", "reports_free_pages", "glibc",
           "configure_hugepage_advice", "ADVICE_VARIABLE", "KEPT_MEMORY"]

#: NumPy's environment variable for the advice, read when numpy is imported.
ADVICE_VARIABLE = "NUMPY_MADVISE_HUGEPAGE"
#: Where Linux lists the virtio devices (each with its type and negotiated features).
VIRTIO_DEVICES = Path("/sys/bus/virtio/devices")
_BALLOON = 0x5                  # virtio device type of a memory balloon
_F_REPORTING = 5                # feature bit: the guest reports free pages to the host
#: glibc's settings of :func:`keep_freed_memory`: its environment variable, mallopt's
#: parameter (malloc.h) and the value, bytes.
KEPT_MEMORY = (("MALLOC_MMAP_THRESHOLD_", -3, 1 << 30), ("MALLOC_TRIM_THRESHOLD_", -1, 1 << 30))
#: Environment variables by which a user has set glibc's allocator: then it is left alone.
_MALLOC_SETTINGS = (*(name for name, _, _ in KEPT_MEMORY), "MALLOC_TOP_PAD_", "MALLOC_MMAP_MAX_")


def configure_process_memory(environ=None) -> dict:
    """:func:`keep_freed_memory` and :func:`configure_hugepage_advice` for this process and
    the processes started from it (`environ`, default ``os.environ``).

    Returns
    -------
    dict
        ``{"kept_freed_memory": bool, "hugepage_advice_off": bool}``: what this call changed.
    """
    environ = os.environ if environ is None else environ
    return {"kept_freed_memory": keep_freed_memory(environ),
            "hugepage_advice_off": configure_hugepage_advice(environ)}


def keep_freed_memory(environ=None) -> bool:
    """Have glibc keep freed memory for reuse instead of mapping large arrays afresh.

    Sets glibc's mmap and trim thresholds to 1 GiB (:data:`KEPT_MEMORY`)
    in this process (``mallopt``) and in `environ` (default ``os.environ``), for the
    processes started from it. Nothing changes off glibc, or when `environ` already sets
    glibc's allocator (a ``MALLOC_*_`` variable or ``glibc.malloc`` tunables).

    Returns
    -------
    bool
        True when this call set them.
    """
    environ = os.environ if environ is None else environ
    if any(name in environ for name in _MALLOC_SETTINGS) \
            or "glibc.malloc." in environ.get("GLIBC_TUNABLES", ""):
        return False
    mallopt = _glibc_mallopt()
    if mallopt is None:
        return False
    for name, parameter, value in KEPT_MEMORY:
        if not mallopt(parameter, value):
            return False
        environ[name] = str(value)
    return True


def glibc():
    """This process's C library through ctypes when it is glibc, else None."""
    try:
        if not os.confstr("CS_GNU_LIBC_VERSION").startswith("glibc"):
            return None
        return ctypes.CDLL(None)
    except (AttributeError, OSError, ValueError):
        return None


def _glibc_mallopt():
    """glibc's ``mallopt`` (int parameter, int value) -> int, or None off glibc."""
    libc = glibc()
    if libc is None:
        return None
    mallopt = libc.mallopt
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return mallopt


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
    numpy_switch._set_madvise_hugepage(False)     # what the variable sets as numpy imports
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
