"""The parameter section of a C3D file: groups of typed, named parameters.

Each entry starts with a signed name length (negative = locked; 0 ends the
section) and a signed group id (negative = a group, positive = a parameter of
group ``|id|``), then the name and a 16-bit offset to the next entry counted
from the offset field itself. A parameter then has a type (-1 char, 1 byte,
2 int16, 4 float), its dimensions and data.

The parser is lenient where files in the wild bend the standard: unknown types
are skipped, a zero or negative offset or a zero name length ends the section,
groups sharing a name are merged, and an entry that runs past the end of the
file ends the section with a note. It never reads past the buffer and always
moves forward, so a corrupt section cannot make it loop or allocate much.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from mocap.io._c3d_numbers import float32, int16

__all__ = ["Parameter", "Parameters", "parse_parameters"]

_TYPES = {-1: "char", 1: "byte", 2: "int16", 4: "float"}


@dataclass(frozen=True)
class Parameter:
    """One parameter: its type code, dimensions, raw data and byte offset.

    ``value`` is decoded on first use: a tuple of str for char data, a 1-D
    ndarray in file order otherwise.
    """

    type: int
    dims: tuple
    raw: bytes
    order: str
    offset: int         # byte offset of the entry in the file

    @cached_property
    def value(self):
        return _decode_value(self.type, self.dims, self.raw, self.order)


def _decode_text(raw: bytes) -> str:
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    return text.rstrip(" \x00").lstrip("\x00")


def _decode_value(kind: int, dims: tuple, raw: bytes, order: str):
    if kind == -1:
        if len(dims) == 0:
            return (_decode_text(raw),)
        width = dims[0]
        if width == 0:          # no bytes: no strings, whatever the other dimensions claim
            return ()
        return tuple(_decode_text(raw[i:i + width]) for i in range(0, len(raw), width))
    if kind == 1:
        return np.frombuffer(raw, dtype=np.int8).astype(np.int64)
    if kind == 2:
        return int16(raw, order).astype(np.int64)
    return float32(raw, order)


class Parameters:
    """Groups of parameters by upper-case name, with typed look-ups.

    ``notes`` collects what the parser had to work around, for warnings;
    ``last_entry`` is the byte offset of the last entry read; ``truncated`` is
    True when an entry ran past the end of the bytes parsed.
    """

    def __init__(self, groups: dict, notes: list, last_entry: int, truncated: bool):
        self.groups = groups
        self.notes = notes
        self.last_entry = last_entry
        self.truncated = truncated

    def get(self, group: str, name: str) -> Parameter | None:
        """The parameter ``group:name`` or None."""
        return self.groups.get(group, {}).get(name)

    def number(self, group: str, name: str, *, unsigned16: bool = False):
        """First numeric value of ``group:name`` as a float, or None if absent/empty.

        With `unsigned16`, an int16 value is read as unsigned (counts and block
        numbers that overflow the signed range).
        """
        values = self.numbers(group, name, unsigned16=unsigned16)
        return None if values is None or values.size == 0 else float(values[0])

    def numbers(self, group: str, name: str, *, unsigned16: bool = False):
        """All numeric values of ``group:name`` as a float64 array, or None."""
        param = self.get(group, name)
        if param is None or param.type == -1:
            return None
        values = np.asarray(param.value, dtype=np.float64)
        if unsigned16 and param.type == 2:
            values = np.mod(values, 65536)
        return values

    def strings(self, group: str, name: str) -> tuple | None:
        """Char data of ``group:name`` as a tuple of strings, or None."""
        param = self.get(group, name)
        if param is None or param.type != -1:
            return None
        return param.value

    def string_series(self, group: str, name: str) -> tuple:
        """Strings of ``NAME``, ``NAME2``, ``NAME3``... concatenated (LABELS past 255)."""
        out = list(self.strings(group, name) or ())
        index = 2
        while (more := self.strings(group, f"{name}{index}")) is not None:
            out.extend(more)
            index += 1
        return tuple(out)

    def text(self, group: str, name: str) -> str:
        """Char data of ``group:name`` joined into one string ('' if absent)."""
        return " ".join(s for s in (self.strings(group, name) or ()) if s).strip()

    def as_dict(self) -> dict:
        """``{group: {name: value}}`` with strings or numeric arrays shaped as declared."""
        out = {}
        for group, params in self.groups.items():
            out[group] = {}
            for name, p in params.items():
                value = p.value
                if p.type != -1 and len(p.dims) == 0:
                    value = value[0]
                elif p.type != -1:
                    value = value.reshape(p.dims[::-1])
                elif p.type == -1 and len(value) == 1 and len(p.dims) <= 1:
                    value = value[0]
                out[group][name] = value
        return out


def parse_parameters(buf: bytes, start: int, order: str, *, end: int) -> Parameters:
    """Parse the parameter section whose 4-byte preamble is at byte `start` of `buf`.

    Entries are read until the section's end mark or byte `end` (where the data
    section starts); the declared block count is not trusted (files in the
    wild get it wrong).
    """
    buf = memoryview(buf)[:end]
    word = ">h" if order == "mips" else "<h"
    truncated = False
    names: dict[int, str] = {}
    by_id: dict[int, dict] = {}
    notes: list[str] = []
    pos = last_entry = start + 4
    while pos + 2 <= len(buf):
        name_len, group_id = struct.unpack_from("bb", buf, pos)
        name_len = abs(name_len)
        if name_len == 0 or group_id == 0:
            break
        last_entry = pos
        name_end = pos + 2 + name_len
        if name_end + 2 > len(buf):
            truncated = True
            break
        name = _decode_text(bytes(buf[pos + 2:name_end])).upper()
        step = struct.unpack_from(word, buf, name_end)[0]
        body = name_end + 2
        if group_id < 0:
            names.setdefault(-group_id, name)
        else:
            try:
                entry = _parse_entry(buf, body, order, pos, notes)
            except _SectionEnd:
                truncated = True
                break
            if entry is not None:
                by_id.setdefault(group_id, {}).setdefault(name, entry)
        if step <= 0:
            break
        pos = name_end + step
    groups: dict[str, dict] = {}
    for gid, params in by_id.items():
        merged = groups.setdefault(names.get(gid, f"GROUP{gid}"), {})
        for name, param in params.items():
            merged.setdefault(name, param)
    for gid, name in names.items():
        groups.setdefault(name, {})
    if truncated:
        notes.append(f"parameter section entry at byte {last_entry} runs past byte {end}; "
                     "ignoring the rest of the section")
    return Parameters(groups, notes, last_entry, truncated)


class _SectionEnd(Exception):
    """An entry runs past the end of the bytes parsed."""


def _parse_entry(buf: bytes, body: int, order: str, pos: int, notes: list):
    """The Parameter whose type byte is at `body`, or None (with a note) if unreadable."""
    if body + 2 > len(buf):
        raise _SectionEnd
    kind = buf[body] - 256 if buf[body] > 127 else buf[body]
    n_dims = buf[body + 1]
    dims = tuple(buf[body + 2:body + 2 + n_dims])
    if kind not in _TYPES:
        notes.append(f"parameter at byte {pos} has unknown type {kind}; skipped")
        return None
    size = abs(kind) * math.prod(dims)
    data = body + 2 + n_dims
    if len(dims) < n_dims or data + size > len(buf):
        raise _SectionEnd
    return Parameter(kind, dims, bytes(buf[data:data + size]), order, pos)
