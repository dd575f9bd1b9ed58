"""The project's own ``.npz`` archives: written from the arrays' own memory, and read
back with every array checked to be one of ours.

:func:`write_npz` writes what ``np.savez`` writes (stored members, zip64 headers, .npy
1.0 headers) without its copy of every array's bytes, converting an array to the dtype
it is stored in block by block as it goes (no whole converted copy), into a file whose
size is reserved first.

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
from mocap.util.atomic import preallocate
from mocap.util.budget import check_allocation
from mocap.util.files import open_input

__all__ = ["read_npz", "read_npz_with_meta", "write_npz"]

#: Deflate never expands data more than this (RFC 1951: 258 bytes per 2 bits, ~1032:1).
_DEFLATE_RATIO = 1032
_COMPRESSIONS = {zipfile.ZIP_STORED: "stored", zipfile.ZIP_DEFLATED: "deflate"}
_HEADERS = {(1, 0): np.lib.format.read_array_header_1_0,
            (2, 0): np.lib.format.read_array_header_2_0}


#: Bytes of one block of an array converted as it is written (a few fit in the L2 cache).
_BLOCK_BYTES = 1 << 18
#: Bytes a stored member takes besides its .npy file, at most: the local header with its
#: zip64 extra field and the central directory entry (each 46 bytes + name + 28 extra),
#: and the end records; the file is cut to what was written.
_MEMBER_OVERHEAD, _END_OVERHEAD = 2 * (46 + 28), 22 + 56 + 20


def write_npz(fh, arrays: dict, *, store_as: dict | None = None) -> None:
    """Write `arrays` as an ``.npz`` archive to the binary file `fh`, as ``np.savez``.

    Parameters
    ----------
    fh : file object
        Open for writing, seekable, empty (a new temporary file).
    arrays : dict of str to array_like
        Member names (without ``.npy``) to arrays; no object arrays.
    store_as : dict of str to dtype, optional
        Members stored in another dtype than their array's (e.g. float64 weights as
        float32), converted as NumPy's ``astype`` does.

    Raises
    ------
    ValueError
        An object array (nothing is written).

    Notes
    -----
    Read back by ``np.load`` and :func:`read_npz` as ``np.savez``'s archive; arrays
    are stored in C order.
    """
    store_as = store_as or {}
    arrays = {name: np.asarray(arr) for name, arr in arrays.items()}
    if any(arr.dtype.hasobject for arr in arrays.values()):
        raise ValueError("write_npz stores no Python objects")
    dtypes = {name: np.dtype(store_as.get(name, arr.dtype)) for name, arr in arrays.items()}
    headers = {name: {"descr": np.lib.format.dtype_to_descr(dtypes[name]),
                      "fortran_order": False, "shape": arr.shape}
               for name, arr in arrays.items()}
    total = _END_OVERHEAD + sum(      # .npy headers: magic and length, text padded to 64
        _MEMBER_OVERHEAD + 2 * len(name.encode()) + 10 + len(repr(headers[name])) + 64
        + arr.size * dtypes[name].itemsize
        for name, arr in arrays.items())
    preallocate(fh, total)
    with zipfile.ZipFile(fh, "w", zipfile.ZIP_STORED, allowZip64=True) as archive:
        for name, arr in arrays.items():
            with archive.open(name + ".npy", "w", force_zip64=True) as member:
                _write_member(member, arr, headers[name], dtypes[name])
    fh.truncate()                   # to what was written, less than the size reserved


def _write_member(member, arr: np.ndarray, header: dict, dtype: np.dtype) -> None:
    """The .npy file of `arr` with `header`: the header, then the data in C order, as
    `dtype` by blocks of rows converted into one reused buffer when it differs."""
    np.lib.format.write_array_header_1_0(member, header)
    if arr.size == 0:
        return
    if arr.dtype == dtype and arr.flags.c_contiguous:
        member.write(memoryview(arr.reshape(-1).view(np.uint8)))
        return
    rows = arr.reshape(len(arr), -1) if arr.ndim else arr.reshape(1, 1)
    per_block = max(1, _BLOCK_BYTES // max(1, rows.shape[1] * dtype.itemsize))
    block = np.empty((min(per_block, len(rows)), rows.shape[1]), dtype)
    for first in range(0, len(rows), per_block):
        part = block[:len(rows) - first]
        np.copyto(part, rows[first:first + len(part)], casting="unsafe")
        member.write(memoryview(part.reshape(-1).view(np.uint8)))


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
