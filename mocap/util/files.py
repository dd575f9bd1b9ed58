"""Reading input files: one place that turns OS, path and encoding errors into ours.

Every reader opens its file through :func:`read_input_bytes`,
:func:`read_input_text` or :func:`mapped_input`, so a missing file, a directory, a permission
problem, a name too long for the file system, a NUL in the path, a file
larger than ``MOCAP2MESH_MAX_BYTES`` or text that is not UTF-8 all end in a
:class:`~mocap.errors.FileFormatError` naming the file (and, for text, the
byte where decoding failed).
"""

from __future__ import annotations

import mmap
import os
from contextlib import contextmanager
from pathlib import Path

from mocap.errors import FileFormatError, InputError
from mocap.util.budget import check_allocation

__all__ = ["as_path", "open_input", "mapped_input", "read_input_bytes", "read_input_text"]


def as_path(path, name: str = "path") -> Path:
    """`path` as a Path, refusing what no file system accepts.

    Raises
    ------
    InputError
        Not a str or os.PathLike, empty, or holding a NUL character.

    Examples
    --------
    >>> as_path("take.c3d")
    PosixPath('take.c3d')
    >>> as_path("a\\0b")
    Traceback (most recent call last):
    ...
    mocap.errors.InputError: path 'a\\x00b' holds a NUL character (no file name may)
    """
    if not isinstance(path, (str, os.PathLike)):
        raise InputError(f"{name} must be a str or os.PathLike, got {type(path).__name__}")
    text = os.fspath(path)
    if isinstance(text, bytes):
        text = os.fsdecode(text)
    if not text:
        raise InputError(f"{name} is empty")
    if "\0" in text:
        raise InputError(f"{name} {text!r} holds a NUL character (no file name may)")
    return Path(text)


def _open(path, what: str):
    """`path` opened for binary reading, every failure a FileFormatError naming it."""
    try:
        path = as_path(path)
    except InputError as exc:
        shown = repr(os.fspath(path)) if isinstance(path, (str, os.PathLike)) else None
        raise FileFormatError(shown, f"cannot read {what}: {exc}") from None
    try:
        return open(path, "rb")
    except IsADirectoryError:
        raise FileFormatError(path, f"cannot read {what}: it is a directory") from None
    except FileNotFoundError:
        raise FileFormatError(path, f"cannot read {what}: no such file") from None
    except OSError as exc:
        raise FileFormatError(path, f"cannot read {what}: {exc.strerror or exc}") from None


def open_input(path, what: str):
    """Open an input file for binary reading (a file object the caller closes).

    Parameters
    ----------
    path : str or os.PathLike
    what : str
        What the file should hold ("C3D file", "mesh"...), for the errors.

    Raises
    ------
    FileFormatError
        No such file, a directory, unreadable (permissions, name too long, I/O
        error), a NUL in the name, or larger than ``MOCAP2MESH_MAX_BYTES``.
    """
    fh = _open(path, what)
    try:
        size = os.fstat(fh.fileno()).st_size
        check_allocation(path, f"reading the {what} ({size} bytes)", size)
    except BaseException:
        fh.close()
        raise
    return fh


@contextmanager
def mapped_input(path, what: str):
    """An input file's bytes as a read-only memory map (``b""`` for an empty file).

    Only the pages that are read come into memory, so the file's size is not
    held against ``MOCAP2MESH_MAX_BYTES``: the reader checks what it decodes.

    Raises
    ------
    FileFormatError
        As :func:`open_input`, but for the size.
    """
    with _open(path, what) as fh:
        try:
            buf = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
        except ValueError:                  # an empty file cannot be mapped
            yield b""
            return
        except OSError as exc:
            raise FileFormatError(path, f"cannot read {what}: {exc.strerror or exc}") from None
    try:
        yield buf
    finally:
        try:
            buf.close()
        except BufferError:     # a view is still held (by a traceback): unmapped when freed
            pass


def read_input_bytes(path, what: str) -> bytes:
    """The bytes of an input file.

    Raises
    ------
    FileFormatError
        As :func:`open_input`, or reading fails (I/O error).
    """
    with open_input(path, what) as fh:
        try:
            return fh.read()
        except OSError as exc:
            raise FileFormatError(path, f"cannot read {what}: {exc.strerror or exc}") from None


def read_input_text(path, what: str) -> str:
    """The text of a UTF-8 input file (a leading byte-order mark is dropped).

    Raises
    ------
    FileFormatError
        As :func:`read_input_bytes`, or the bytes are not UTF-8 (naming the byte).
    """
    raw = read_input_bytes(path, what)
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise FileFormatError(path, f"{what} is not UTF-8 text ({exc.reason}: byte "
                                    f"{raw[exc.start]:#04x})", offset=exc.start) from None
