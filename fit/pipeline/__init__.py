"""One take, or a session of takes, through the whole chain."""

from fit.pipeline.stages import *  # noqa: F401,F403
from fit.pipeline.stages import __all__  # noqa: F401
