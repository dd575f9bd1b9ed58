"""One take, or a session of takes, through the whole chain.

- :mod:`.options`: the options of each stage (the tables of ``run.toml``);
- :mod:`.stages`: one function per stage, each returning a frozen result;
- :mod:`.config`: ``run.toml`` read and validated;
- :mod:`.reconstruction`: :class:`Reconstruction`, the scripting entry point;
- :mod:`.gaps`: the face markers ingestion left with gaps, named before binding;
- :mod:`.session`: every take of a session (:func:`run_takes`), with
  :mod:`.manifest` recording what was done, :mod:`.session_basis` the PCA the
  takes share (``[basis] scope = "session"``), :mod:`.take_warnings` what
  each take warned about, :mod:`.completion` committing each take as a unit
  with the record a later run verifies, :mod:`.outdir` keeping the output
  directory safe (lock, names, stale files), :mod:`.executors` running the
  takes (a local process pool, a Dask cluster, or any executor) and
  :mod:`.workers` making worker processes die with the run;
- :mod:`.template`: a complete ``run.toml``, every key with its default and a comment;
- :mod:`.initialize`: what ``mocap2mesh init`` writes for a capture never seen.
"""

from fit._moved import PIPELINE_NAMES
from fit.pipeline.config import RunConfig, load_run_config
from fit.pipeline.options import (
                                  BASES,
                                  BASIS_SCOPES,
                                  CENTRE_MODELS,
                                  H_SOLVERS,
                                  SPACES,
                                  BasisOptions,
                                  BindOptions,
                                  FitOptions,
                                  ReportOptions,
)
from fit.pipeline.reconstruction import Reconstruction, ReconstructionResult
from fit.pipeline.session import RunOutcome, process_take, run_takes
from fit.pipeline.stages import (
                                  BasisResult,
                                  FitResult,
                                  NamedBasis,
                                  basis_stage,
                                  bind_stage,
                                  complete_span,
                                  fit_stage,
                                  ingest_stage,
                                  retarget_stage,
)
from mocap.util.deprecation import moved_names

__all__ = ["BASES", "SPACES", "H_SOLVERS", "CENTRE_MODELS", "BASIS_SCOPES", "BindOptions",
           "BasisOptions", "FitOptions", "ReportOptions", "NamedBasis", "BasisResult", "FitResult",
           "complete_span", "ingest_stage", "bind_stage", "retarget_stage", "basis_stage",
           "fit_stage", "RunConfig", "load_run_config", "Reconstruction", "ReconstructionResult",
           "RunOutcome", "process_take", "run_takes"]

__getattr__ = moved_names(__name__, PIPELINE_NAMES)
