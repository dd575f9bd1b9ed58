"""The ``mocap2mesh`` command line."""

from fit.cli.main import COMMANDS, console, main

__all__ = ["main", "console", "COMMANDS"]
