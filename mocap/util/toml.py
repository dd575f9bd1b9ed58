"""Reading the project's small TOML files (marker sets, layouts, landmarks, configs)."""

from __future__ import annotations

import sys
from pathlib import Path

from mocap.errors import FileFormatError

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
        The file cannot be read, is not UTF-8, or is not valid TOML.
    """
    path = Path(path)
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise FileFormatError(path, f"cannot read {what}: {exc.strerror}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise FileFormatError(path, f"{what} is not valid TOML: {exc}") from None
