"""Atomic output: write to a temporary file beside the target, then rename."""

from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path

from mocap.errors import InputError

__all__ = ["atomic_path", "refuse_overwrite"]


def refuse_overwrite(output, inputs) -> None:
    """Raise InputError if `output` is the same file as any of `inputs`."""
    output = Path(output)
    if not output.exists():
        return
    for item in inputs:
        if item is not None and Path(item).exists() and os.path.samefile(output, item):
            raise InputError(f"{output}: refusing to overwrite an input file")


@contextmanager
def atomic_path(path, *, inputs=()):
    """Yield a temporary path; on success rename it over `path`, else delete it.

    Parameters
    ----------
    path : str or os.PathLike
        The final output file. Its directory must exist.
    inputs : iterable of path, optional
        Files this output must never replace.

    Raises
    ------
    InputError
        `path` is an input, its directory is missing, or writing fails
        (permissions, disk full): ``"<path>: cannot write: <reason>"``.
    """
    path = Path(path)
    refuse_overwrite(path, inputs)
    if not path.parent.is_dir():
        raise InputError(f"{path}: cannot write: directory {path.parent} does not exist")
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as exc:
        raise InputError(f"{path}: cannot write: {exc.strerror or exc}") from None
    finally:
        if tmp.exists():
            tmp.unlink()
