"""Read and write any supported marker file, chosen by its extension."""

from __future__ import annotations

from pathlib import Path

from mocap.errors import InputError
from mocap.take import Take
from mocap.util.files import as_path

__all__ = ["read", "write", "READ_FORMATS", "WRITE_FORMATS"]

#: Extensions that :func:`read` accepts.
READ_FORMATS = (".c3d", ".csv", ".trc", ".npz")
#: Extensions that :func:`write` accepts.
WRITE_FORMATS = (".c3d", ".csv", ".trc", ".npz")


def _extension(path, allowed) -> str:
    ext = Path(path).suffix.lower()
    if ext not in allowed:
        raise InputError(f"{path}: unsupported extension {ext or '(none)'!r}; "
                         f"expected one of {', '.join(allowed)}")
    return ext


def read(path) -> Take:
    """Read a marker file: C3D, Vicon Nexus CSV, TRC or our ``.npz``.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    Take
        Positions in mm, NaN where missing.

    Raises
    ------
    FileFormatError
        The file is missing, unreadable, empty, truncated or corrupt (names file
        and offset or line), or would take more memory than it justifies.
    InputError
        The extension is not supported, or the path is not one (a NUL in it).
    """
    path = as_path(path)
    ext = _extension(path, READ_FORMATS)
    if ext == ".c3d":
        from mocap.io.c3d import read_c3d
        return read_c3d(path)
    if ext == ".csv":
        from mocap.io.vicon_csv import read_vicon_csv
        return read_vicon_csv(path)
    if ext == ".trc":
        from mocap.io.trc import read_trc
        return read_trc(path)
    from mocap.io.take_npz import read_take_npz
    return read_take_npz(path)


def write(take: Take, path, *, inputs=()) -> None:
    """Write `take` as C3D, Vicon Nexus CSV, TRC or ``.npz`` by extension, atomically.

    Parameters
    ----------
    take : Take
    path : str or os.PathLike
    inputs : iterable of paths, optional
        Files that must never be overwritten (the files the take was read from).
    """
    ext = _extension(path, WRITE_FORMATS)
    if ext == ".c3d":
        from mocap.io.c3d import write_c3d
        write_c3d(take, path, inputs=inputs)
    elif ext == ".csv":
        from mocap.io.vicon_csv import write_vicon_csv
        write_vicon_csv(take, path, inputs=inputs)
    elif ext == ".trc":
        from mocap.io.trc import write_trc
        write_trc(take, path, inputs=inputs)
    else:
        from mocap.io.take_npz import write_take_npz
        write_take_npz(take, path, inputs=inputs)
