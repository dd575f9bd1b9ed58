"""The project's own ``.npz`` archives: written from the arrays' own memory, and read
back with every array checked to be one of ours.

:func:`write_npz` writes the archive ``np.savez`` writes (stored members, .npy 1.0
headers) without its copy of every array's bytes, converting an array to the dtype it
is stored in chunk by chunk as it goes (no whole converted copy), into a file whose
size is reserved first. A second thread sums each member's CRC-32 while its bytes are
written, and checks them finite where asked (the caller then needs no pass of its own).
The CRC-32 is zlib-ng's where the ``speed`` extra installed it (folded by carry-less
multiplication, five to six times as fast on data in cache; the same value), else the
standard library's.

One reader for takes, bases, masks, mesh sequences, gesture clips and capture
truths, so that each refuses a foreign or damaged file the same way: the
error names the file and what it should have been, pickled objects are never
loaded, and no member is allocated before its header has been checked against
what the member can hold (its stored bytes, at most 1032 times its compressed
bytes for deflate) and against ``MOCAP2MESH_MAX_BYTES``.
"""

from __future__ import annotations

import io
import json
import math
import struct
import threading
import tokenize
import zipfile
import zlib
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from mocap.errors import FileFormatError
from mocap.util.atomic import preallocate
from mocap.util.budget import check_allocation
from mocap.util.files import open_input
from mocap.util.validation import surely_finite

try:                                # the speed extra
    from zlib_ng.zlib_ng import crc32
except ImportError:
    from zlib import crc32

__all__ = ["read_npz", "read_npz_with_meta", "write_npz", "NotFiniteError"]

#: Deflate never expands data more than this (RFC 1951: 258 bytes per 2 bits, ~1032:1).
_DEFLATE_RATIO = 1032
_COMPRESSIONS = {zipfile.ZIP_STORED: "stored", zipfile.ZIP_DEFLATED: "deflate"}
_HEADERS = {(1, 0): np.lib.format.read_array_header_1_0,
            (2, 0): np.lib.format.read_array_header_2_0}


#: Bytes of one chunk of an array handed to the helper thread (each hand-over costs a
#: thread's wake-up; smaller members are summed where they are written), and of each of
#: the two conversion buffers a writing thread keeps.
_CHUNK_BYTES = 1 << 22
#: Bytes a member takes besides its .npy file: its local header and central directory
#: entry (30 and 46 bytes, the name each, zip64 fields 20 and 28), and the archive's end
#: records (zip64 end record 56, its locator 20, end record 22).
_MEMBER_OVERHEAD, _END_OVERHEAD = 30 + 20 + 46 + 28, 56 + 20 + 22
#: Zip records (APPNOTE 6.3): signatures, "version needed" 4.5 (zip64), made on Unix,
#: names in UTF-8, member files -rw-------, and the DOS time 1980-01-01 00:00 (the
#: same archive for the same arrays).
_LOCAL, _CENTRAL, _END64, _LOCATOR64, _END = (
    b"PK\x03\x04", b"PK\x01\x02", b"PK\x06\x06", b"PK\x06\x07", b"PK\x05\x06")
_VERSION, _MADE_BY, _UTF8_NAMES = 45, (3 << 8) | 45, 1 << 11
_ATTRIBUTES, _DOS_DATE = 0o600 << 16, (1 << 5) | 1
_UNKNOWN32, _UNKNOWN16 = 0xFFFF_FFFF, 0xFFFF


class NotFiniteError(ValueError):
    """A member :func:`write_npz` was to store finite holds a NaN or an infinite value
    as it is stored (e.g. a float64 beyond float32's range)."""

    def __init__(self, member: str):
        super().__init__(f"member {member!r} holds NaN or infinite values as stored")
        self.member = member


def write_npz(fh, arrays: dict, *, store_as: dict | None = None, finite=()) -> None:
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
    finite : iterable of str, optional
        Members whose stored values must all be finite, checked as they are written
        (no pass over the arrays of its own).

    Raises
    ------
    ValueError
        An object array (nothing is written).
    NotFiniteError
        A member of `finite` is not (the file is left incomplete: write it to a
        temporary file).

    Notes
    -----
    Read back by ``np.load`` and :func:`read_npz` as ``np.savez``'s archive: the
    members hold the same bytes (arrays in C order). Every size and offset is a zip64
    field, so that one layout holds members of any size. The CRC-32 of each member is
    computed on a second thread while its bytes are written (both release the GIL),
    and set in its local header after them.
    """
    store_as, finite = store_as or {}, set(finite)
    arrays = {name: np.asarray(arr) for name, arr in arrays.items()}
    if any(arr.dtype.hasobject for arr in arrays.values()):
        raise ValueError("write_npz stores no Python objects")
    dtypes = {name: np.dtype(store_as.get(name, arr.dtype)) for name, arr in arrays.items()}
    headers = {name: _npy_header(arr.shape, dtypes[name]) for name, arr in arrays.items()}
    total = _END_OVERHEAD + sum(
        _MEMBER_OVERHEAD + 2 * len((name + ".npy").encode()) + len(headers[name])
        + arr.size * dtypes[name].itemsize for name, arr in arrays.items())
    preallocate(fh, total)
    with ThreadPoolExecutor(1, thread_name_prefix="npz-crc32") as helper:
        archive = _Archive(fh, helper)
        for name, arr in arrays.items():
            archive.add(name, arr, headers[name], dtypes[name], finite=name in finite)
        archive.finish()
    fh.truncate()                   # where the archive ends (the size reserved)


def _npy_header(shape: tuple, dtype: np.dtype) -> bytes:
    """The .npy 1.0 header (magic, length, padded text) of an array in C order."""
    text = io.BytesIO()
    np.lib.format.write_array_header_1_0(text, {
        "descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False,
        "shape": shape})
    return text.getvalue()


class _Archive:
    """The members of an archive being written to `fh`: the bytes of each go to the file
    while the `helper` thread sums their CRC-32 (and checks them finite if asked); the
    CRCs are set in the local headers at the end, then the central directory written.

    An array stored in another dtype is converted by chunks of rows into two buffers
    in turn, each refilled once the helper has summed it.
    """

    def __init__(self, fh, helper):
        self.fh, self.helper, self.members = fh, helper, []
        self.summing = []                   # futures, in the order handed over
        self.buffers, self.in_buffer = _thread_buffers(), [None, None]

    def add(self, name: str, arr: np.ndarray, header: bytes, dtype: np.dtype, *,
            finite: bool) -> None:
        """Write the member `name`: its local header, the .npy `header`, then `arr` as
        `dtype` in C order."""
        file_name, offset = (name + ".npy").encode(), self.fh.tell()
        size = len(header) + arr.size * dtype.itemsize
        crc = _RunningCrc(crc32(header), check=finite and dtype.kind in "fc")
        self.members.append((name, file_name, offset, size, crc))
        self.fh.write(_local_header(file_name, size))
        self.fh.write(header)
        if size <= _CHUNK_BYTES:            # summed here: a hand-over would cost more
            with np.errstate(over="ignore"):    # to inf, as astype (checked if asked)
                chunk = np.ascontiguousarray(arr, dtype).reshape(-1)
            crc.update(chunk)
            self.fh.write(_raw(chunk))
        elif arr.dtype == dtype and arr.flags.c_contiguous:
            self.summing.append(self.helper.submit(crc.update, arr.reshape(-1)))
            self.fh.write(_raw(arr.reshape(-1)))
        else:
            for slot, chunk in self._converted(arr, dtype):
                self.in_buffer[slot] = self.helper.submit(crc.update, chunk)
                self.summing.append(self.in_buffer[slot])
                self.fh.write(_raw(chunk))

    def _converted(self, arr: np.ndarray, dtype: np.dtype):
        """(buffer index, chunk) of `arr` as `dtype` in C order, flat, chunk by chunk."""
        rows = arr.reshape(-1, arr.shape[-1])
        if rows.shape[1] * dtype.itemsize > _CHUNK_BYTES:  # rows longer than a chunk
            rows = np.ascontiguousarray(arr).reshape(-1, 1)
        per_chunk = max(1, _CHUNK_BYTES // max(1, rows.shape[1] * dtype.itemsize))
        for first in range(0, len(rows), per_chunk):
            slot = len(self.summing) % 2
            if self.in_buffer[slot] is not None:
                self.in_buffer[slot].result()
            part = rows[first:first + per_chunk]
            chunk = self.buffers[slot][:part.size * dtype.itemsize].view(dtype)
            with np.errstate(over="ignore"):
                np.copyto(chunk.reshape(part.shape), part, casting="unsafe")
            yield slot, chunk

    def finish(self) -> None:
        """Set each member's CRC-32 in its local header and write the central directory.

        Raises
        ------
        NotFiniteError
            A member checked finite is not.
        """
        for future in self.summing:
            future.result()
        for name, *_, crc in self.members:
            if crc.value is None:
                raise NotFiniteError(name)
        end = self.fh.tell()
        for _, _, offset, _, crc in self.members:
            self.fh.seek(offset + 14)       # the CRC-32 field of the local header
            self.fh.write(struct.pack("<I", crc.value))
        self.fh.seek(end)
        _write_directory(self.fh, [(file_name, offset, size, crc.value)
                                   for _, file_name, offset, size, crc in self.members])


_kept = threading.local()


def _thread_buffers() -> list:
    """The calling thread's two conversion buffers of `_CHUNK_BYTES`, kept between
    archives (their pages are touched once, not by every archive)."""
    if getattr(_kept, "buffers", None) is None or len(_kept.buffers[0]) < _CHUNK_BYTES:
        _kept.buffers = [np.empty(_CHUNK_BYTES, np.uint8) for _ in range(2)]
    return _kept.buffers


def _raw(chunk: np.ndarray) -> memoryview:
    """The bytes of a flat contiguous array, without a copy."""
    return memoryview(chunk.view(np.uint8))


class _RunningCrc:
    """CRC-32 of a member's chunks, summed in order; None once a chunk checked finite
    holds a NaN or an infinite value (told by its sum, exactly checked if it overflows)."""

    def __init__(self, crc: int, *, check: bool):
        self.value, self.check = crc, check

    def update(self, chunk: np.ndarray) -> None:
        if self.value is None:
            return
        if self.check and not (surely_finite(chunk) or np.isfinite(chunk).all()):
            self.value = None
            return
        self.value = crc32(_raw(chunk), self.value)


def _local_header(name: bytes, size: int) -> bytes:
    """A stored member's local header, its sizes in the zip64 extra field, its CRC-32 zero
    (set once the data is summed: :meth:`_Archive.finish`)."""
    return (_LOCAL + struct.pack("<HHHHHIIIHH", _VERSION, _UTF8_NAMES, zipfile.ZIP_STORED, 0,
                                 _DOS_DATE, 0, _UNKNOWN32, _UNKNOWN32, len(name), 20)
            + name + struct.pack("<HHQQ", 1, 16, size, size))


def _write_directory(fh, entries: list) -> None:
    """The central directory of `entries` (sizes and offsets in zip64 extra fields)
    and the zip64 and classic end records."""
    start = fh.tell()
    for name, offset, size, crc in entries:
        fh.write(_CENTRAL + struct.pack(
            "<HHHHHHIIIHHHHHII", _MADE_BY, _VERSION, _UTF8_NAMES, zipfile.ZIP_STORED, 0, _DOS_DATE,
            crc, _UNKNOWN32, _UNKNOWN32, len(name), 28, 0, 0, 0, _ATTRIBUTES, _UNKNOWN32)
            + name + struct.pack("<HHQQQ", 1, 24, size, size, offset))
    end = fh.tell()
    fh.write(_END64 + struct.pack("<QHHIIQQQQ", 44, _MADE_BY, _VERSION, 0, 0, len(entries),
                                  len(entries), end - start, start))
    fh.write(_LOCATOR64 + struct.pack("<IQI", 0, end, 1))
    fh.write(_END + struct.pack("<HHHHIIH", 0, 0, _UNKNOWN16, _UNKNOWN16, _UNKNOWN32,
                                _UNKNOWN32, 0))


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
