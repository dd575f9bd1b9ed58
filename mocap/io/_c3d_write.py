"""Encode a Take as C3D bytes: Intel byte order, float storage, mm."""

from __future__ import annotations

import functools
import struct

import numpy as np

from mocap.errors import InputError
from mocap.io._c3d_header import BLOCK, KEY
from mocap.take import Take

__all__ = ["PART_BYTES", "encode_c3d"]

_INTEL = 84
_MAX_DIM = 255           # a parameter dimension is one byte
_MAX_WORD = 65535        # header counts are unsigned 16-bit words
_SOFTWARE = "mocap2mesh"


def _entry(name: str, group_id: int, body: bytes, *, last: bool = False) -> bytes:
    """One group (`group_id` < 0) or parameter entry with its offset to the next one."""
    raw = name.encode("ascii")
    step = 0 if last else 2 + len(body)
    return struct.pack("<bb", len(raw), group_id) + raw + struct.pack("<h", step) + body


def _param(kind: int, dims, data: bytes) -> bytes:
    return struct.pack("<bB", kind, len(dims)) + bytes(dims) + data + b"\x00"


def _int16(values) -> bytes:
    values = np.atleast_1d(np.asarray(values, dtype=np.int64)) % 65536
    return _param(2, [] if values.size == 1 else [values.size], values.astype("<u2").tobytes())


def _float(values, *, scalar: bool = False) -> bytes:
    values = np.atleast_1d(np.asarray(values, dtype="<f4"))
    return _param(4, [] if scalar else [values.size], values.tobytes())


def _chars(strings, what: str) -> bytes:
    encoded = [s.encode("utf-8") for s in strings]
    width = max([1] + [len(e) for e in encoded])
    if width > _MAX_DIM:
        raise InputError(f"{what} longer than {_MAX_DIM} bytes cannot be written to C3D")
    data = b"".join(e.ljust(width) for e in encoded)
    return _param(-1, [width, len(encoded)], data)


def _char_series(name: str, strings, what: str) -> list:
    """NAME, NAME2, NAME3... with at most 255 strings each."""
    chunks = [strings[i:i + _MAX_DIM] for i in range(0, len(strings), _MAX_DIM)] or [()]
    return [(name if i == 0 else f"{name}{i + 1}", _chars(chunk, what))
            for i, chunk in enumerate(chunks)]


def _text(value: str) -> bytes:
    raw = value.encode("utf-8")
    return _param(-1, [len(raw)], raw)


def _analog_layout(take: Take) -> int:
    """Analog samples per frame (0 without analog); validates the analog rate."""
    analog = take.analog
    if analog is None or analog.values.shape[1] == 0:
        return 0
    ratio = analog.rate / take.rate
    per_frame = int(round(ratio))
    if per_frame < 1 or abs(ratio - per_frame) > 1e-9 * ratio \
            or analog.values.shape[0] != per_frame * take.n_frames:
        raise InputError(f"analog data ({analog.values.shape[0]} samples at {analog.rate} Hz) "
                         f"must hold a whole number of samples per frame for {take.n_frames} "
                         f"frames at {take.rate} Hz to be written to C3D")
    if analog.values.shape[1] > _MAX_DIM or per_frame * analog.values.shape[1] > _MAX_WORD:
        raise InputError(f"C3D can hold at most {_MAX_DIM} analog channels and {_MAX_WORD} "
                         f"analog values per frame, got {analog.values.shape[1]} channels "
                         f"x {per_frame} samples")
    return per_frame


def _parameters(take: Take, per_frame: int, data_block: int) -> bytes:
    first, last = take.first_frame, take.first_frame + take.n_frames - 1
    # readers take longer takes from TRIAL; POINT:FRAMES must stay an integer (ezc3d)
    frames = _int16(min(take.n_frames, _MAX_WORD))
    point = [("USED", _int16(take.n_markers)), ("SCALE", _float(-1.0, scalar=True)),
             ("RATE", _float(take.rate, scalar=True)), ("FRAMES", frames),
             ("DATA_START", _int16(data_block)), ("UNITS", _text("mm")),
             *_char_series("LABELS", take.labels, "marker labels")]
    channels = 0 if per_frame == 0 else take.analog.values.shape[1]
    analog = [("USED", _int16(channels)),
              ("RATE", _float(take.rate * per_frame, scalar=True)),
              ("GEN_SCALE", _float(1.0, scalar=True))]
    if channels:
        analog += [("SCALE", _float(np.ones(channels))), ("OFFSET", _int16(np.zeros(channels))),
                   *_char_series("LABELS", take.analog.labels, "analog labels"),
                   *_char_series("UNITS", take.analog.units, "analog units")]
    trial = [("ACTUAL_START_FIELD", _int16([first % 65536, first // 65536])),
             ("ACTUAL_END_FIELD", _int16([last % 65536, last // 65536]))]
    manufacturer = [("COMPANY", _text(_SOFTWARE)), ("SOFTWARE", _text(_SOFTWARE))]
    groups = [("POINT", point), ("ANALOG", analog), ("TRIAL", trial),
              ("MANUFACTURER", manufacturer)]
    out = [_entry(name, -(i + 1), b"\x00") for i, (name, _) in enumerate(groups)]
    params = [(name, i + 1, body) for i, (_, entries) in enumerate(groups)
              for name, body in entries]
    out += [_entry(name, gid, body, last=k == len(params) - 1)
            for k, (name, gid, body) in enumerate(params)]
    return b"".join(out)


#: Bytes of frames one worker thread encodes at a time (cache-sized, as the npz's parts).
PART_BYTES = 1 << 21


def _frame_parts(take: Take, per_frame: int) -> list:
    """The data section as parts of :func:`mocap.util.parallel_writes.write_parts`: (size,
    maker) of a few frames each, encoded vectorized by the thread that writes them."""
    n, m = take.n_frames, take.n_markers
    values = None if not per_frame else take.analog.values
    if values is not None and np.abs(np.nan_to_num(values)).max(initial=0.0) > \
            np.finfo(np.float32).max:
        raise InputError("analog values exceed the float32 range of a C3D file")
    width = 4 * m + (0 if values is None else per_frame * values.shape[1])
    step = max(1, PART_BYTES // (4 * width))
    return [(4 * width * (min(n, first + step) - first),
             functools.partial(_encoded_frames, take, values, per_frame, first,
                               min(n, first + step), width))
            for first in range(0, n, step)]


def _encoded_frames(take: Take, values, per_frame: int, first: int, stop: int, width: int,
                    out: np.ndarray) -> np.ndarray:
    """Frames `first` to `stop` as little-endian float32 words (stop - first, width) in the
    uint8 buffer `out`: each marker's xyz and residual, then the frame's analog values."""
    m = take.n_markers
    positions = take.positions[first:stop]
    words = out[:4 * width * (stop - first)].view("<f4").reshape(stop - first, width)
    points = words[:, :4 * m].reshape(stop - first, m, 4)
    # narrowed in place; a value beyond float32's range overflows the cast, which
    # checks them as it goes (no pass of its own; a NaN is no overflow)
    try:
        with np.errstate(over="raise"):
            points[:, :, :3] = positions
    except FloatingPointError:
        raise InputError("positions exceed the float32 range of a C3D file") from None
    missing = np.isnan(positions[:, :, 0])
    points[:, :, 3] = np.where(missing, -1.0, 0.0)
    # xyz 0 where missing, by flat indices: a boolean mask's assignment visits every sample
    points.reshape(-1, 4)[np.flatnonzero(missing), :3] = 0.0
    if values is not None:
        words[:, 4 * m:] = values[first * per_frame:stop * per_frame].reshape(stop - first, -1)
    return words


def encode_c3d(take: Take) -> list:
    """The bytes of a C3D file holding `take` (see :func:`mocap.io.c3d.write_c3d`), as
    parts of :func:`mocap.util.parallel_writes.write_parts` (of at most
    :data:`PART_BYTES` made at a time): the header and parameter blocks (bytes), then the
    frames a few at a time, each part encoded when it is made.

    Raises
    ------
    InputError
        As :func:`mocap.io.c3d.write_c3d`: what C3D cannot hold but positions beyond float32's
        range here, those when their part is made.
    """
    if take.n_frames == 0:
        raise InputError("a take with no frames cannot be written to C3D")
    if take.first_frame < 0:
        raise InputError(f"C3D frame numbers are unsigned; first_frame must be >= 0, "
                         f"got {take.first_frame}")
    if take.n_markers > _MAX_WORD:
        raise InputError(f"C3D can hold at most {_MAX_WORD} markers, got {take.n_markers}")
    per_frame = _analog_layout(take)
    size = len(_parameters(take, per_frame, 0)) + 4
    n_blocks = -(-size // BLOCK)
    data_block = 2 + n_blocks
    params = struct.pack("<BBBB", 1, KEY, n_blocks, _INTEL) + \
        _parameters(take, per_frame, data_block)
    channels = 0 if per_frame == 0 else take.analog.values.shape[1]
    header = bytearray(BLOCK)
    struct.pack_into("<BBHHHHH", header, 0, 2, KEY, take.n_markers, per_frame * channels,
                     min(take.first_frame, _MAX_WORD),
                     min(take.first_frame + take.n_frames - 1, _MAX_WORD), 0)
    struct.pack_into("<fHHf", header, 12, -1.0, data_block, per_frame, take.rate)
    # The data section is not padded to a whole block: readers that count frames
    # from the file size past 65535 frames (ezc3d) would read the padding as frames.
    head = bytes(header) + params.ljust(n_blocks * BLOCK, b"\x00")
    return [(len(head), head), *_frame_parts(take, per_frame)]
