"""Allocation budgets: what a file may make a reader allocate, checked before allocating.

Every reader works out from a file's header or contents what reading it would
allocate (parameter dimensions, frame ranges, row widths, array shapes) and
asks :func:`check_allocation` first. An allocation is refused, naming the file,
the field and the number, when it exceeds

- what the file's own contents justify: a bound the reader derives from the
  bytes it holds (one float64 per cell of a text table, the samples a data
  section holds...), plus a fixed allowance of :data:`SLACK_BYTES` that every
  file gets; or
- the documented limit ``MOCAP2MESH_MAX_BYTES`` (bytes, optionally with a
  ``K``, ``M``, ``G`` or ``T`` binary suffix; default :data:`DEFAULT_MAX_BYTES`),
  whatever the file holds: raise it to read larger files.
"""

from __future__ import annotations

import os
import re

from mocap.errors import FileFormatError, InputError

__all__ = ["ENV_VAR", "DEFAULT_MAX_BYTES", "SLACK_BYTES", "max_bytes", "format_bytes",
           "check_allocation"]

#: The environment variable that sets the largest allocation a reader makes.
ENV_VAR = "MOCAP2MESH_MAX_BYTES"
#: Its default: 4 GiB (the positions of 100 markers x 1.7 million frames).
DEFAULT_MAX_BYTES = 4 << 30
#: What any file may allocate beyond what its contents justify (small tables, headers).
SLACK_BYTES = 16 << 20

_SIZE = re.compile(r"\s*(\d+)\s*([KMGT]?)i?B?\s*", re.IGNORECASE)
_UNITS = {"": 0, "K": 10, "M": 20, "G": 30, "T": 40}


def max_bytes() -> int:
    """The largest allocation a reader may make, bytes (from ``MOCAP2MESH_MAX_BYTES``).

    Raises
    ------
    InputError
        The variable is set but is not a size such as ``8000000000`` or ``16G``.

    Examples
    --------
    >>> import os
    >>> os.environ["MOCAP2MESH_MAX_BYTES"] = "16G"
    >>> max_bytes() == 16 * 2 ** 30
    True
    >>> del os.environ["MOCAP2MESH_MAX_BYTES"]
    >>> max_bytes() == DEFAULT_MAX_BYTES
    True
    """
    text = os.environ.get(ENV_VAR)
    if text is None or not text.strip():
        return DEFAULT_MAX_BYTES
    match = _SIZE.fullmatch(text)
    if match is None or int(match[1]) == 0:
        raise InputError(f"{ENV_VAR} must be a positive number of bytes, optionally with a "
                         f"K, M, G or T suffix (e.g. 16G), got {text!r}")
    return int(match[1]) << _UNITS[match[2].upper()]


def format_bytes(n: float) -> str:
    """A byte count for people: ``'5.5 GB'``, ``'128 KB'``, ``'512 B'`` (powers of 1000).

    Examples
    --------
    >>> format_bytes(5.5e9), format_bytes(128_340), format_bytes(12)
    ('5.5 GB', '128 kB', '12 B')
    """
    for unit, scale in (("PB", 1e15), ("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if abs(n) >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{int(n)} B"


def check_allocation(path, field: str, n_bytes, *, justified=None, offset: int | None = None,
                     line: int | None = None) -> int:
    """Refuse an allocation a file cannot justify, before it is made.

    Parameters
    ----------
    path : str or os.PathLike
        The file being read (named in the error).
    field : str
        What would be allocated and from which field, e.g. ``"positions of
        2000000 frames (frame numbers 1 to 2000000) x 51 markers"``.
    n_bytes : int or float
        Bytes the allocation would take (a float for products that may overflow).
    justified : int or float, optional
        Bytes the file's own contents justify (its bound for this allocation);
        :data:`SLACK_BYTES` more are allowed. None: only the global limit applies.
    offset, line : int, optional
        Where the field is (byte offset or 1-based line), for the error.

    Returns
    -------
    int
        `n_bytes`, when allowed.

    Raises
    ------
    FileFormatError
        Beyond the justified bound or beyond ``MOCAP2MESH_MAX_BYTES``.

    Examples
    --------
    >>> check_allocation("a.trc", "positions", 24_000, justified=24_000)
    24000
    >>> check_allocation("a.trc", "positions of 1e9 frames", 2.4e10, justified=1e5, line=7)
    Traceback (most recent call last):
    ...
    mocap.errors.FileFormatError: a.trc at line 7: positions of 1e9 frames would take 24 GB, \
more than the file's contents justify (at most 16.9 MB)
    """
    limit = max_bytes()
    if justified is not None and n_bytes > justified + SLACK_BYTES:
        raise FileFormatError(path, f"{field} would take {format_bytes(n_bytes)}, more than "
                                    "the file's contents justify (at most "
                                    f"{format_bytes(justified + SLACK_BYTES)})",
                              offset=offset, line=line)
    if n_bytes > limit:
        raise FileFormatError(path, f"{field} would take {format_bytes(n_bytes)}, more than "
                                    f"{ENV_VAR} ({format_bytes(limit)}); set it higher to "
                                    "read this file", offset=offset, line=line)
    return int(n_bytes)
