"""The 512-byte header block of a C3D file and the processor byte that says how to read it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.errors import FileFormatError
from mocap.io._c3d_numbers import PROCESSORS, float32, uint16

__all__ = ["BLOCK", "KEY", "Header", "locate_parameters", "parse_header"]

#: C3D sections are counted in 512-byte blocks, numbered from 1.
BLOCK = 512
#: Byte 1 of every C3D file.
KEY = 0x50
_EVENT_KEY = 12345
_MAX_EVENTS = 18


@dataclass(frozen=True)
class Header:
    """Fields of the header block, decoded in the file's byte order.

    Frame numbers and counts are the raw unsigned 16-bit words; the reader
    checks them against the parameters and the file size.
    """

    parameter_block: int
    n_points: int
    analog_words: int          # analog values per 3D frame (channels x samples)
    first_frame: int
    last_frame: int
    max_gap: int
    scale: float
    data_block: int
    analog_per_frame: int      # analog samples per 3D frame
    rate: float
    events: tuple              # ((label, time s), ...)

    def as_extra(self) -> dict:
        """The header fields worth keeping in ``SourceInfo.extra``."""
        return {"header_points": self.n_points, "header_analog_words": self.analog_words,
                "header_first_frame": self.first_frame, "header_last_frame": self.last_frame,
                "header_scale": self.scale, "header_rate": self.rate,
                "header_data_block": self.data_block, "parameter_block": self.parameter_block,
                "analog_per_frame": self.analog_per_frame, "max_gap": self.max_gap,
                "events": self.events}


def locate_parameters(buf: bytes, path) -> tuple[int, str]:
    """Byte offset of the parameter section and the byte order it declares.

    Raises
    ------
    FileFormatError
        Empty file, no C3D key, a parameter pointer outside the file, or an
        unknown processor type.
    """
    if len(buf) == 0:
        raise FileFormatError(path, "file is empty; a C3D file starts with a 512-byte header",
                              offset=0)
    if len(buf) < BLOCK:
        raise FileFormatError(path, f"file is truncated: it ends inside the 512-byte header "
                                    f"({len(buf)} bytes)", offset=len(buf))
    if buf[1] != KEY:
        raise FileFormatError(path, f"not a C3D file: byte 1 is {buf[1]}, expected {KEY} "
                                    "(the C3D key)", offset=1)
    block = buf[0]
    start = (block - 1) * BLOCK
    if block < 2 or start + 4 > len(buf):
        raise FileFormatError(path, f"bad parameter-section pointer: block {block} is "
                                    f"{'the header' if block < 2 else 'past the end of the file'}"
                                    f" (file has {len(buf) // BLOCK} blocks)", offset=0)
    processor = buf[start + 3]
    if processor not in PROCESSORS:
        raise FileFormatError(path, f"unknown processor type {processor} in the parameter "
                                    "section; expected 84 (Intel), 85 (DEC) or 86 (MIPS)",
                              offset=start + 3)
    return start, PROCESSORS[processor]


def parse_header(buf: bytes, order: str) -> Header:
    """Decode the header block `buf[:512]` read in byte order `order`."""
    words = uint16(buf[:BLOCK], order)
    floats = float32(buf[12:16] + buf[20:24], order)
    events = ()
    n_events = int(words[150])
    if words[149] == _EVENT_KEY and 0 < n_events <= _MAX_EVENTS:
        times = float32(buf[304:304 + 4 * n_events], order)
        labels = [buf[396 + 4 * i:400 + 4 * i].decode("latin-1").strip(" \x00")
                  for i in range(n_events)]
        events = tuple((label, float(t)) for label, t in zip(labels, times)
                       if np.isfinite(t))
    return Header(parameter_block=buf[0], n_points=int(words[1]),
                  analog_words=int(words[2]), first_frame=int(words[3]),
                  last_frame=int(words[4]), max_gap=int(words[5]),
                  scale=float(floats[0]), data_block=int(words[8]),
                  analog_per_frame=int(words[9]), rate=float(floats[1]), events=events)
