"""The project's error types.

Every error raised on bad input derives from :class:`Mocap2MeshError`, so a
caller (and the CLI) can tell "your input is wrong" from a bug. Each names
the thing at fault: a file with a byte offset or line, a marker with frames,
or an argument.
"""

from __future__ import annotations

import os

__all__ = ["Mocap2MeshError", "FileFormatError", "MarkerError", "InputError",
           "MissingDependencyError"]


class Mocap2MeshError(Exception):
    """Base class of every error that mocap2mesh raises on bad input.

    Errors pickle with their type, message and attributes (an error raised in a helper
    process reaches the caller as itself), whatever their constructor takes.
    """

    def __reduce__(self):
        return _rebuilt, (type(self), self.args, self.__dict__)


def _rebuilt(cls, args: tuple, attributes: dict) -> Mocap2MeshError:
    """An error of type `cls` with `args` and `attributes`, without calling its constructor."""
    error = Exception.__new__(cls)
    error.args = args
    error.__dict__.update(attributes)
    return error


class InputError(Mocap2MeshError, ValueError):
    """An argument has the wrong shape, type, units or value."""


class FileFormatError(Mocap2MeshError, ValueError):
    """A file is empty, truncated, corrupt, or not of the format expected.

    Parameters
    ----------
    path : str or os.PathLike
        The file at fault.
    message : str
        What is wrong and what was expected.
    offset : int, optional
        Byte offset (0-based) where the problem was found, for binary files.
    line : int, optional
        Line number (1-based) where the problem was found, for text files.
    """

    def __init__(self, path, message: str, *, offset: int | None = None,
                 line: int | None = None):
        self.path = os.fspath(path) if path is not None else None
        self.offset = offset
        self.line = line
        where = ""
        if offset is not None:
            where = f" at byte {offset}"
        elif line is not None:
            where = f" at line {line}"
        super().__init__(f"{self.path}{where}: {message}")


class MarkerError(Mocap2MeshError, ValueError):
    """A marker is unknown, missing where it is needed, or inconsistent.

    Parameters
    ----------
    marker : str
        The label of the marker at fault.
    message : str
        What is wrong, ideally with the frames concerned.
    """

    def __init__(self, marker: str, message: str):
        self.marker = marker
        super().__init__(f"marker {marker!r}: {message}")


class MissingDependencyError(Mocap2MeshError, ImportError):
    """A feature needs a package of an optional extra that is not installed.

    Parameters
    ----------
    package : str
        The distribution missing (``praat-parselmouth``).
    extra : str
        The extra of mocap2mesh that installs it (``speech``).
    purpose : str
        What it is needed for, said in the message.
    """

    def __init__(self, package: str, extra: str, purpose: str):
        self.package = package
        self.extra = extra
        super().__init__(f"{purpose} needs {package}, which is not installed: "
                         f"pip install 'mocap2mesh[{extra}]'")
