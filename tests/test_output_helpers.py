"""Helpers of the binary writers: column extremes by halving, preallocated files, parts
written by threads at their offsets, npz."""

from __future__ import annotations

import errno
import functools
import os
import shutil
import struct
import subprocess
import threading
import zipfile
import zlib

import numpy as np
import pytest

from mocap.util import npz
from mocap.util.atomic import preallocate
from mocap.util.extremes import column_extremes
from mocap.util.parallel_writes import positional_writer, write_parts


@pytest.mark.parametrize("shape", [(1, 3), (2, 3), (3, 1), (7, 5), (1000, 53), (1023, 3),
                                   (4, 9409, 3), (3, 1, 2), (5, 2, 2), (2, 3, 17, 4),
                                   (70, 64), (33, 65), (129, 1), (0, 5, 3), (5, 2, 0)])
def test_column_extremes_are_numpys(shape):
    """Every row count (odd ones fold their last row in), batches of tables alike, empty
    ones too."""
    rng = np.random.default_rng(sum(shape))
    arr = rng.normal(size=shape)
    low, high = column_extremes(arr)
    np.testing.assert_array_equal(low, arr.min(axis=-2))
    np.testing.assert_array_equal(high, arr.max(axis=-2))
    assert low.shape == high.shape == shape[:-2] + shape[-1:]
    assert low.dtype == high.dtype == arr.dtype


@pytest.mark.parametrize("where", [(0, 0), (0, 2), (37, 1), (88, 2), (100, 0)])
def test_column_extremes_of_nan_anywhere(where):
    """A NaN in the first row, the last, an odd one folded in or any other makes its
    column's min and max NaN, and no other column's."""
    arr = np.random.default_rng(sum(where)).normal(size=(101, 3))
    arr[where] = np.nan
    low, high = column_extremes(arr)
    expected = [j == where[1] for j in range(3)]
    assert np.isnan(low).tolist() == np.isnan(high).tolist() == expected
    np.testing.assert_array_equal(low, arr.min(axis=0))
    np.testing.assert_array_equal(high, arr.max(axis=0))


def test_column_extremes_of_float32_and_nan_and_views():
    """A NaN makes its column's extremes NaN (those of the glTF writer's checks)."""
    rng = np.random.default_rng(0)
    arr = rng.normal(size=(101, 4)).astype(np.float32)
    arr[37, 2] = arr[88, 1] = np.nan
    low, high = column_extremes(arr[::2])                 # a strided view, read not copied
    assert low.dtype == np.float32
    np.testing.assert_array_equal(low, arr[::2].min(axis=0))
    np.testing.assert_array_equal(high, arr[::2].max(axis=0))
    assert np.isnan(low).tolist() == np.isnan(high).tolist() == [False, True, False, False]
    before = arr.copy()
    low, high = column_extremes(arr)
    np.testing.assert_array_equal(low, arr.min(axis=0))
    np.testing.assert_array_equal(high, arr.max(axis=0))
    np.testing.assert_array_equal(arr, before)             # the input is left as it was


def test_column_extremes_need_a_row():
    with pytest.raises(ValueError, match="at least one row"):
        column_extremes(np.zeros((0, 3)))


def test_preallocated_file_holds_what_is_written(tmp_path):
    """The reserved size is the file's size once exactly that much is written."""
    data = np.arange(100_000, dtype=np.float32)
    with open(tmp_path / "a.bin", "wb") as fh:
        preallocate(fh, data.nbytes)
        fh.write(memoryview(data).cast("B"))
    np.testing.assert_array_equal(np.fromfile(tmp_path / "a.bin", np.float32), data)
    assert os.path.getsize(tmp_path / "a.bin") == data.nbytes


def test_preallocation_that_the_file_system_refuses_is_skipped(tmp_path, monkeypatch):
    def unsupported(fd, offset, length):
        raise OSError(errno.EOPNOTSUPP, "Operation not supported")

    def full(fd, offset, length):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "posix_fallocate", unsupported)
    with open(tmp_path / "b.bin", "wb") as fh:
        preallocate(fh, 10)
        fh.write(b"0123456789")
    assert (tmp_path / "b.bin").read_bytes() == b"0123456789"
    monkeypatch.setattr(os, "posix_fallocate", full)
    with open(tmp_path / "c.bin", "wb") as fh, pytest.raises(OSError, match="No space"):
        preallocate(fh, 10)


def _parts(sizes, made=None):
    """Parts of :func:`write_parts` of `sizes` bytes, bytes and made ones in turn, and
    the bytes they hold one after another; a made part's index goes to `made`."""
    rng = np.random.default_rng(len(sizes))
    blobs = [rng.integers(0, 256, size, dtype=np.uint8) for size in sizes]

    def make(i, out):
        out[:sizes[i]] = blobs[i]
        if made is not None:
            made.append(i)
        return memoryview(out[:sizes[i]])
    parts = [(size, blob.tobytes() if i % 2 else functools.partial(make, i))
             for i, (size, blob) in enumerate(zip(sizes, blobs))]
    return parts, b"".join(blob.tobytes() for blob in blobs)


@pytest.mark.parametrize("workers", [1, 2, 3, 9])
def test_parts_are_written_at_their_offsets_on_any_threads(tmp_path, workers):
    """After a header written by the file object, on as many threads as asked (more
    than there are parts too): the file holds the parts in order, the file object's
    position is where it was."""
    parts, expected = _parts([5, 1000, 0, 4096, 7, 333, 4096, 1])
    with open(tmp_path / "a.bin", "wb") as fh:
        fh.write(b"head")
        assert write_parts(positional_writer(fh, fh.tell()), parts, workers=workers,
                           part_bytes=4096) == len(expected)
        assert fh.tell() == 4
    assert (tmp_path / "a.bin").read_bytes() == b"head" + expected


def test_a_write_that_takes_fewer_bytes_is_carried_on(tmp_path, monkeypatch):
    parts, expected = _parts([10, 2000, 3])
    real = os.pwrite
    monkeypatch.setattr(os, "pwrite", lambda fd, data, at: real(fd, bytes(data[:7]), at))
    with open(tmp_path / "a.bin", "wb") as fh:
        write_parts(positional_writer(fh, 0), parts, workers=2, part_bytes=2000)
    assert (tmp_path / "a.bin").read_bytes() == expected


def test_parts_are_written_where_there_is_no_pwrite(tmp_path, monkeypatch):
    """Without ``os.pwrite`` (Windows), the parts are written by seeks and writes, one
    thread at a time: the same file."""
    parts, expected = _parts([5, 1000, 0, 4096, 7, 333, 4096, 1])
    monkeypatch.delattr(os, "pwrite")
    with open(tmp_path / "a.bin", "wb") as fh:
        fh.write(b"head")
        write_parts(positional_writer(fh, fh.tell()), parts, workers=3, part_bytes=4096)
    assert (tmp_path / "a.bin").read_bytes() == b"head" + expected


def test_a_failed_part_stops_the_file_once_every_thread_is_done(tmp_path):
    """The error of a part's making is raised after the other threads have stopped: no
    part is made behind it. A part of another size than announced is an error."""
    made = []
    parts, _ = _parts([100] * 40, made)

    def broken(out):
        raise ValueError("part 4 is broken")
    parts[4] = (100, broken)
    with open(tmp_path / "a.bin", "wb") as fh, pytest.raises(ValueError, match="part 4"):
        write_parts(positional_writer(fh, 0), parts, workers=3, part_bytes=100)
    settled = len(made)
    threading.Event().wait(0.05)
    assert len(made) == settled
    parts[4] = (99, parts[6][1])
    with open(tmp_path / "b.bin", "wb") as fh, \
            pytest.raises(ValueError, match="part 4 made 100 bytes, not 99"):
        write_parts(positional_writer(fh, 0), parts, workers=1, part_bytes=100)


@pytest.mark.parametrize("crc32, combine", [(npz.crc32, npz.crc32_combine), (zlib.crc32, None)],
                         ids=["writer's", "stdlib and our combine"])
@pytest.mark.parametrize("workers", [1, 3])
@pytest.mark.parametrize("chunk_bytes", [100, npz._PART_BYTES])
def test_npz_holds_what_np_savez_writes(tmp_path, monkeypatch, chunk_bytes, workers, crc32,
                                        combine):
    """Member by member the bytes of ``np.savez`` of the arrays as stored (C order, the
    stored dtype by ``astype``), on one worker thread or shared among three: converted
    in parts of a few rows (with a remainder) or, rows longer than a part, of elements;
    a Fortran-ordered array reads back the same; the CRC-32 set in each local header,
    combined from the parts' by zlib-ng's (the speed extra) as by the standard library's
    and our own combination; the file ends where the archive does."""
    monkeypatch.setattr(npz, "_PART_BYTES", chunk_bytes)
    monkeypatch.setattr(npz, "worker_threads", lambda: workers)
    monkeypatch.setattr(npz, "crc32", crc32)
    monkeypatch.setattr(npz, "crc32_combine", combine)
    rng = np.random.default_rng(0)
    arrays = dict(weights=rng.normal(size=(101, 7)), faces=np.arange(30).reshape(10, 3),
                  names=np.array(["jawOpen", "eyeBlink_L"]), units=np.array("cm"),
                  rate=np.float64(276.0), empty=np.zeros((0, 3)),
                  fortran=np.asfortranarray(rng.normal(size=(6, 5))),
                  displacements=rng.normal(size=(3, 11, 3)), größe=np.arange(3),
                  wide=rng.normal(size=(2, 40)), wide_fortran=np.asfortranarray(
                      rng.normal(size=(3, 2, 40))))
    store_as = {"weights": np.float32, "displacements": np.float32, "fortran": np.float32,
                "wide": np.float32, "wide_fortran": np.float32}
    with open(tmp_path / "ours.npz", "wb") as fh:
        npz.write_npz(fh, arrays, store_as=store_as)
    stored = {name: np.array(arr, dtype=store_as.get(name, arr.dtype), order="C")
              for name, arr in arrays.items()}
    np.savez(tmp_path / "numpy.npz", **stored)
    ours, theirs = zipfile.ZipFile(tmp_path / "ours.npz"), zipfile.ZipFile(tmp_path / "numpy.npz")
    assert ours.testzip() is None and ours.namelist() == theirs.namelist()
    for name in ours.namelist():
        assert ours.read(name) == theirs.read(name), name
    with np.load(tmp_path / "ours.npz") as back:
        for name, arr in stored.items():
            assert back[name].dtype == arr.dtype
            np.testing.assert_array_equal(back[name], arr)
    raw = (tmp_path / "ours.npz").read_bytes()
    for info in ours.infolist():     # the CRC set in each local header after its data
        assert raw[info.header_offset + 14:info.header_offset + 18] == struct.pack(
            "<I", zlib.crc32(ours.read(info.filename)))
    assert raw[-22:-18] == b"PK\x05\x06" and raw[-2:] == b"\0\0"     # nothing after
    reserved = []
    monkeypatch.setattr(npz, "preallocate", lambda fh, n_bytes: reserved.append(n_bytes))
    with open(tmp_path / "again.npz", "wb") as fh:
        npz.write_npz(fh, arrays, store_as=store_as)
    assert reserved == [len(raw)]    # the size reserved is the archive's
    assert (tmp_path / "again.npz").read_bytes() == raw     # no date: the same bytes
    if shutil.which("unzip"):        # an independent reader of zip64
        subprocess.run(["unzip", "-tq", tmp_path / "ours.npz"], check=True,
                       capture_output=True)


def test_npz_sums_by_zlib_ng_where_the_speed_extra_is_installed():
    """The writer's CRC-32 is zlib-ng's when the speed extra brought it (the tests install
    it), and the same number as zlib's."""
    from zlib_ng import zlib_ng
    assert npz.crc32 is zlib_ng.crc32
    data = np.random.default_rng(0).bytes(3 << 20)
    assert npz.crc32(data[1:], npz.crc32(data[:1])) == zlib.crc32(data)


@pytest.mark.parametrize("n_bytes", [0, 1, 7, 1000, 3 << 20])
def test_crc32_combination_is_the_crc32_of_the_joined_bytes(n_bytes):
    """Our ``crc32_combine`` (the writer's without zlib-ng) against zlib's CRC-32 of the
    joined bytes, and zlib-ng's own combination."""
    from zlib_ng import zlib_ng
    rng = np.random.default_rng(n_bytes)
    for first in (b"", rng.bytes(1), rng.bytes(4099)):
        second = rng.bytes(n_bytes)
        combined = npz._crc32_combine(zlib.crc32(first), zlib.crc32(second), n_bytes)
        assert combined == zlib.crc32(first + second)
        assert combined == zlib_ng.crc32_combine(zlib.crc32(first), zlib.crc32(second),
                                                 n_bytes)


def test_npz_refuses_python_objects(tmp_path):
    with open(tmp_path / "o.npz", "wb") as fh, pytest.raises(ValueError, match="objects"):
        npz.write_npz(fh, {"o": np.array([{}, None], dtype=object)})


@pytest.mark.parametrize("chunk_bytes", [100, npz._PART_BYTES])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, 1e39])
@pytest.mark.parametrize("where", [0, 57, 100])
def test_npz_checks_members_finite_as_stored(tmp_path, monkeypatch, bad, where, chunk_bytes):
    """A NaN, an infinite value or a float64 beyond float32's range, in the first, a
    middle or the last part of rows (or in a member of one part), refused in a member
    stored finite; the same values written where they are not asked to be finite (1e39
    as float32's inf)."""
    monkeypatch.setattr(npz, "_PART_BYTES", chunk_bytes)
    weights = np.random.default_rng(where).normal(size=(101, 7))
    weights[where, 3] = bad
    with np.errstate(over="ignore"):
        arrays = dict(weights=weights, raw=weights.astype(np.float32))
    store_as = {"weights": np.float32}
    for member in arrays:
        with open(tmp_path / "a.npz", "wb") as fh, \
                pytest.raises(npz.NotFiniteError, match=repr(member)) as caught:
            npz.write_npz(fh, arrays, store_as=store_as, finite=[member])
        assert caught.value.member == member
    with open(tmp_path / "b.npz", "wb") as fh:
        npz.write_npz(fh, arrays, store_as=store_as, finite=["other"])
    with np.load(tmp_path / "b.npz") as back:
        np.testing.assert_array_equal(back["weights"], arrays["raw"])


def test_npz_finite_members_with_large_sums(tmp_path):
    """Finite values whose sum overflows (the fast check's doubt) are exactly checked."""
    arrays = dict(big=np.full((1000, 3), 3e38, dtype=np.float32))
    with open(tmp_path / "a.npz", "wb") as fh:
        npz.write_npz(fh, arrays, finite=["big"])
    with np.load(tmp_path / "a.npz") as back:
        np.testing.assert_array_equal(back["big"], arrays["big"])
