"""Reading the project's own ``.npz`` archives: every array, checked to be one of ours.

One reader for takes, bases, masks, mesh sequences, gesture clips and capture
truths, so that each refuses a foreign or damaged file the same way: the
error names the file and what it should have been, pickled objects are never
loaded.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from mocap.errors import FileFormatError

__all__ = ["read_npz", "read_npz_with_meta"]


def read_npz(path, what: str, *, required=(), version: tuple | None = None) -> dict:
    """All arrays of an ``.npz`` archive, with its kind checked.

    Parameters
    ----------
    path : str or os.PathLike
    what : str
        What the archive holds ("basis archive", "mask", ...), for the errors.
    required : sequence of str
        Members that must be there.
    version : (str, object), optional
        A member naming the format, and the value this reader knows (compared
        as text: a format string or a version number).

    Returns
    -------
    dict of str to ndarray

    Raises
    ------
    FileFormatError
        The file is missing, not an archive, damaged, holds pickled objects,
        lacks a required member or is of another format.

    Examples
    --------
    >>> import tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "a.npz")
    >>> np.savez(path, format_version=1, x=np.arange(3))
    >>> sorted(read_npz(path, "test archive", required=["x"], version=("format_version", 1)))
    ['format_version', 'x']
    """
    path = Path(path)
    if not path.exists():
        raise FileFormatError(path, "no such file")
    try:
        with np.load(path, allow_pickle=False) as archive:
            arrays = {name: archive[name] for name in archive.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise FileFormatError(path, f"cannot read {what}: {exc}") from None
    absent = [name for name in required if name not in arrays]
    if absent:
        raise FileFormatError(path, f"not a {what}: members {', '.join(absent)} missing")
    if version is not None:
        key, expected = version
        found = str(arrays[key]) if key in arrays else None
        if found != str(expected):
            raise FileFormatError(path, f"not a {what} this program reads ({key} {found!r}, "
                                        f"expected {str(expected)!r})")
    return arrays


def read_npz_with_meta(path, what: str, format: str, *, required=()) -> tuple[dict, dict]:
    """An archive whose ``meta`` member is a JSON object naming its `format`.

    Returns
    -------
    meta : dict
        The parsed ``meta``.
    arrays : dict of str to ndarray
        Every other member.

    Raises
    ------
    FileFormatError
        As :func:`read_npz`; ``meta`` not a JSON object, or of another format.
    """
    arrays = read_npz(path, what, required=("meta", *required))
    try:
        meta = json.loads(str(arrays.pop("meta")))
    except ValueError as exc:
        raise FileFormatError(path, f"not a {what}: its meta is not JSON ({exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != format:
        found = meta.get("format") if isinstance(meta, dict) else None
        raise FileFormatError(path, f"not a {what} (format {found!r}, expected {format!r})")
    return meta, arrays
