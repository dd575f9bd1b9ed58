"""One take, or a session of takes, through the whole chain.

- :mod:`.options`: the options of each stage (the tables of ``run.toml``);
- :mod:`.stages`: one function per stage, each returning a frozen result;
- :mod:`.config`: ``run.toml`` read and validated;
- :mod:`.reconstruction`: :class:`Reconstruction`, the scripting entry point;
- :mod:`.session`: every take of a session (:func:`run_takes`), with
  :mod:`.manifest` recording what was done and :mod:`.executors` running the
  takes (a local process pool, a Dask cluster, or any executor).
"""

from fit._moved import PIPELINE_NAMES
from fit.pipeline.config import RunConfig, load_run_config
from fit.pipeline.options import (
                                  BASES,
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

__all__ = ["BASES", "SPACES", "H_SOLVERS", "CENTRE_MODELS", "BindOptions", "BasisOptions",
           "FitOptions", "ReportOptions", "NamedBasis", "BasisResult", "FitResult",
           "complete_span", "ingest_stage", "bind_stage", "retarget_stage", "basis_stage",
           "fit_stage", "RunConfig", "load_run_config", "Reconstruction", "ReconstructionResult",
           "RunOutcome", "process_take", "run_takes"]

__getattr__ = moved_names(__name__, PIPELINE_NAMES)
