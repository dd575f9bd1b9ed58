"""Takes prepared for the session basis, kept on disk for their own run.

With a session basis (``[basis] scope = "session"``) every take goes through ingest, bind
and retarget twice: once for the pooled PCA (:func:`fit.pipeline.session_basis.take_moments`,
which sends back only its operator and marker moments), once when it is fitted. Kept, the
first pass's :class:`~fit.pipeline.reconstruction.PreparedTake` and the warnings its stages
raised are read back by the take's run instead (a 3,000-frame take: 25 MB, written and read
in a few hundredths of a second, against about a second of stages).

The files live in the run's staging folder (removed when the run starts and ends), within
:data:`KEPT_BYTES` in all: beyond it a take is prepared again, as without keeping. A file
that cannot be read back (a worker killed while writing it, a full disk) is the same: the
take is prepared again. Workers of a cluster write where the takes' outputs go, so the
output directory must be theirs to write, as it is for the takes.
"""

from __future__ import annotations

import os
import pickle
from pathlib import Path

from fit.pipeline.outdir import staging_dir
from fit.pipeline.reconstruction import PreparedTake
from mocap.errors import InputError
from mocap.util.atomic import atomic_path

__all__ = ["KEPT_BYTES", "kept_files", "keep_prepared", "take_kept"]

#: Most bytes of prepared takes kept at once (about 80 takes of 3,000 frames, 7 of 35,000).
KEPT_BYTES = 2 * 1024 ** 3


def kept_files(out_dir, names) -> dict:
    """Where takes are kept: capture -> a file in the staging folder of the run's output
    `out_dir` (the folder is created), for `names` (capture -> take name)."""
    folder = staging_dir(out_dir) / "kept"
    folder.mkdir(exist_ok=True)
    return {capture: folder / f"{name}.pickle" for capture, name in names.items()}


def keep_prepared(prepared: PreparedTake, caught: list, path) -> bool:
    """Write `prepared` and the warnings its stages raised to `path`, if they fit.

    Parameters
    ----------
    prepared : PreparedTake
    caught : list of (str, type)
        The stages' warnings, message and category, in the order raised.
    path : path
        The take's file, in a folder of kept takes only.

    Returns
    -------
    bool
        Whether it was written: not when the folder's files and this one would pass
        :data:`KEPT_BYTES`, nor when writing fails.
    """
    path = Path(path)
    try:
        held = sum(entry.stat().st_size for entry in os.scandir(path.parent)
                   if entry.is_file())
        if held >= KEPT_BYTES:                   # full: not even pickled
            return False
        data = pickle.dumps((prepared, caught), protocol=pickle.HIGHEST_PROTOCOL)
        if held + len(data) > KEPT_BYTES:
            return False
        with atomic_path(path) as tmp:
            tmp.write_bytes(data)
    except (OSError, InputError):                # no room, no folder: prepared again later
        return False
    return True


def take_kept(path):
    """The prepared take and its stages' warnings kept at `path`, removing the file.

    Returns
    -------
    tuple of (PreparedTake, list of (str, type)) or None
        None when there is no such file or it does not read back whole.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError:
        return None
    path.unlink(missing_ok=True)
    try:
        prepared, caught = pickle.loads(data)
    except Exception:  # noqa: BLE001 - a file cut short or garbled: prepare the take again
        return None
    if not isinstance(prepared, PreparedTake):
        return None
    return prepared, caught
