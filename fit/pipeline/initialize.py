"""``mocap2mesh init``: the files a first run needs, for a capture and a mesh never seen before.

:func:`initialize` infers (:func:`mocap.infer.capture.infer_capture`) and
writes into one directory:

- ``markerset.toml``: prefix, head or stabilization markers, regions, landmark markers;
- ``landmarks.toml``: the mesh landmarks (found from the mesh when none are given);
- ``run.toml``: every key of the run configuration with its default and a
  comment (:func:`fit.pipeline.template.run_config_text`), the inputs filled in;
- ``init.png``: the markers by region, landmarks named; ``mesh_landmarks.png``:
  the mesh with the landmarks found.

What inference could not decide is an open question in the file it belongs
to; the loaders (and so ``run``) refuse a file with an open question.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import mocap
from basis.basis_io import load_any_basis
from fit.pipeline.template import run_config_text
from mocap.clean.gapfill import DEFAULT_MAX_GAP_S, default_max_gap
from mocap.errors import InputError
from mocap.gaps import find_gaps
from mocap.infer.capture import Inference, OpenQuestion, infer_capture
from mocap.infer.files import markerset_toml, mesh_landmarks_toml, write_text
from mocap.infer.names import NAMING_CONVENTIONS
from mocap.infer.picture import plot_inference, plot_mesh_landmarks
from mocap.mesh import load_mesh
from mocap.mesh.landmarks import load_mesh_landmarks

__all__ = ["Initialized", "initialize", "OUTPUT_FILES"]

#: What :func:`initialize` writes into its directory.
OUTPUT_FILES = ("markerset.toml", "landmarks.toml", "run.toml", "init.png",
                "mesh_landmarks.png")


@dataclass(frozen=True, eq=False)
class Initialized:
    """What :func:`initialize` inferred and wrote.

    Attributes
    ----------
    inference : Inference
    files : dict of str to Path
        Name -> path of each file written.
    questions : list of OpenQuestion
        Everything left open (in every file).
    lines : list of str
        The report ``mocap2mesh init`` prints.
    """

    inference: Inference
    files: dict
    questions: list
    lines: list


def _longest_inner_gap(take, inference: Inference):
    """The face markers' longest gap that filling would have to bridge, or None.

    (label, first frame number, length in frames); gaps at the ends of the take
    are not filled (they are cut off with the end frames) and do not count.
    """
    raw = [inference.prefix + name if inference.prefix + name in take.labels else name
           for name in inference.face]
    gaps = find_gaps(take.select(raw).missing)
    inner = ~gaps.at_edge
    if not inner.any():
        return None
    k = int(gaps.length[inner].argmax())
    marker, start, length = (int(a[inner][k]) for a in (gaps.marker, gaps.start, gaps.length))
    return inference.face[marker], take.first_frame + start, length


def _relative(path: Path, directory: Path) -> str:
    return Path(os.path.relpath(Path(path).resolve(), directory.resolve())).as_posix()


def initialize(capture, mesh, directory, *, shapes=None, landmarks=None,
               mesh_units: str | None = None, force: bool = False) -> Initialized:
    """Infer the marker set, landmarks and run configuration of a capture; write them.

    Parameters
    ----------
    capture : str or os.PathLike
        A capture file (C3D, Vicon CSV, TRC, take ``.npz``).
    mesh : str or os.PathLike
        The neutral face mesh to bind to.
    directory : str or os.PathLike
        Where the files go (created).
    shapes : str or os.PathLike, optional
        The artist basis (OBJ folder, ``.glb`` or saved basis) of the mesh;
        without it, ``[inputs] basis`` is an open question.
    landmarks : str or os.PathLike, optional
        The mesh's landmark file, if it has one (referred to by ``run.toml``;
        no ``landmarks.toml`` is written).
    mesh_units : str, optional
        Units of the mesh file when it does not say; default inferred from the
        face's size (an open question when it is not a real-size face).
    force : bool, default False
        Overwrite the files of an earlier ``init`` in `directory`.

    Returns
    -------
    Initialized

    Raises
    ------
    InputError
        A file of :data:`OUTPUT_FILES` exists in `directory` (without `force`),
        or `shapes` does not fit the mesh; the errors of reading the inputs
        and of :func:`mocap.infer.capture.infer_capture`.
    """
    directory = Path(directory)
    existing = [name for name in OUTPUT_FILES if (directory / name).exists()]
    if existing and not force:
        raise InputError(f"{directory / existing[0]} exists (an earlier init?); answers "
                         "written there would be lost: choose another directory or --force")
    inputs = [Path(p) for p in (capture, mesh, shapes, landmarks) if p is not None]
    take = mocap.read(capture)
    face_mesh = load_mesh(mesh, units=mesh_units)
    given = load_mesh_landmarks(landmarks, face_mesh) if landmarks is not None else None
    if shapes is not None:
        load_any_basis(shapes, face_mesh)                 # refuses another topology now
    inference = infer_capture(take, face_mesh, mesh_landmarks=given)
    directory.mkdir(parents=True, exist_ok=True)
    files = {name: directory / name for name in OUTPUT_FILES}
    source = Path(capture).name
    write_text(files["markerset.toml"], markerset_toml(inference, source=source),
               inputs=inputs)
    if landmarks is None:
        write_text(files["landmarks.toml"],
                   mesh_landmarks_toml(inference, mesh_name=Path(mesh).name,
                                       n_vertices=face_mesh.n_vertices), inputs=inputs)
        plot_mesh_landmarks(face_mesh, inference, files["mesh_landmarks.png"])
    else:
        del files["landmarks.toml"], files["mesh_landmarks.png"]
    plot_inference(inference, files["init.png"], title=source)

    run_inputs = {"captures": [_relative(capture, directory)], "markerset": "markerset.toml",
                  "mesh": _relative(mesh, directory),
                  "landmarks": "landmarks.toml" if landmarks is None
                  else _relative(landmarks, directory)}
    questions = {}
    units = face_mesh.units or inference.alignment.units
    if units is not None:
        run_inputs["mesh_units"] = units
    else:
        questions["mesh_units"] = (
            f"the mesh's units: the face fits the capture at {inference.alignment.scale:.4g} "
            "mesh units per mm, which is no real-size face in mm, cm, m or in: set "
            "[inputs] mesh_units (or leave it out for a unitless mesh)")
    if shapes is not None:
        run_inputs["basis"] = _relative(shapes, directory)
    else:
        questions["basis"] = ("the artist basis of the mesh (a folder of OBJ shapes, a .glb or "
                              "a saved basis): set [inputs] basis")
    for q in inference.questions:
        if q.file == "run":
            questions[q.key] = q.text
    options, reasons = {}, {}
    if inference.stabilization == "auto":
        options["ingest"] = {"stabilize": "auto"}
        reasons["ingest.stabilize"] = ("init found no head markers: the markers of the marker "
                                       "set's stabilization list stand in")
    longest = _longest_inner_gap(take, inference)
    if longest is not None and longest[2] > default_max_gap(take.rate):
        label, first, length = longest
        options.setdefault("ingest", {})["max_gap"] = length
        reasons["ingest.max_gap"] = (
            f"the face markers have gaps up to {length} frames ({length / take.rate:.2f} s: "
            f"{label} from frame {first}), longer than the default "
            f"{default_max_gap(take.rate)} ({DEFAULT_MAX_GAP_S:g} s) that the chain needs "
            "filled: check the filled stretches in the report's gap chart, or lower it and "
            "leave such markers out of the marker set")
    text = run_config_text(run_inputs, options=options, reasons=reasons, questions=questions,
                           header=f"Run configuration written by `mocap2mesh init` for {source}"
                                  f" and {Path(mesh).name}.")
    write_text(files["run.toml"], text, inputs=inputs)

    lines = inference.report()
    if "max_gap" in options.get("ingest", {}):
        lines.append(f"max_gap: {options['ingest']['max_gap']} frames ({reasons['ingest.max_gap']})")
    if units is not None and face_mesh.units is None:
        lines.append(f"mesh units: {units} (inferred: a real-size face)")
    for key, text in questions.items():
        lines.append(f"OPEN QUESTION (run) {key}: {text}")
    lines.append("naming conventions read: " + "; ".join(
        f"{example} ({what})" for example, what in NAMING_CONVENTIONS))
    lines.append("wrote " + ", ".join(str(p) for p in files.values()))
    every = list(inference.questions) + [OpenQuestion(k, "run", t) for k, t in questions.items()]
    if every:
        lines.append(f"{len(every)} open questions: answer them in the files, then run "
                     f"`mocap2mesh run {files['run.toml']}`")
    else:
        lines.append(f"look at {files['init.png']}, then `mocap2mesh run {files['run.toml']}`")
    return Initialized(inference=inference, files=files, questions=every, lines=lines)
