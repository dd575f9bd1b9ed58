"""Reading the project's small TOML files (marker sets, layouts, landmarks, configs)."""

from __future__ import annotations

import sys

from mocap.errors import FileFormatError
from mocap.util.files import read_input_text

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["read_toml"]


def read_toml(path, what: str) -> dict:
    """Parse a TOML file; errors name the file and say what it should have been.

    Parameters
    ----------
    path : str or os.PathLike
    what : str
        What the file holds ("marker set", "layout", ...), for the error message.

    Raises
    ------
    FileFormatError
        The file cannot be read (see :func:`mocap.util.files.read_input_bytes`),
        is not UTF-8, is not valid TOML, or nests arrays or tables too deeply
        to parse.
    """
    text = read_input_text(path, what)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise FileFormatError(path, f"{what} is not valid TOML: {exc}") from None
    except RecursionError:
        raise FileFormatError(path, f"{what} nests arrays or tables too deeply to "
                                    "parse") from None
