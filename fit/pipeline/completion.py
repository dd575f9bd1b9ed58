"""A take's outputs committed as a unit, with the record of what made them.

A take is written into a fresh staging folder (:func:`begin_take`); when every
output is there, :func:`commit_take` hashes them, writes the take's completion
record (``take-record.json``) last and atomically, and swaps the folder in as
``<output>/<take>/``. A later run trusts the folder only if
:func:`verify_take` finds that record, made from the same capture, shared
inputs and parameters (:class:`Provenance`), with every output it lists
present with its recorded size and SHA-256. A kill at any moment thus leaves
each take either committed and verifiable, or not trusted (then redone); a
folder's files always come from one run.

The protocol, for any executor (local pool, Dask, a script)::

    stage = begin_take(out_dir, "take01")
    ...write every output of the take below `stage`...
    record = commit_take(stage, out_dir, "take01", provenance, summary={...})

    verdict = verify_take(out_dir, "take01", provenance)
    verdict.reusable, verdict.reason      # True, "done by an earlier run; 41 outputs verified"

Record layout::

    {"format": "mocap2mesh-take-record-1", "name": "take01", "key": sha256,
     "created": ISO time, "capture": {"path", "sha256"}, "inputs": {role: {"path", "sha256"}},
     "parameters": {...}, "versions": {...},
     "files": {"relative/path": {"bytes": int, "sha256": hex}},   # below the take folder
     "summary": {...}}                                          # the manifest's take entry
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path, PurePosixPath

from fit.pipeline.manifest import json_default, package_versions, sha256_path, take_key
from fit.pipeline.outdir import check_take_dir, staging_dir
from mocap.errors import InputError
from mocap.util.atomic import atomic_path, is_inside
from mocap.util.blas import map_on_blas_threads

__all__ = ["RECORD_NAME", "FORMAT", "Provenance", "TakeRecord", "Verdict", "input_entries",
           "begin_take", "commit_take", "discard_stage", "read_record", "verify_take",
           "plan_takes"]

RECORD_NAME = "take-record.json"
FORMAT = "mocap2mesh-take-record-1"


@dataclass(frozen=True)
class Provenance:
    """What a take's outputs are made from.

    Attributes
    ----------
    capture : dict
        ``{"path": str, "sha256": hex}`` of the capture file.
    inputs : dict of str to dict
        The shared inputs by role, each ``{"path", "sha256"}``.
    parameters : dict
        Every stage's options (JSON-serializable).
    """

    capture: dict
    inputs: dict
    parameters: dict

    @classmethod
    def of(cls, capture, inputs: dict, parameters: dict) -> "Provenance":
        """The provenance of a take of `capture` (hashed here).

        `inputs` are the shared inputs' entries, hashed once for every take
        (:func:`input_entries`).
        """
        return cls({"path": str(capture), "sha256": sha256_path(capture)}, inputs, parameters)

    @property
    def key(self) -> str:
        """Hash of everything the outputs depend on (:func:`~fit.pipeline.manifest.take_key`)."""
        return take_key(self.capture["sha256"], self.inputs, self.parameters)

    def differences(self, record: dict) -> list:
        """What differs from a record's provenance, one phrase each (empty: nothing)."""
        found = []
        if record.get("capture", {}).get("sha256") != self.capture["sha256"]:
            found.append("the capture changed")
        old_inputs = record.get("inputs", {})
        for role in sorted(set(old_inputs) | set(self.inputs)):
            old = old_inputs.get(role, {}).get("sha256")
            if old != self.inputs.get(role, {}).get("sha256"):
                found.append(f"input {role} changed")
        found += _changed_options(record.get("parameters", {}), self.parameters)
        return found


def _changed_options(old: dict, new: dict, prefix: str = "") -> list:
    out = []
    for name in sorted(set(old) | set(new), key=str):
        a, b = old.get(name, "(unset)"), new.get(name, "(unset)")
        if isinstance(a, dict) and isinstance(b, dict):
            out += _changed_options(a, b, f"{prefix}{name}.")
        elif json.dumps(a, sort_keys=True, default=str) != json.dumps(b, sort_keys=True,
                                                                        default=str):
            out.append(f"parameter {prefix}{name} changed ({a!r} -> {b!r})")
    return out


def input_entries(paths: dict) -> dict:
    """``{role: {"path", "sha256"}}`` of input files or directories given by role."""
    return {role: {"path": str(p), "sha256": sha256_path(p)} for role, p in paths.items()}


@dataclass(frozen=True)
class TakeRecord:
    """A committed take's completion record (see the module docstring)."""

    name: str
    key: str
    files: dict
    summary: dict
    document: dict = field(repr=False)

    def paths(self, out_dir) -> list:
        """Each output as a path, below ``out_dir / name``."""
        return [Path(out_dir) / self.name / rel for rel in self.files]


@dataclass(frozen=True)
class Verdict:
    """Whether a take's folder can stand for a new run of it.

    Attributes
    ----------
    name : str
    reusable : bool
    reason : str
        Why (``"the capture changed"``, ``"output x.npz changed size"``...).
    record : TakeRecord or None
        The record found (None when absent or unreadable).
    """

    name: str
    reusable: bool
    reason: str
    record: TakeRecord | None = None


def begin_take(out_dir, name: str) -> Path:
    """A new, empty staging folder for take `name` (inside ``out_dir/.staging``)."""
    check_take_dir(out_dir, name)
    stage = staging_dir(out_dir) / f"{name}.{os.getpid()}.{secrets.token_hex(4)}"
    stage.mkdir()
    return stage


def discard_stage(stage) -> None:
    """Remove a staging folder whose take failed."""
    shutil.rmtree(stage, ignore_errors=True)


def _relative(path: Path, root: Path) -> str:
    if not is_inside(path, root) or path.is_symlink():
        raise InputError(f"{path}: an output of the take lies outside its folder {root}")
    return path.relative_to(root).as_posix()


def commit_take(stage, out_dir, name: str, provenance: Provenance, *, summary: dict,
                inputs=()) -> TakeRecord:
    """Record every file of `stage`, write the record last, and swap the folder in.

    Parameters
    ----------
    stage : path
        From :func:`begin_take`, holding every output of the take.
    out_dir : path
    name : str
        The take's folder name.
    provenance : Provenance
    summary : dict
        What the manifest records of the take (metrics, timings...), JSON-ready.
    inputs : iterable of path
        Inputs the take folder must not hold.

    Returns
    -------
    TakeRecord
        With ``files`` relative to the take folder.
    """
    stage, out_dir = Path(stage), Path(out_dir)
    target = check_take_dir(out_dir, name, inputs)
    outputs = {}
    for path in sorted(stage.rglob("*")):
        if path.is_file() or path.is_symlink():
            rel = _relative(path, stage)
            if rel != RECORD_NAME:
                outputs[rel] = path
    # hashlib leaves the GIL while it hashes: the files on this process's share of cores
    digests = map_on_blas_threads(sha256_path, outputs.values())
    files = {rel: {"bytes": path.stat().st_size, "sha256": digest}
             for (rel, path), digest in zip(outputs.items(), digests)}
    doc = {"format": FORMAT, "name": name, "key": provenance.key,
           "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
           "capture": provenance.capture, "inputs": provenance.inputs,
           "parameters": provenance.parameters, "versions": package_versions(),
           "files": files, "summary": summary}
    with atomic_path(stage / RECORD_NAME) as tmp:
        Path(tmp).write_text(json.dumps(doc, indent=1, default=json_default) + "\n",
                             encoding="utf-8")
    if target.exists():      # the previous folder of this take goes first, then the new one in
        old = staging_dir(out_dir) / f"old-{stage.name}"
        os.replace(target, old)
        os.replace(stage, target)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(stage, target)
    return _record(json.loads(json.dumps(doc, default=json_default)))


def _record(doc: dict) -> TakeRecord:
    return TakeRecord(name=doc["name"], key=doc["key"], files=doc["files"],
                      summary=doc.get("summary", {}), document=doc)


def read_record(take_dir) -> TakeRecord | None:
    """The completion record of a take folder, or None when absent, unreadable or foreign."""
    try:
        doc = json.loads((Path(take_dir) / RECORD_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT \
            or not isinstance(doc.get("files"), dict) or not isinstance(doc.get("name"), str) \
            or not isinstance(doc.get("key"), str) or not isinstance(doc.get("summary", {}), dict):
        return None
    return _record(doc)


def _check_file(folder: Path, rel, entry) -> str:
    """Why a recorded output cannot be trusted ('' when it can)."""
    if not isinstance(rel, str) or not isinstance(entry, dict) \
            or PurePosixPath(rel).is_absolute() or ".." in PurePosixPath(rel).parts:
        return f"the record lists an output outside the take folder ({rel!r})"
    path = folder / rel
    if not is_inside(path, folder):
        return f"output {rel} lies outside the take folder"
    try:
        size = path.stat().st_size
    except OSError:
        return f"output {rel} is missing"
    if size != entry.get("bytes"):
        return f"output {rel} changed size ({entry.get('bytes')} -> {size} bytes)"
    if sha256_path(path) != entry.get("sha256"):
        return f"output {rel} changed (SHA-256 differs)"
    return ""


def verify_take(out_dir, name: str, provenance: Provenance) -> Verdict:
    """Whether the committed folder of take `name` can stand for a run with `provenance`.

    It can when its record is there, names this take, was made from the same
    capture, shared inputs and parameters (same key), and every output it
    lists exists with its recorded size and SHA-256.
    """
    folder = Path(out_dir) / name
    record = read_record(folder)
    if record is None:
        reason = ("not done yet" if not folder.exists()
                  else "no completion record (the run that wrote it did not finish it)")
        return Verdict(name, False, reason)
    if record.name != name:
        return Verdict(name, False, f"the record is of take {record.name!r}", record)
    if record.key != provenance.key:
        changed = provenance.differences(record.document) or ["its provenance changed"]
        return Verdict(name, False, "; ".join(changed), record)
    for rel, entry in record.files.items():
        problem = _check_file(folder, rel, entry)
        if problem:
            return Verdict(name, False, problem, record)
    n = len(record.files)
    return Verdict(name, True, f"done by an earlier run; {n} output{'s' * (n != 1)} verified",
                   record)


def plan_takes(out_dir, provenances: dict, *, force: bool = False) -> dict:
    """The :class:`Verdict` of each take (name -> provenance): what a run would skip, and why.

    With `force`, no take is reusable.
    """
    if force:
        return {name: Verdict(name, False, "redone on request (--force)") for name in provenances}
    return {name: verify_take(out_dir, name, p) for name, p in provenances.items()}
