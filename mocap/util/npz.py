"""The project's own ``.npz`` archives: written from the arrays' own memory, and read
back with every array checked to be one of ours.

:func:`write_npz` writes the archive ``np.savez`` writes (stored members, .npy 1.0
headers) without its copy of every array's bytes, converting an array to the dtype it
is stored in part by part as it goes (no whole converted copy), into a file whose
size is reserved first. The parts are shared among the worker threads: each converts
its part, sums its CRC-32, checks it finite where asked (the caller then needs no pass
of its own) and writes it at its offset, and a member's CRC-32 is combined from its
parts'. The CRC-32 is zlib-ng's where the ``speed`` extra installed it (folded by
carry-less multiplication, five to six times as fast on data in cache; the same value),
else the standard library's, combined then by our own ``crc32_combine``.

One reader for takes, bases, masks, mesh sequences, gesture clips and capture
truths, so that each refuses a foreign or damaged file the same way: the
error names the file and what it should have been, pickled objects are never
loaded, and no member is allocated before its header has been checked against
what the member can hold (its stored bytes, at most 1032 times its compressed
bytes for deflate) and against ``MOCAP2MESH_MAX_BYTES``.
"""

from __future__ import annotations

import functools
import io
import json
import math
import struct
import tokenize
import zipfile
import zlib

import numpy as np

from mocap.errors import FileFormatError
from mocap.util.atomic import preallocate
from mocap.util.blas import worker_threads
from mocap.util.budget import check_allocation
from mocap.util.files import open_input
from mocap.util.parallel_writes import positional_writer, write_parts
from mocap.util.validation import surely_finite

try:                                # the speed extra
    from zlib_ng.zlib_ng import crc32, crc32_combine
except ImportError:
    from zlib import crc32
    crc32_combine = None            # then our own (_crc32_combine)

__all__ = ["read_npz", "read_npz_with_meta", "write_npz", "NotFiniteError"]

#: Deflate never expands data more than this (RFC 1951: 258 bytes per 2 bits, ~1032:1).
_DEFLATE_RATIO = 1032
_COMPRESSIONS = {zipfile.ZIP_STORED: "stored", zipfile.ZIP_DEFLATED: "deflate"}
_HEADERS = {(1, 0): np.lib.format.read_array_header_1_0,
            (2, 0): np.lib.format.read_array_header_2_0}


#: Bytes of a member's values made, summed and written at a time by one worker thread:
#: converted, they are still in the cache when summed and written (the 14 MB mesh
#: sequence of 35,000 frames on 2 threads: 6.0-7.0 ms in parts of 0.5 MB, 6.0-6.5 ms
#: of 2 MB, 6.2-7.0 ms of 4 MB).
_PART_BYTES = 1 << 21
#: Bytes a member takes besides its .npy file and its name: its local header and its
#: central directory entry (30 and 46 bytes, zip64 fields 20 and 28); and the archive's
#: end records (zip64 end record 56, its locator 20, end record 22).
_LOCAL_BYTES, _CENTRAL_BYTES, _END_OVERHEAD = 30 + 20, 46 + 28, 56 + 20 + 22
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
    field, so that one layout holds members of any size. The members' values are
    written in parts of :data:`_PART_BYTES`, shared among the worker threads
    (:func:`mocap.util.parallel_writes.write_parts`); each part is converted, summed
    (CRC-32) and checked by the thread that writes it, and each member's CRC-32, combined
    from its parts', is set in its local header after them.
    """
    store_as, finite = store_as or {}, set(finite)
    arrays = {name: np.asarray(arr) for name, arr in arrays.items()}
    if any(arr.dtype.hasobject for arr in arrays.values()):
        raise ValueError("write_npz stores no Python objects")
    start = offset = fh.tell()
    members = []
    for name, arr in arrays.items():
        members.append(_Member(name, arr, np.dtype(store_as.get(name, arr.dtype)),
                               offset=offset, finite=name in finite))
        offset += members[-1].file_bytes
    preallocate(fh, offset - start + _END_OVERHEAD + sum(
        _CENTRAL_BYTES + len(member.file_name) for member in members))
    write_parts(positional_writer(fh, start),
                [part for member in members for part in member.parts()],
                workers=worker_threads(), part_bytes=_PART_BYTES)
    crcs = [member.crc() for member in members]
    for member, crc in zip(members, crcs):
        fh.seek(member.offset + 14)             # the CRC-32 field of the local header
        fh.write(struct.pack("<I", crc))
    fh.seek(offset)
    _write_directory(fh, [(member.file_name, member.offset, member.size, crc)
                          for member, crc in zip(members, crcs)])
    fh.truncate()                   # where the archive ends (the size reserved)


def _npy_header(shape: tuple, dtype: np.dtype) -> bytes:
    """The .npy 1.0 header (magic, length, padded text) of an array in C order."""
    text = io.BytesIO()
    np.lib.format.write_array_header_1_0(text, {
        "descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False,
        "shape": shape})
    return text.getvalue()


class _Member:
    """One array of an archive: its local header and .npy header, then its values as
    `dtype` in C order, as parts for :func:`mocap.util.parallel_writes.write_parts`: the
    headers' bytes, then the values of a few rows each (of elements where a row is longer
    than a part), converted by the part that writes them where `dtype` is not the
    array's. Each part sums its bytes' CRC-32 and, `finite`, checks its values as it
    is made; :meth:`crc` combines them in order."""

    def __init__(self, name: str, arr: np.ndarray, dtype: np.dtype, *, offset: int,
                 finite: bool):
        self.name, self.arr, self.dtype, self.offset = name, arr, dtype, offset
        self.file_name = (name + ".npy").encode()
        self.header = _npy_header(arr.shape, dtype)
        self.size = len(self.header) + arr.size * dtype.itemsize      # the .npy file's
        self.file_bytes = _LOCAL_BYTES + len(self.file_name) + self.size
        self.check = finite and dtype.kind in "fc"
        self.sums = []          # per part of values: (its CRC-32, its bytes, finite)

    def parts(self) -> list:
        """The member's bytes as (size, bytes or maker) parts, in the file's order."""
        parts = [(self.file_bytes - self.size + len(self.header),
                  _local_header(self.file_name, self.size) + self.header)]
        if not self.arr.size:
            return parts
        rows = self.arr.reshape(-1, self.arr.shape[-1]) if self.arr.ndim else \
            self.arr.reshape(1, 1)
        if rows.shape[1] * self.dtype.itemsize > _PART_BYTES:     # rows longer than a part
            rows = np.ascontiguousarray(self.arr).reshape(-1, 1)
        per_part = max(1, _PART_BYTES // (rows.shape[1] * self.dtype.itemsize))
        for first in range(0, len(rows), per_part):
            part = rows[first:first + per_part]
            self.sums.append(None)
            parts.append((part.size * self.dtype.itemsize,
                          functools.partial(self._made, part, len(self.sums) - 1)))
        return parts

    def _made(self, rows: np.ndarray, index: int, out: np.ndarray) -> memoryview:
        """The bytes of `rows` as stored: their own memory where it is, else converted
        into `out`; summed and checked into ``sums[index]``."""
        if rows.dtype == self.dtype and rows.flags.c_contiguous:
            values = rows.reshape(-1)
        else:
            values = out[:rows.size * self.dtype.itemsize].view(self.dtype)
            with np.errstate(over="ignore"):    # to inf, as astype (checked if asked)
                np.copyto(values.reshape(rows.shape), rows, casting="unsafe")
        ok = not self.check or surely_finite(values) or bool(np.isfinite(values).all())
        self.sums[index] = (crc32(_raw(values)), values.nbytes, ok)
        return _raw(values)

    def crc(self) -> int:
        """The CRC-32 of the member's .npy file, once its parts are written.

        Raises
        ------
        NotFiniteError
            A member checked finite is not.
        """
        combine = crc32_combine or _crc32_combine
        value = crc32(self.header)
        for part_crc, n_bytes, ok in self.sums:
            if not ok:
                raise NotFiniteError(self.name)
            value = combine(value, part_crc, n_bytes)
        return value


def _raw(chunk: np.ndarray) -> memoryview:
    """The bytes of a flat contiguous array, without a copy."""
    return memoryview(chunk.view(np.uint8))


#: The CRC-32 polynomial, bit-reflected (x³² is implied; bit 31 is x⁰).
_CRC_POLYNOMIAL = 0xEDB88320


def _multiply_mod_polynomial(a: int, b: int) -> int:
    """``a(x)·b(x) mod P(x)`` of two bit-reflected CRC-32 polynomials."""
    product, bit = 0, 1 << 31
    while a:
        if a & bit:
            product ^= b
            a ^= bit
        bit >>= 1
        b = (b >> 1) ^ _CRC_POLYNOMIAL if b & 1 else b >> 1
    return product


@functools.lru_cache(maxsize=64)
def _shift_operator(n_bytes: int) -> int:
    """``x^(8·n_bytes) mod P(x)``, bit-reflected: what appending `n_bytes` zero bytes
    multiplies a CRC-32's register by (square and multiply)."""
    result, square, exponent = 1 << 31, 1 << 30, 8 * n_bytes      # x⁰ and x¹
    while exponent:
        if exponent & 1:
            result = _multiply_mod_polynomial(square, result)
        square = _multiply_mod_polynomial(square, square)
        exponent >>= 1
    return result


def _crc32_combine(crc1: int, crc2: int, n_bytes2: int) -> int:
    """The CRC-32 of ``a + b`` from ``crc32(a)``, ``crc32(b)`` and ``len(b)`` (zlib's
    ``crc32_combine``, for a zlib whose Python module does not offer it): the pre- and
    post-conditioning of both cancel, so ``crc(a + b) = crc(a)·x^(8·len(b)) ⊕ crc(b)``
    modulo the CRC's polynomial."""
    return _multiply_mod_polynomial(_shift_operator(n_bytes2), crc1) ^ crc2


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
