"""The heap ``mocap2mesh run`` is expected to need, told by its configuration before the
command's imports: the size of the block :func:`mocap.util.pretouch.start_pretouch`
writes while they run."""

from __future__ import annotations

from pathlib import Path

from mocap.errors import Mocap2MeshError
from mocap.util.toml import read_toml

__all__ = ["expected_run_heap", "HEAP_PER_CAPTURE_BYTE"]

#: The heap a take's chain uses beyond what every take needs whatever its length (the
#: mesh's arrays, the figures'), in bytes per byte of its capture file: about 20 for a C3D
#: of float samples. After the command's start, the 35,000-frame take of
#: ``bench/bench_chain.py`` (37 MB) faulted about 800 MB of fresh pages, a 3,870-frame
#: take (4 MB) 230 MB. A text capture holds fewer samples a byte, so that its need is
#: overestimated, up to :data:`mocap.util.pretouch.MAX_PRETOUCH`.
HEAP_PER_CAPTURE_BYTE = 20


def expected_run_heap(args) -> int:
    """Bytes of heap the take of the ``run`` arguments `args` is expected to need.

    Parameters
    ----------
    args : sequence of str
        The words after ``run`` on the command line.

    Returns
    -------
    int
        :data:`HEAP_PER_CAPTURE_BYTE` times the size of the capture file when the
        configuration (the one ``.toml`` word, a regular file) lists exactly one in
        ``inputs.captures`` (a take that runs in this process); else 0, as for anything
        unreadable: the command reports a configuration's errors itself.
    """
    configs = [Path(word) for word in args if word.endswith(".toml")]
    # a regular file only: a pipe's text would be gone for the command's own reading
    if len(configs) != 1 or not configs[0].is_file():
        return 0
    try:
        captures = read_toml(configs[0], "run configuration")["inputs"]["captures"]
        capture = captures[0] if isinstance(captures, list) and len(captures) == 1 \
            else captures
        if not isinstance(capture, str):
            return 0
        return HEAP_PER_CAPTURE_BYTE * (configs[0].parent / capture).stat().st_size
    except (Mocap2MeshError, OSError, KeyError, TypeError, ValueError):
        return 0
