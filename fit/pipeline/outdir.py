"""The output directory of a run: one writer at a time, safe take names, no stale files.

- :func:`output_lock` holds an exclusive lock on the directory for the whole
  run (``.mocap2mesh.lock``, a POSIX ``flock``: released by the kernel when the
  process and the workers it forked are gone, so a killed run never leaves it
  held), so two runs never write into one directory together;
- :func:`take_names` turns capture file stems into folder names that stay
  inside the directory (:func:`safe_stem`), resolving collisions;
- :func:`staging_dir` is where takes are written before they are committed
  (:mod:`fit.pipeline.completion`); :func:`clean_stale` removes it and the
  temporary files of atomic writes a killed run left behind.
"""

from __future__ import annotations

import errno
import fcntl
import os
import re
import shutil
import unicodedata
from contextlib import contextmanager
from pathlib import Path

from mocap.errors import InputError
from mocap.util.atomic import is_inside, is_temp_name

__all__ = ["LOCK_NAME", "STAGING_NAME", "MAX_STEM", "safe_stem", "take_names", "staging_dir",
           "output_lock", "clean_stale", "check_take_dir"]

LOCK_NAME = ".mocap2mesh.lock"
STAGING_NAME = ".staging"
#: Longest take folder name, characters: room for suffixes under the 255-byte NAME_MAX.
MAX_STEM = 100

_UNSAFE = re.compile(r"[^\w .+-]+")


def safe_stem(text: str) -> str:
    """A file stem that names one folder inside the output directory.

    Characters other than letters, digits, spaces and ``. _ + -`` (separators,
    NUL, control characters, quotes, ``$``) become ``_``; leading dots and
    surrounding spaces are removed (no ``..``, no hidden folders); the result is
    at most :data:`MAX_STEM` characters and never empty (``"take"``).

    Examples
    --------
    >>> safe_stem(".."), safe_stem("take 01"), safe_stem("a/b\\\\c\\x00d"), safe_stem("Daphnée")
    ('take', 'take 01', 'a_b_c_d', 'Daphnée')
    """
    text = unicodedata.normalize("NFC", str(text))
    text = "".join(c if unicodedata.category(c)[0] != "C" else "_" for c in text)
    stem = _UNSAFE.sub("_", text).strip(" ").lstrip(".")
    stem = stem[:MAX_STEM].rstrip(". ")
    return stem if stem.strip("_ ") else "take"


def take_names(captures) -> tuple[dict, list]:
    """Folder names for the takes of a session, unique and safe.

    Parameters
    ----------
    captures : sequence of path
        The capture files, in session order.

    Returns
    -------
    names : dict of Path to str
        Each capture's take name (:func:`safe_stem` of its stem; ``-2``,
        ``-3``... added, in session order, where two would share a name, case
        ignored, as on case-insensitive file systems).
    renamed : list of str
        One sentence per take whose name is not its file stem, to report.

    Examples
    --------
    >>> names, renamed = take_names(["a/take.c3d", "b/take.c3d", "c/...c3d"])
    >>> list(names.values())
    ['take', 'take-2', 'take-3']
    >>> renamed[0]
    "b/take.c3d: take named 'take-2' (another take is named 'take')"
    """
    names, renamed, used = {}, [], set()
    for capture in captures:
        capture = Path(capture)
        base = safe_stem(capture.stem)
        name, k = base, 2
        while name.lower() in used:
            name, k = f"{base}-{k}", k + 1
        used.add(name.lower())
        names[capture] = name
        if name != capture.stem:
            why = (f"another take is named {base!r}" if name != base
                   else "its file stem is not a safe folder name")
            renamed.append(f"{capture}: take named {name!r} ({why})")
    return names, renamed


def check_take_dir(out_dir, name: str, inputs=()) -> Path:
    """The folder of take `name`: a direct child of `out_dir` that holds no input.

    Raises
    ------
    InputError
        The folder would resolve outside `out_dir` or would hold (or be) one of
        `inputs`: committing the take replaces the folder.
    """
    out_dir = Path(out_dir)
    folder = out_dir / name
    if folder.parent != out_dir or not is_inside(folder, out_dir) \
            or os.path.realpath(folder) == os.path.realpath(out_dir):
        raise InputError(f"take name {name!r}: its folder would not lie inside {out_dir}")
    for item in inputs:
        if is_inside(item, folder):
            raise InputError(f"{folder}: the folder of take {name!r} holds the input {item}; "
                             "choose another output directory")
    return folder


def staging_dir(out_dir) -> Path:
    """Where takes are staged before being committed (created)."""
    path = Path(out_dir) / STAGING_NAME
    path.mkdir(exist_ok=True)
    return path


@contextmanager
def output_lock(out_dir):
    """Hold the output directory for one run (creating it); an error if a run holds it.

    Raises
    ------
    InputError
        Another process (a run, or the workers of a killed one) holds the lock;
        the directory cannot be created or the lock file written.
    """
    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        fd = os.open(out_dir / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        raise InputError(f"{out_dir}: cannot write the output directory: "
                         f"{exc.strerror or exc}") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EAGAIN, errno.EACCES):
                raise InputError(f"{out_dir}: cannot lock the output directory: "
                                 f"{exc.strerror}") from None
            holder = os.pread(fd, 64, 0).decode("ascii", "replace").strip() or "?"
            raise InputError(f"{out_dir}: another mocap2mesh run (pid {holder}) is writing "
                             "into this directory; wait for it to finish") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield out_dir
    finally:
        os.close(fd)


def clean_stale(out_dir) -> list:
    """Remove what killed runs left in `out_dir`: the staging folder and temporary files.

    Call it holding :func:`output_lock` (no other run is writing).

    Returns
    -------
    list of Path
        What was removed.
    """
    out_dir = Path(out_dir)
    removed = []
    staging = out_dir / STAGING_NAME
    if staging.exists():
        shutil.rmtree(staging)
        removed.append(staging)
    for root, dirs, files in os.walk(out_dir):
        for name in files:
            if is_temp_name(name):
                path = Path(root) / name
                path.unlink(missing_ok=True)
                removed.append(path)
    return removed
