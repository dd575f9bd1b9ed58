"""``manifest.json`` of a run: inputs with SHA-256, parameters, versions, per-take results.

The manifest is also what makes re-runs cheap: a take whose key (the hash of
its capture, of the shared inputs and of every parameter) is unchanged since
the last successful run, and whose files are all still there, is skipped.

Layout::

    {"format": "mocap2mesh-manifest-1", "created": ISO time, "config": path,
     "versions": {"python": ..., "numpy": ..., ...},
     "parameters": {stage: {option: value}},
     "inputs": {role: {"path": ..., "sha256": ...}},      # + "session": {"takes", "sha256"}
     "session_basis": {"takes": {name: frames}, "n_components", "sha256", ...},  # if shared
     "takes": {name: {"capture": {"path", "sha256"}, "key",
                      "status": "ok" | "failed" | "pending" (not finished yet),
                      "skipped": bool, "error": str | null, "seconds",
                      "worker": {"host", "pid", "peak_rss_mb"},
                      "basis": {"scope", "pca_sha256"}, "warnings": [str],
                      "metrics": {basis: {...}}, "files": [relative paths], ...}}}
"""

from __future__ import annotations

import functools
import hashlib
import json
import platform
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path

from mocap.util.atomic import atomic_path

__all__ = ["MANIFEST_NAME", "FORMAT", "sha256_path", "package_versions", "take_key",
           "load_manifest", "reusable_record", "write_manifest", "json_default"]

MANIFEST_NAME = "manifest.json"
FORMAT = "mocap2mesh-manifest-1"
_PACKAGES = ("mocap2mesh", "numpy", "scipy", "pandas", "trimesh", "libigl",
             "opencv-contrib-python-headless", "matplotlib", "pygltflib")
_BLOCK = 1 << 20


def _file_digest(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(_BLOCK), b""):
            digest.update(block)
    return digest.hexdigest()


def sha256_path(path) -> str:
    """SHA-256 (hex) of a file, or of a directory's files.

    A directory hashes the sorted list of ``relative/path:sha256`` lines of
    every file below it (hidden files excluded), so renaming, adding or
    changing a shape file changes it.
    """
    path = Path(path)
    if path.is_file():
        return _file_digest(path)
    lines = [f"{p.relative_to(path).as_posix()}:{_file_digest(p)}"
             for p in sorted(path.rglob("*"))
             if p.is_file() and not any(part.startswith(".") for part in p.relative_to(path).parts)]
    return hashlib.sha256("\n".join(lines).encode()).hexdigest()


def package_versions() -> dict:
    """Python and the installed versions of the packages the chain uses (a new dict)."""
    return dict(_installed_versions())


@functools.cache
def _installed_versions() -> dict:
    """:func:`package_versions`, read once a process: the packages a process has imported
    do not change, and each read of the installed metadata costs a few milliseconds."""
    versions = {"python": platform.python_version()}
    for name in _PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return versions


def take_key(capture_sha256: str, inputs: dict, parameters: dict) -> str:
    """Hash of everything a take's outputs depend on.

    Parameters
    ----------
    capture_sha256 : str
    inputs : dict of role to {"sha256": ...}
        The shared inputs.
    parameters : dict
        Every stage's options (JSON-serializable).
    """
    doc = {"capture": capture_sha256,
           "inputs": {role: entry["sha256"] for role, entry in sorted(inputs.items())},
           "parameters": parameters}
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()


def load_manifest(path) -> dict | None:
    """The manifest at `path`, or None when absent or unreadable (then nothing is skipped)."""
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and doc.get("format") == FORMAT else None


def reusable_record(previous: dict | None, name: str, key: str, out_dir) -> dict | None:
    """The previous record of take `name` if it can stand for a new run, else None.

    It can when the take succeeded, its key is `key` and every file it listed
    (relative to `out_dir`) still exists.
    """
    if previous is None:
        return None
    record = previous.get("takes", {}).get(name)
    if not isinstance(record, dict) or record.get("status") != "ok" \
            or record.get("key") != key:
        return None
    out_dir = Path(out_dir)
    if not all((out_dir / f).is_file() for f in record.get("files", ())):
        return None
    return record


def write_manifest(path, *, config, versions: dict, parameters: dict, inputs: dict,
                   takes: dict, session_basis: dict | None = None) -> dict:
    """Write the manifest atomically; returns the document written.

    `session_basis` (:meth:`fit.pipeline.session_basis.SessionBasis.record`)
    is recorded under ``"session_basis"`` when the takes share one.
    """
    doc = {"format": FORMAT, "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
           "config": str(config),
           "versions": versions, "parameters": parameters, "inputs": inputs, "takes": takes}
    if session_basis is not None:
        doc["session_basis"] = session_basis
    with atomic_path(path) as tmp:
        Path(tmp).write_text(json.dumps(doc, indent=1, default=json_default) + "\n",
                             encoding="utf-8")
    return doc


def json_default(value):
    """JSON fallback (``json.dumps(..., default=json_default)``): numpy values, paths."""
    if hasattr(value, "tolist"):
        return value.tolist()
    return str(value)
