"""The data section of a C3D file: where it is, how big, and its vectorized decoding.

The header and the parameters both describe the data section and either may
be wrong in files in the wild: :func:`plan_layout` weighs them against the file
size before anything is allocated. :func:`decode_frames` then decodes the
frames in chunks (each chunk vectorized with ``numpy.frombuffer``, the chunks
shared among the worker threads) straight into the arrays it returns, from a
memory map whose pages it releases as it goes: a read holds one float64 copy
of the positions and a chunk of the file per thread. :func:`scan_missing`
counts missing samples and gaps the same way without keeping the positions at
all.
"""

from __future__ import annotations

import mmap
from dataclasses import dataclass

import numpy as np

from mocap.errors import FileFormatError
from mocap.gaps import find_gaps
from mocap.io._c3d_header import BLOCK, Header
from mocap.io._c3d_numbers import float32
from mocap.io._c3d_params import Parameters
from mocap.util.blas import map_on_blas_threads

__all__ = ["Layout", "plan_layout", "decode_frames", "scan_missing", "CHUNK_BYTES"]

_HEADER_POINTS = 2
_HEADER_SCALE_OFFSET = 12
_HEADER_DATA_BLOCK_OFFSET = 16
_WRAP = 65536


@dataclass(frozen=True)
class Layout:
    """Where the frames are and what each holds."""

    offset: int             # byte offset of the first frame
    n_frames: int
    first_frame: int
    n_points: int
    analog_words: int       # analog values per frame (n_channels * analog_per_frame)
    analog_per_frame: int
    n_channels: int         # 0 when there is no (usable) analog data
    storage: str            # "float" or "integer"
    scale: float            # POINT:SCALE magnitude (integer storage)

    @property
    def word_size(self) -> int:
        return 4 if self.storage == "float" else 2

    @property
    def frame_bytes(self) -> int:
        return (4 * self.n_points + self.analog_words) * self.word_size


def _scale(header: Header, params: Parameters, path, notes: list) -> float:
    """The point scale: the header's copy unless it is unusable, then POINT:SCALE.

    Where both are usable and differ, the header wins (sample_06/MACsample.c3d:
    only the header's scale gives anatomically sized distances).
    """
    def usable(value):
        return value is not None and np.isfinite(value) and value != 0

    param = params.number("POINT", "SCALE")
    if usable(header.scale):
        if usable(param) and not np.isclose(param, header.scale, rtol=1e-6):
            notes.append(f"header scale {header.scale:.6g} differs from POINT:SCALE "
                         f"{param:.6g}; using the header's")
        return header.scale
    if usable(param):
        return param
    raise FileFormatError(path, f"point scale is {header.scale} (POINT:SCALE {param}): "
                                "cannot tell float from integer storage (expected a negative "
                                "scale for float, positive for integer)",
                          offset=_HEADER_SCALE_OFFSET)


def _data_offset(size: int, header: Header, params: Parameters, param_start: int,
                 path, notes: list) -> int:
    """Byte offset of the data section.

    The header's block, unless it lies outside the file, before the parameter
    section, or inside it while POINT:DATA_START (read unsigned) lies beyond it.
    """
    def usable(block):
        return block is not None and param_start < (int(block) - 1) * BLOCK <= size

    head = header.data_block
    param = params.number("POINT", "DATA_START", unsigned16=True)
    param = None if param is None else int(param)
    if usable(head) and usable(param) and param != head:
        if (head - 1) * BLOCK <= params.last_entry < (param - 1) * BLOCK:
            notes.append(f"header data start block {head} lies inside the parameter section; "
                         f"using POINT:DATA_START {param}")
            return (param - 1) * BLOCK
        notes.append(f"header data start block {head} differs from POINT:DATA_START "
                     f"{param}; using the header's")
    if usable(head):
        return (head - 1) * BLOCK
    if usable(param):
        notes.append(f"header data start block {head} is impossible; using "
                     f"POINT:DATA_START {param}")
        return (param - 1) * BLOCK
    raise FileFormatError(path, f"bad data-section pointer: header block {head}, "
                                f"POINT:DATA_START {param}; neither lies after the parameter "
                                f"section and inside the file ({size} bytes)",
                          offset=_HEADER_DATA_BLOCK_OFFSET)


def _frame_counts(header: Header, params: Parameters) -> tuple[list, int]:
    """Candidate frame counts ``[(count, kind), ...]`` and the first frame number, from
    TRIAL:ACTUAL_START/END_FIELD, the header and POINT:FRAMES.

    `kind` is ``"exact"`` (32-bit or float counts), ``"wrapped"`` (a 16-bit
    count that may have wrapped past 65535) or ``"at_least"`` (a 16-bit count
    saturated at 65535, as Vicon writes for longer takes).
    """
    def sixteen(count: int) -> str:
        return "at_least" if count == _WRAP - 1 else "wrapped"

    counts = [((header.last_frame - header.first_frame + 1) % _WRAP,
               sixteen(header.last_frame))]
    first = header.first_frame
    start = params.numbers("TRIAL", "ACTUAL_START_FIELD", unsigned16=True)
    stop = params.numbers("TRIAL", "ACTUAL_END_FIELD", unsigned16=True)
    if start is not None and stop is not None and start.size >= 2 and stop.size >= 2:
        trial_first = int(start[0] + _WRAP * start[1])
        trial_last = int(stop[0] + _WRAP * stop[1])
        if trial_last >= trial_first:
            counts.append((trial_last - trial_first + 1, "exact"))
            first = trial_first
    frames = params.get("POINT", "FRAMES")
    if frames is not None and frames.type != -1 and len(frames.value) > 0:
        value = float(frames.value[0])
        if frames.type == 4 and np.isfinite(value) and value >= 0:
            counts.append((int(min(value, 2.0 ** 62)), "exact"))
        elif frames.type != 4:
            counts.append((int(value) % _WRAP, sixteen(int(value) % _WRAP)))
    return counts, first


def _n_frames(counts: list, available: int, path, frame_bytes: int, size: int,
              notes: list) -> int:
    """The largest claimed count the file holds; the complete frames if none fits, or
    when the only counts are 16-bit ones saturated at 65535 and the data section holds
    more."""
    fitting = [(n, kind) for n, kind in counts if n <= available]
    claimed = min(n for n, _ in counts)
    if not fitting:
        if available == 0:
            raise FileFormatError(path, f"data section is truncated: it holds no complete "
                                        f"frame of {frame_bytes} bytes ({claimed} frames "
                                        "claimed)", offset=size)
        notes.append(f"data section is truncated: {available} complete frames of {claimed} "
                     "claimed; reading those")
        return available
    n, kind = max(fitting)
    if n == 0 and available > 0:
        notes.append(f"the file claims no frames; reading the {available} frames its data "
                     "section holds")
        return available
    if kind == "at_least" and available > n:
        notes.append(f"the frame count is saturated at {n} (16-bit header and POINT:FRAMES, "
                     f"no TRIAL range); reading the {available} frames the data section holds")
        return available
    if kind == "wrapped" and available - n >= _WRAP:
        n += _WRAP * ((available - n) // _WRAP)
    return n


def _analog(header: Header, params: Parameters, notes: list) -> tuple[int, int]:
    """(analog samples per frame, channels) from the header words and ANALOG:USED."""
    words, per_frame = header.analog_words, header.analog_per_frame
    used = params.number("ANALOG", "USED", unsigned16=True)
    if words == 0:
        return per_frame, 0
    if per_frame > 0 and words % per_frame == 0:
        channels = words // per_frame
    elif used and words % int(used) == 0:
        channels, per_frame = int(used), words // int(used)
    else:
        notes.append(f"cannot split {words} analog values per frame into channels "
                     f"(samples per frame {per_frame}, ANALOG:USED {used}); analog data skipped")
        return per_frame, 0
    if used is not None and int(used) != channels:
        notes.append(f"ANALOG:USED is {int(used)} but the header's layout holds {channels} "
                     "channels; using the header's")
    return per_frame, channels


def plan_layout(size: int, header: Header, params: Parameters, param_start: int,
                path, notes: list) -> Layout:
    """Decide where the frames are and how many complete ones the file holds.

    A data section shorter than claimed yields the complete frames with a note
    (a warning for the caller); one with no complete frame is an error.
    """
    scale = _scale(header, params, path, notes)
    offset = _data_offset(size, header, params, param_start, path, notes)
    used = params.number("POINT", "USED", unsigned16=True)
    if used is not None and int(used) != header.n_points:
        notes.append(f"POINT:USED is {int(used)} but the header says {header.n_points} "
                     "points per frame; using the header's")
    per_frame, channels = _analog(header, params, notes)
    layout = Layout(offset, 0, 0, header.n_points, header.analog_words, per_frame, channels,
                    "float" if scale < 0 else "integer", abs(scale))
    if layout.frame_bytes == 0:
        raise FileFormatError(path, "frames hold no point and no analog value (header: 0 "
                                    "points, 0 analog values per frame)", offset=_HEADER_POINTS)
    counts, first = _frame_counts(header, params)
    available = (size - offset) // layout.frame_bytes
    n_frames = _n_frames(counts, available, path, layout.frame_bytes, size, notes)
    return Layout(offset, n_frames, first, layout.n_points, layout.analog_words, per_frame,
                  channels, layout.storage, layout.scale)


#: Bytes of the data section decoded at a time: bounds the float64 temporaries of a read.
CHUNK_BYTES = 4 << 20


def _release(buf, start: int, stop: int) -> None:
    """Drop the pages of bytes [start, stop) of a memory map from this process's memory.

    The file's pages stay in the system's cache; only the process's resident
    set shrinks, so a read holds no more of the file than the chunks it is decoding.
    A page another thread still reads is mapped again from the cache.
    """
    advise = getattr(buf, "madvise", None)
    dontneed = getattr(mmap, "MADV_DONTNEED", None)
    if advise is None or dontneed is None:
        return
    start -= start % mmap.PAGESIZE
    if stop > start:
        advise(dontneed, start, min(stop, len(buf)) - start)


def _spans(layout: Layout, frames_per_chunk: int | None = None) -> list:
    """The chunks of frames, ``(first, count)``: :data:`CHUNK_BYTES` of file each, or
    `frames_per_chunk` frames."""
    step = frames_per_chunk or max(1, CHUNK_BYTES // layout.frame_bytes)
    return [(first, min(step, layout.n_frames - first))
            for first in range(0, layout.n_frames, step)]


def _words(buf, layout: Layout, order: str, first: int, count: int) -> np.ndarray:
    """The words of frames ``first`` to ``first + count``, (count, words per frame): a view
    of `buf` in the file's own type (float32 or int16), or float64 for DEC floats."""
    per_frame = 4 * layout.n_points + layout.analog_words
    start = layout.offset + first * layout.frame_bytes
    kind = "f4" if layout.storage == "float" else "i2"
    if order == "dec" and kind == "f4":
        words = float32(buf[start:start + count * layout.frame_bytes], order)
    else:
        words = np.frombuffer(buf, dtype=(">" if order == "mips" else "<") + kind,
                              count=count * per_frame, offset=start)
    return words.reshape(count, per_frame)


def _release_frames(buf, layout: Layout, first: int, count: int) -> None:
    """:func:`_release` of the bytes of frames ``first`` to ``first + count``."""
    start = layout.offset + first * layout.frame_bytes
    _release(buf, start, start + count * layout.frame_bytes)


def _missing(points) -> np.ndarray:
    """Missing samples of (c, M, 4) point words: a negative residual or a coordinate that
    is not finite."""
    finite = np.isfinite(points[:, :, :3])
    with np.errstate(invalid="ignore"):
        missing = points[:, :, 3] < 0
    missing |= ~(finite[:, :, 0] & finite[:, :, 1] & finite[:, :, 2])   # not .all(axis=2): slow
    return missing


def _missing_widened(points, xyz) -> np.ndarray:
    """:func:`_missing` of (c, M, 4) point words whose coordinates are already widened to
    float64 in `xyz` (c, M, 3), by one (c, M) sum instead of a (c, M, 3) mask: a sample's
    coordinates are all finite exactly when their float64 sum is (float32 or int16 words
    times a float32 scale and a unit factor stay far below float64's overflow)."""
    with np.errstate(invalid="ignore"):
        missing = points[:, :, 3] < 0
        total = xyz @ np.ones(3)        # a BLAS product: twice as fast as two np.add
    missing |= ~np.isfinite(total)
    return missing


def decode_frames(buf, layout: Layout, order: str, *, factor: float = 1.0):
    """Decode every frame, a chunk of frames at a time, into arrays allocated once.

    Parameters
    ----------
    buf : bytes-like or mmap.mmap
        The whole file; a memory map's pages are released chunk by chunk.
    layout : Layout
    order : str
    factor : float
        Multiplies the positions (file units to mm).

    Returns
    -------
    xyz : ndarray of shape (n_frames, n_points, 3), float64, mm
        NaN where the residual word is negative or a coordinate is not finite.
    analog : ndarray of shape (n_frames * analog_per_frame, n_channels), float64
        Raw analog values (before offset and scale).

    Notes
    -----
    Memory: the two outputs, plus a chunk (:data:`CHUNK_BYTES` of file) and its
    missing mask per worker thread: the words are scaled and widened to float64
    straight into the output.
    """
    n, m = layout.n_frames, layout.n_points
    xyz = np.empty((n, m, 3))
    per, channels = layout.analog_per_frame, layout.n_channels
    analog = np.empty((n * per, channels))
    scale = factor * (1.0 if layout.storage == "float" else layout.scale)

    def decode(span):
        first, count = span
        words = _words(buf, layout, order, first, count)
        points = words[:, :4 * m].reshape(count, m, 4)
        out = xyz[first:first + count]
        out[...] = points[:, :, :3]                 # widened to float64 in place
        if scale != 1.0:
            with np.errstate(all="ignore"):
                out *= scale
        # by flat indices: a boolean mask's assignment visits every sample
        out.reshape(-1, 3)[np.flatnonzero(_missing_widened(points, out))] = np.nan
        values = words[:, 4 * m:4 * m + channels * per]
        analog[first * per:(first + count) * per] = values.reshape(count * per, channels)
        _release_frames(buf, layout, first, count)
    # the chunks shared among the worker threads: each writes its own rows (NumPy's casts
    # and comparisons run without the GIL); the same arrays on any number of threads
    map_on_blas_threads(decode, _spans(layout))
    return xyz, analog


def scan_missing(buf, layout: Layout, order: str, *, frames_per_chunk: int | None = None):
    """Missing samples and the longest gap of every marker, without holding the positions.

    Returns
    -------
    missing : ndarray of shape (n_points,), int
        Frames in which each marker is missing.
    longest : ndarray of shape (n_points,), int
        Each marker's longest run of missing frames (0 if none), runs joined
        across chunks.
    """
    m = layout.n_points
    missing = np.zeros(m, dtype=np.int64)
    longest = np.zeros(m, dtype=np.int64)
    carry = np.zeros(m, dtype=np.int64)          # a run still open at the chunk's end
    for first, count in _spans(layout, frames_per_chunk):
        words = _words(buf, layout, order, first, count)
        mask = _missing(words[:, :4 * m].reshape(count, m, 4))
        missing += mask.sum(axis=0)
        gaps = find_gaps(mask)
        lengths = gaps.length + np.where(gaps.start == 0, carry[gaps.marker], 0)
        np.maximum.at(longest, gaps.marker, lengths)
        carry = np.zeros(m, dtype=np.int64)
        open_end = gaps.stop == len(mask)
        carry[gaps.marker[open_end]] = lengths[open_end]
        _release_frames(buf, layout, first, count)
    return missing, longest
