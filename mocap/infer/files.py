"""The marker set and the mesh landmarks of an :class:`~mocap.infer.capture.Inference`, as TOML.

Both files say, in comments, how each entry was found; what inference could
not decide is an ``[open_questions]`` entry, which makes the loaders refuse
the file (:func:`mocap.util.toml.check_open_questions`) until it is answered
and the line deleted.
"""

from __future__ import annotations

from pathlib import Path

from mocap.infer.capture import Inference
from mocap.markerset import REQUIRED_REGIONS
from mocap.util.atomic import atomic_path

__all__ = ["markerset_toml", "mesh_landmarks_toml", "write_text", "toml_string"]


def toml_string(text: str) -> str:
    """A TOML basic string of `text` (quotes and backslashes escaped).

    Examples
    --------
    >>> toml_string('say "hi"')
    '"say \\\\"hi\\\\""'
    """
    escaped = text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", " ")
    return f'"{escaped}"'


def _list(labels) -> str:
    return "[" + ", ".join(toml_string(x) for x in labels) + "]"


def _questions(inference: Inference, file: str) -> list:
    qs = [q for q in inference.questions if q.file == file]
    lines = ["", "# OPEN QUESTIONS: what `mocap2mesh init` could not decide. Answer each in this",
             "# file, then delete its line; a file with a question left is refused.",
             "[open_questions]"]
    return lines + [f"{q.key} = {toml_string(q.text)}" for q in qs] if qs else []


def markerset_toml(inference: Inference, *, source: str = "") -> str:
    """The marker-set file of an inference (:func:`mocap.markerset.load_markerset` reads it).

    Parameters
    ----------
    inference : Inference
    source : str
        The capture it was inferred from (named in the header).

    Returns
    -------
    str
        TOML text: name, the subject prefix, the head markers (or the
        stabilization markers), every region (the required ones, possibly
        empty), the landmark markers, and the open questions of the marker set.
    """
    inf = inference
    lines = [f"# Marker set inferred by `mocap2mesh init` from {source or 'a capture'}.",
             "# Left and right are the subject's own. Every entry says how it was found:",
             "# check them against init.png, then run.",
             f"name = {toml_string(Path(source).stem if source else 'inferred')}"]
    lines.append(f"prefix = {toml_string(inf.prefix)}   # stripped from the capture's labels"
                 if inf.prefix else 'prefix = ""   # the labels carry no subject prefix')
    if inf.flagged:
        lines.append("# not kept (they are in the capture but not in this set):")
        lines += [f"#   {label}: {why}" for label, why in inf.flagged]
    if inf.stabilization == "head":
        lines.append(f"head = {_list(_short(inf, inf.head))}   # rigid, apart from the face")
        lines.append("stabilization = []")
    else:
        lines.append("head = []   # no head markers: the run stabilizes on the markers below")
        lines.append("# face markers that hold their shape best over the take (stabilize = "
                     "'auto');")
        chosen = _short(inf, inf.stable.labels)
        lines.append("# distance variation (mm): " + ", ".join(
            f"{x} {v:.2f}" for x, v in zip(chosen, inf.stable.marker_variation)))
        lines.append("# an empty list makes every take choose its own")
        lines.append(f"stabilization = {_list(chosen)}")
    lines += ["", "[regions]   # by geometry on the mesh (and by name where noted)"]
    table = inf.region_table()
    named = {g.label: g for g in inf.regions if g.source == "name"}
    for region in list(REQUIRED_REGIONS) + [r for r in table if r not in REQUIRED_REGIONS]:
        labels = table.get(region, [])
        note = [f"{x}: by name, geometry says {named[x].geometry}" for x in labels
                if x in named]
        comment = f"   # {'; '.join(note)}" if note else ""
        lines.append(f"{region} = {_list(_short(inf, labels))}{comment}")
    lines += ["", "[landmarks]   # anatomical point = marker"]
    for pair in inf.landmarks:
        lines.append(f"{pair.point} = {toml_string(_short(inf, [pair.label])[0])}"
                     f"   # {pair.source}: {pair.how}")
    lines += _questions(inf, "markerset")
    return "\n".join(lines) + "\n"


def _short(inference: Inference, labels) -> list:
    """Labels without the subject prefix (the names the marker set uses)."""
    p = inference.prefix
    return [x[len(p):] if p and x.startswith(p) else x for x in labels]


def mesh_landmarks_toml(inference: Inference, *, mesh_name: str = "",
                        n_vertices: int | None = None) -> str:
    """The mesh-landmark file (:func:`mocap.mesh.landmarks.load_mesh_landmarks` reads it)."""
    marks = inference.mesh_landmarks
    how = "found from the mesh itself" if marks.found else "as given"
    lines = [f"# Landmarks of {mesh_name or 'the mesh'}, {how} (`mocap2mesh init`):"]
    lines += [f"#   {note}" for note in marks.notes]
    lines.append(f"mesh = {toml_string(mesh_name)}")
    if n_vertices is not None:
        lines.append(f"n_vertices = {n_vertices}")
    lines += ["", "[landmarks]   # anatomical point = 0-based vertex id"]
    lines += [f"{point} = {vertex}" for point, vertex in marks.landmarks.items()]
    lines += _questions(inference, "landmarks")
    return "\n".join(lines) + "\n"


def write_text(path, text: str, *, inputs=()) -> None:
    """Write `text` (UTF-8) to `path` atomically, never over one of `inputs`."""
    with atomic_path(path, inputs=inputs) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
