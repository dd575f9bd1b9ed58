"""The configuration of ``mocap2mesh run``: one TOML file naming the inputs and every stage's options.

Schema (paths are relative to the configuration file; every table but
``[inputs]`` is optional, every key of a stage table is an option of that
stage with the same name)::

    [inputs]
    captures = ["take1.c3d", "take2.c3d"]   # or: session = "captures/" (its .c3d .csv .trc)
    markerset = "markerset.toml"
    mesh = "neutral.obj"
    mesh_units = "cm"          # optional, when the mesh file does not say
    landmarks = "landmarks.toml"
    basis = "shapes"           # save_basis directory or .npz, a folder of OBJ shapes, or .glb

    [output]
    directory = "out"          # default: "out" beside the configuration

    [run]                      # where the takes run (fit.pipeline.executors)
    executor = "local"         # "local" (a process pool) or "dask"
    scheduler = "tcp://host:8786"   # dask only; default: a LocalCluster started for the run
    workers = 2                # parallel takes / LocalCluster workers; default: min(2, takes)
    timeout = 3600             # s a take may run before it is stopped and failed; default: none

    [ingest]    # mocap.clean.ingest.IngestOptions: fix_swaps, reject_implausible, fill,
                #   max_gap (default 0.1 s), min_visible, extra_markers, lowpass_hz, ...,
                #   stabilize = "head" | "auto" | "none" (default "head"),
                #   robust_stabilization, robust_guard_deg
    [bind]      # fit.pipeline.stages.BindOptions: frame, icp, skin_offset, max_distance_warn
    [retarget]  # mocap.retarget.retargeting.RetargetOptions: kernel ("auto", the default: chosen
                #   by cross-validation), epsilon, degree, smoothing, distance, use_regions, ...
    [basis]     # fit.pipeline.stages.BasisOptions: pca_components, pca_coverage, qe_missing,
                #   missing_eps, scope ("session": one PCA/QE for all takes, or "take")
    [fit]       # fit.pipeline.stages.FitOptions: space, h_epsilon, smoothness, moving_average,
                #   h_solver, n_samples, n_neighbors, marker_centres
    [report]    # ReportOptions: video, video_step, n_worst, exaggerate, held_out_folds,
                #   held_out_guard_s, mesh_views

    [open_questions]   # written by `mocap2mesh init`: a file with a question is refused

Every error names the file and the key at fault (``run.toml: fit.space: ...``).
``mocap2mesh init`` writes a file with every key, its default and a comment
(:mod:`fit.pipeline.template`).
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from pathlib import Path

from fit.pipeline.executors import EXECUTORS
from fit.pipeline.options import BasisOptions, BindOptions, FitOptions, ReportOptions
from mocap.clean.ingest import STABILIZATIONS, IngestOptions
from mocap.errors import InputError
from mocap.retarget.retargeting import RetargetOptions
from mocap.util.files import as_path
from mocap.util.toml import check_open_questions, read_toml
from mocap.util.validation import as_choice, as_int, as_positive_float

__all__ = ["RunConfig", "load_run_config", "stage_options", "CAPTURE_SUFFIXES", "STAGE_TABLES",
           "INPUT_KEYS", "OUTPUT_KEYS", "RUN_KEYS", "CHAIN_DEFAULTS"]

#: Files of a session directory taken as captures.
CAPTURE_SUFFIXES = (".c3d", ".csv", ".trc")


#: The option tables: TOML table name -> options class.
STAGE_TABLES = {"ingest": IngestOptions, "bind": BindOptions, "retarget": RetargetOptions,
                "basis": BasisOptions, "fit": FitOptions, "report": ReportOptions}
#: The keys of ``[inputs]``, each with what it is (paths relative to the file).
INPUT_KEYS = {
    "captures": "the takes: a list of capture files (C3D, Vicon CSV, TRC)",
    "session": "or a directory: every .c3d .csv .trc file in it is a take",
    "markerset": "marker-set TOML: head markers, regions, landmark markers",
    "mesh": "the neutral face mesh (OBJ, PLY, glTF)",
    "mesh_units": "units of the mesh when its file does not say (mm, cm, m, in)",
    "landmarks": "mesh-landmark TOML: anatomical point = vertex id",
    "basis": "the artist basis: a folder of OBJ shapes, a .glb, or a saved basis",
}
#: The keys of ``[output]``, each with what it is.
OUTPUT_KEYS = {
    "directory": "where every take's outputs go (default: out, beside this file)",
}
#: The keys of ``[run]``: where the takes run (:mod:`fit.pipeline.executors`).
RUN_KEYS = {
    "executor": 'where the takes run: "local" (a process pool) or "dask"',
    "scheduler": "Dask scheduler address (tcp://host:8786); default: a LocalCluster for the run",
    "workers": "takes run in parallel, or LocalCluster workers (default: min(2, takes))",
    "timeout": "seconds a take may run before it is stopped and failed (default: none)",
}
#: Options whose default in the chain differs from their stage's (the stage
#: function alone does not stabilize; the chain always does).
CHAIN_DEFAULTS = {"ingest": {"stabilize": "head"}}
_TOP = {"inputs", "output", "run", "open_questions", *STAGE_TABLES}


@dataclass(frozen=True)
class RunConfig:
    """A validated run configuration (paths absolute).

    Attributes
    ----------
    path : Path
        The configuration file.
    captures : tuple of Path
        The takes, in order.
    markerset, mesh, landmarks, basis : Path
    mesh_units : str or None
    output : Path
    workers : int
        Takes run in parallel (LocalCluster workers for ``executor="dask"``).
    ingest, bind, retarget, basis_options, fit, report
        The options of each stage.
    session : Path or None
        The directory of ``inputs.session``, when the captures come from one.
    executor : {"local", "dask"}
        Where the takes run (:mod:`fit.pipeline.executors`).
    scheduler : str or None
        Address of a Dask scheduler; None starts a LocalCluster for the run.
    timeout : float or None, s
        Longest a take may run; None: no limit.
    """

    path: Path
    captures: tuple
    markerset: Path
    mesh: Path
    landmarks: Path
    basis: Path
    mesh_units: str | None
    output: Path
    workers: int
    ingest: IngestOptions
    bind: BindOptions
    retarget: RetargetOptions
    basis_options: BasisOptions
    fit: FitOptions
    report: ReportOptions
    session: Path | None = None
    executor: str = "local"
    scheduler: str | None = None
    timeout: float | None = None

    @property
    def shared_inputs(self) -> dict:
        """Inputs every take reads, by role."""
        return {"markerset": self.markerset, "mesh": self.mesh, "landmarks": self.landmarks,
                "basis": self.basis}

    def parameters(self) -> dict:
        """Every stage's options as plain data (for the manifest and the skip logic)."""
        return {"mesh_units": self.mesh_units,
                **{table: dataclasses.asdict(self.options(table)) for table in STAGE_TABLES}}

    def options(self, table: str):
        """The options of one stage table."""
        return getattr(self, "basis_options" if table == "basis" else table)


def _fail(path, key: str, message: str):
    raise InputError(f"{path}: {key}: {message}")


def _unknown(path, table: dict, known, prefix: str) -> None:
    for key in table:
        if key not in known:
            _fail(path, f"{prefix}{key}", f"unknown key; expected one of {sorted(known)}")


def _file(path: Path, value, key: str, *, directory: bool | None = False) -> Path:
    if not isinstance(value, str) or not value:
        _fail(path, key, f"expected a path (string), got {value!r}")
    try:
        resolved = (path.parent / as_path(value, key)).resolve()
        exists, is_dir, is_file = resolved.exists(), resolved.is_dir(), resolved.is_file()
    except InputError as exc:
        _fail(path, key, str(exc))
    except (OSError, RuntimeError) as exc:   # a name too long, a symlink loop
        _fail(path, key, f"{value!r} is not a usable path: {exc.strerror or exc}")
    if not exists:
        _fail(path, key, f"{resolved} does not exist")
    if directory is True and not is_dir:
        _fail(path, key, f"{resolved} is not a directory")
    if directory is False and not is_file:
        _fail(path, key, f"{resolved} is not a file")
    return resolved


def _captures(path: Path, inputs: dict) -> tuple:
    if ("captures" in inputs) == ("session" in inputs):
        _fail(path, "inputs.captures", "give either inputs.captures (a list of files) or "
                                       "inputs.session (a directory), not both nor neither")
    if "session" in inputs:
        folder = _file(path, inputs["session"], "inputs.session", directory=True)
        try:
            found = sorted(p for p in folder.iterdir() if p.suffix.lower() in CAPTURE_SUFFIXES
                           and p.is_file())
        except OSError as exc:
            _fail(path, "inputs.session", f"cannot list {folder}: {exc.strerror or exc}")
        if not found:
            _fail(path, "inputs.session", f"{folder} holds no {'/'.join(CAPTURE_SUFFIXES)} file")
        return tuple(found)
    listed = inputs["captures"]
    if isinstance(listed, str):
        listed = [listed]
    if not isinstance(listed, list) or not listed:
        _fail(path, "inputs.captures", f"expected a non-empty list of paths, got {listed!r}")
    return tuple(_file(path, item, f"inputs.captures[{i}]") for i, item in enumerate(listed))


def stage_options(name: str, table, *, where="run configuration"):
    """The options of stage table `name` (``"fit"``, ...) from a mapping of its keys.

    Parameters
    ----------
    name : str
        A key of :data:`STAGE_TABLES`.
    table : mapping
        Option name -> value, as in the TOML table.
    where : str or path
        Named first in errors (the configuration file).

    Raises
    ------
    InputError
        An unknown key or a wrong value; the message names `where` and the
        key (``fit.space: ...``).

    Examples
    --------
    >>> stage_options("fit", {"smoothness": "gcv"}).smoothness
    'gcv'
    """
    cls = STAGE_TABLES[name]
    if not isinstance(table, dict):
        _fail(where, name, f"expected a table, got {table!r}")
    known = {f.name for f in dataclasses.fields(cls)}
    _unknown(where, table, known, f"{name}.")
    if name == "ingest" and "stabilize" in table and table["stabilize"] not in STABILIZATIONS:
        _fail(where, "ingest.stabilize", f"the chain always stabilizes: expected one of "
                                         f"{', '.join(map(repr, STABILIZATIONS))}, got "
                                         f"{table['stabilize']!r}")
    for key, value in table.items():            # one key at a time: the error names it
        try:
            cls(**{key: value})
        except (InputError, TypeError, ValueError) as exc:
            _fail(where, f"{name}.{key}", str(exc))
    try:
        return cls(**table)
    except (InputError, TypeError, ValueError) as exc:
        _fail(where, name, str(exc))


def load_run_config(path) -> RunConfig:
    """Read and validate a run configuration.

    Parameters
    ----------
    path : str or os.PathLike
        The TOML file (schema in the module docstring).

    Returns
    -------
    RunConfig

    Raises
    ------
    FileFormatError
        The file cannot be read, is not UTF-8 or not valid TOML (with the line),
        or holds an open question (``[open_questions]``) not answered.
    InputError
        A missing or unknown key, a wrong value, a path that does not exist:
        the message names the file and the key (``inputs.mesh``, ``fit.space``).
    """
    path = as_path(path).resolve()
    doc = read_toml(path, "run configuration")
    _unknown(path, doc, _TOP, "")
    check_open_questions(doc, path, "run configuration")
    inputs = doc.get("inputs")
    if not isinstance(inputs, dict):
        _fail(path, "inputs", "missing table [inputs] (captures, markerset, mesh, landmarks, "
                              "basis)")
    _unknown(path, inputs, INPUT_KEYS, "inputs.")
    for key in ("markerset", "mesh", "landmarks", "basis"):
        if key not in inputs:
            _fail(path, f"inputs.{key}", "missing")
    captures = _captures(path, inputs)
    units = inputs.get("mesh_units")
    if units is not None and not isinstance(units, str):
        _fail(path, "inputs.mesh_units", f"expected a unit name such as 'cm', got {units!r}")
    output = doc.get("output", {})
    if not isinstance(output, dict):
        _fail(path, "output", f"expected a table, got {output!r}")
    _unknown(path, output, {*OUTPUT_KEYS, "workers"}, "output.")  # workers: the old place of run.workers
    directory = output.get("directory", "out")
    if not isinstance(directory, str) or not directory:
        _fail(path, "output.directory", f"expected a path (string), got {directory!r}")
    try:
        out_dir = (path.parent / as_path(directory, "output.directory")).resolve()
    except InputError as exc:
        _fail(path, "output.directory", str(exc))
    except (OSError, RuntimeError) as exc:
        _fail(path, "output.directory", f"{directory!r} is not a usable path: "
                                        f"{exc.strerror or exc}")
    run = _run_table(path, doc.get("run", {}), output, len(captures))
    stages = {}
    for name in STAGE_TABLES:
        table = doc.get(name, {})
        if isinstance(table, dict):
            table = CHAIN_DEFAULTS.get(name, {}) | table
        stages[name] = stage_options(name, table, where=path)
    return RunConfig(
        path=path, captures=captures,
        markerset=_file(path, inputs["markerset"], "inputs.markerset"),
        mesh=_file(path, inputs["mesh"], "inputs.mesh"),
        landmarks=_file(path, inputs["landmarks"], "inputs.landmarks"),
        basis=_file(path, inputs["basis"], "inputs.basis", directory=None),
        mesh_units=units, output=out_dir,
        ingest=stages["ingest"], bind=stages["bind"], retarget=stages["retarget"],
        basis_options=stages["basis"], fit=stages["fit"], report=stages["report"],
        session=captures[0].parent if "session" in inputs else None, **run)


def _run_table(path: Path, run, output: dict, n_captures: int) -> dict:
    """``executor``, ``scheduler``, ``workers`` and ``timeout`` from ``[run]``."""
    if not isinstance(run, dict):
        _fail(path, "run", f"expected a table, got {run!r}")
    _unknown(path, run, RUN_KEYS, "run.")
    workers_key = "run.workers"
    if "workers" in output:
        if "workers" in run:
            _fail(path, "output.workers", "workers is given in [run] and in [output]; "
                                          "keep run.workers")
        warnings.warn(f"{path}: output.workers is now run.workers ([run] table); "
                      "output.workers is read until mocap2mesh 0.3", FutureWarning,
                      stacklevel=3)
        run = {**run, "workers": output["workers"]}
        workers_key = "output.workers"
    values = {}
    for key, check in (("executor", lambda v: as_choice(v, "executor", EXECUTORS)),
                       ("scheduler", _address),
                       ("workers", lambda v: as_int(v, "workers", minimum=1)),
                       ("timeout", lambda v: as_positive_float(v, "timeout"))):
        if key in run:
            try:
                values[key] = check(run[key])
            except InputError as exc:
                _fail(path, workers_key if key == "workers" else f"run.{key}", str(exc))
    values.setdefault("workers", min(2, n_captures))
    if "scheduler" in values and values.get("executor") != "dask":
        _fail(path, "run.scheduler", "a scheduler address needs executor = \"dask\"")
    return values


def _address(value) -> str:
    if not isinstance(value, str) or not value.strip():
        raise InputError(f"scheduler must be an address such as 'tcp://host:8786', "
                         f"got {value!r}")
    return value.strip()
