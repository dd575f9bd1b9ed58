"""The heap touched on an idle core before a command needs it.

A process's first write to a page of fresh memory is a page fault, and on a virtual
machine that reports its free memory to the host each fault must have the host back the
page again (:mod:`mocap.util.process_memory`). ``mocap2mesh run`` of a 35,000-frame take
faults about 200,000 pages (800 MB) after its start, in its stages. Meanwhile the
command's imports keep one core busy for about a second and leave the others idle.

:func:`start_pretouch` takes a block of the heap and has a thread write its pages while
the imports run; :func:`finish_pretouch` stops that thread (before the command forks the
figure helpers' server, which needs no other thread); :func:`release_pretouch` frees the
block, its pages kept or given back. glibc, keeping freed memory
(:func:`mocap.util.process_memory.keep_freed_memory`), then hands the written pages to
the arrays that follow. A Java VM's ``AlwaysPreTouch`` does the same for its heap; here
it is done on a core that would idle.

Until it is freed, the block is left out of any forked child (``MADV_WIPEONFORK``): a
child would otherwise share its pages copy-on-write, and this process would fault on
each again, to copy it. The figure helpers' server, forked while the block is held,
never reads it.

The block is taken only where every part of this holds: Linux on x86-64 or AArch64 with
glibc, the freed memory kept, at least two cores for this process, and the kernel's
``MADV_WIPEONFORK`` (4.14 and later).
"""

from __future__ import annotations

import ctypes
import os
import platform
import threading
from dataclasses import dataclass, field

from mocap.util.process_memory import KEPT_MEMORY, glibc

__all__ = ["start_pretouch", "finish_pretouch", "release_pretouch", "pretouched_bytes",
           "MAX_PRETOUCH"]

#: The largest block: three quarters of the trim threshold glibc is given by
#: :func:`~mocap.util.process_memory.keep_freed_memory`, so that freeing the block can
#: never make the heap's top large enough for glibc to give it back to the system.
MAX_PRETOUCH = 3 * dict((name, value) for name, _, value in KEPT_MEMORY)[
    "MALLOC_TRIM_THRESHOLD_"] // 4
#: Most of the memory the system has available that the block may take.
_AVAILABLE_SHARE = 0.25
#: The least worth a thread: below it the block is not taken.
_MIN_PRETOUCH = 32 << 20
#: Bytes the thread writes at a time (it checks whether to stop between them).
_CHUNK = 16 << 20
_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096
# madvise advice of asm-generic/mman-common.h (x86-64 and AArch64)
_MADV_DONTNEED, _MADV_WIPEONFORK, _MADV_KEEPONFORK = 4, 18, 19
_MACHINES = ("x86_64", "aarch64")


@dataclass
class _Block:
    """The block: its address and size from malloc, the whole pages inside it, the
    thread writing them and how far it has come (bytes from `first`)."""

    address: int
    size: int
    first: int
    end: int
    libc: object
    stop: threading.Event = field(default_factory=threading.Event)
    touched: int = 0
    thread: threading.Thread | None = None

    def touch(self) -> None:
        """Write the block's pages from the first, a chunk at a time, until told to stop
        (ctypes lets go of the GIL in each ``memset``)."""
        while self.touched < self.end - self.first and not self.stop.is_set():
            n = min(_CHUNK, self.end - self.first - self.touched)
            self.libc.memset(self.first + self.touched, 0, n)
            self.touched += n


_block: _Block | None = None


def start_pretouch(nbytes: int) -> bool:
    """Take a block of the heap and start a thread writing its pages.

    Parameters
    ----------
    nbytes : int
        The block's size (what the command's arrays are expected to need), at most
        :data:`MAX_PRETOUCH` and a quarter of the memory the system has available.

    Returns
    -------
    bool
        True when the block was taken (see the module's conditions); False leaves the
        process as it was.
    """
    global _block
    if _block is not None:
        return True
    libc = _libc()
    if libc is None:
        return False
    size = min(int(nbytes), MAX_PRETOUCH, int(_available_bytes() * _AVAILABLE_SHARE))
    if size < _MIN_PRETOUCH:
        return False
    address = libc.malloc(size)
    if not address:
        return False
    # whole pages only, and not the pages of the chunk's header or the next chunk's
    first = -(-address // _PAGE) * _PAGE
    end = (address + size) // _PAGE * _PAGE - _PAGE
    if libc.madvise(first, end - first, _MADV_WIPEONFORK) != 0:
        libc.free(address)
        return False
    block = _Block(address, size, first, end, libc)
    block.thread = threading.Thread(target=block.touch, name="mocap2mesh-pretouch",
                                    daemon=True)
    block.thread.start()
    _block = block
    return True


def finish_pretouch() -> None:
    """Stop the thread writing the block's pages (those written stay), and wait for it."""
    if _block is not None and _block.thread is not None:
        _block.stop.set()
        _block.thread.join()
        _block.thread = None


def pretouched_bytes() -> int:
    """Bytes of the block written so far (0 without a block)."""
    return 0 if _block is None else _block.touched


def release_pretouch(keep: bool = True) -> None:
    """Free the block: its written pages kept for the heap's next arrays, or given back to
    the system (`keep` False: the arrays that would use them are made elsewhere, e.g. in
    worker processes). Forked children share the freed block's pages again."""
    global _block
    if _block is None:
        return
    finish_pretouch()
    block, _block = _block, None
    libc, length = block.libc, block.end - block.first
    libc.madvise(block.first, length, _MADV_KEEPONFORK)
    if not keep:
        libc.madvise(block.first, length, _MADV_DONTNEED)
    libc.free(block.address)


def _libc():
    """glibc's malloc, free, memset and madvise when this process may take a block, or
    None (see the module's conditions)."""
    if platform.system() != "Linux" or platform.machine() not in _MACHINES:
        return None
    if any(os.environ.get(name) != str(value) for name, _, value in KEPT_MEMORY):
        return None                    # freed memory not kept: the block would go back
    if len(os.sched_getaffinity(0)) < 2:
        return None                    # no idle core to write it
    libc = glibc()
    if libc is None:
        return None
    pointer, size = ctypes.c_void_p, ctypes.c_size_t
    for name, restype, argtypes in (("malloc", pointer, (size,)), ("free", None, (pointer,)),
                                    ("memset", pointer, (pointer, ctypes.c_int, size)),
                                    ("madvise", ctypes.c_int, (pointer, size, ctypes.c_int))):
        function = getattr(libc, name)
        function.restype, function.argtypes = restype, argtypes
    return libc


def _available_bytes() -> int:
    """The memory the system has available (``MemAvailable``), 0 when unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return 0
