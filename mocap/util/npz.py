"""Reading the project's own ``.npz`` archives: every array, checked to be one of ours.

One reader for takes, bases, masks, mesh sequences, gesture clips and capture
truths, so that each refuses a foreign or damaged file the same way: the
error names the file and what it should have been, pickled objects are never
loaded, and no member is allocated before its header has been checked against
what the member can hold (its stored bytes, at most 1032 times its compressed
bytes for deflate) and against ``MOCAP2MESH_MAX_BYTES``.
"""

from __future__ import annotations

import json
import math
import tokenize
import zipfile
import zlib

import numpy as np

from mocap.errors import FileFormatError
from mocap.util.budget import check_allocation
from mocap.util.files import open_input

__all__ = ["read_npz", "read_npz_with_meta"]

#: Deflate never expands data more than this (RFC 1951: 258 bytes per 2 bits, ~1032:1).
_DEFLATE_RATIO = 1032
_COMPRESSIONS = {zipfile.ZIP_STORED: "stored", zipfile.ZIP_DEFLATED: "deflate"}
_HEADERS = {(1, 0): np.lib.format.read_array_header_1_0,
            (2, 0): np.lib.format.read_array_header_2_0}


def _capacity(info: zipfile.ZipInfo) -> int:
    """Most bytes a member can decompress to."""
    if info.compress_type == zipfile.ZIP_STORED:
        return min(info.file_size, info.compress_size)
    return min(info.file_size, _DEFLATE_RATIO * info.compress_size)


def _member_header(archive: zipfile.ZipFile, info: zipfile.ZipInfo, path, what: str):
    """(shape, fortran order, dtype) of an array member, checked against its capacity."""
    name = info.filename
    if not name.endswith(".npy"):
        raise FileFormatError(path, f"not a {what}: member {name!r} is not a NumPy array "
                                    "(.npy)")
    if info.flag_bits & 0x1:
        raise FileFormatError(path, f"not a {what}: member {name!r} is encrypted")
    if info.compress_type not in _COMPRESSIONS:
        raise FileFormatError(path, f"not a {what}: member {name!r} uses compression method "
                                    f"{info.compress_type}; expected stored or deflate")
    with archive.open(info) as member:
        version = np.lib.format.read_magic(member)
        if version not in _HEADERS:
            raise FileFormatError(path, f"not a {what}: member {name!r} is a .npy file of "
                                        f"version {version}; expected 1.0 or 2.0")
        shape, fortran, dtype = _HEADERS[version](member)
        header = member.tell()
    if dtype.hasobject:
        raise FileFormatError(path, f"not a {what}: member {name!r} holds Python objects, "
                                    "which are never unpickled")
    n_bytes = math.prod(shape) * dtype.itemsize
    if n_bytes > _capacity(info) - header:
        raise FileFormatError(path, f"not a {what}: member {name!r} claims shape "
                                    f"{shape} of {dtype} ({n_bytes} bytes), more than it "
                                    f"holds (at most {max(0, _capacity(info) - header)})")
    return n_bytes


def _read_members(fh, path, what: str) -> dict:
    with zipfile.ZipFile(fh) as archive:
        infos = {info.filename: info for info in archive.infolist()}
        sizes = {name: _member_header(archive, info, path, what)
                 for name, info in infos.items()}
        check_allocation(path, f"the {len(sizes)} arrays of the {what}", sum(sizes.values()))
        arrays = {}
        for name, info in infos.items():
            with archive.open(info) as member:
                arrays[name[:-4]] = np.lib.format.read_array(member, allow_pickle=False)
    return arrays


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
        The file is missing, not an archive, damaged, holds pickled objects or a
        member that is not an array, has a member whose header claims more
        than the member holds, would take more than ``MOCAP2MESH_MAX_BYTES``,
        lacks a required member or is of another format.

    Examples
    --------
    >>> import tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "a.npz")
    >>> np.savez(path, format_version=1, x=np.arange(3))
    >>> sorted(read_npz(path, "test archive", required=["x"], version=("format_version", 1)))
    ['format_version', 'x']
    """
    with open_input(path, what) as fh:
        try:
            arrays = _read_members(fh, path, what)
        except FileFormatError:
            raise
        except (OSError, ValueError, EOFError, RuntimeError, SyntaxError, tokenize.TokenError,
                zlib.error, zipfile.BadZipFile, zipfile.LargeZipFile) as exc:
            # (numpy tokenizes a .npy header of format 1.0 as Python: a damaged one can end
            # in a TokenError or SyntaxError)
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
    except (ValueError, RecursionError) as exc:
        raise FileFormatError(path, f"not a {what}: its meta is not JSON ({exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != format:
        found = meta.get("format") if isinstance(meta, dict) else None
        raise FileFormatError(path, f"not a {what} (format {found!r}, expected {format!r})")
    return meta, arrays
