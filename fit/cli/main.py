"""The ``mocap2mesh`` command: a thin layer over the library functions.

Exit codes: 0 success, 1 bad input (a :class:`mocap.errors.Mocap2MeshError`,
printed as one line naming the file, marker or frame at fault), 2 usage error.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
import warnings

from fit.cli import commands
from mocap.errors import Mocap2MeshError

__all__ = ["main", "COMMANDS"]

#: Subcommands: every module of :mod:`fit.cli.commands`, each with ``add_parser`` and ``run``.
COMMANDS = tuple(sorted(m.name for m in pkgutil.iter_modules(commands.__path__)
                        if not m.name.startswith("_")))

EXIT_OK, EXIT_BAD_INPUT, EXIT_USAGE = 0, 1, 2


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand registered."""
    parser = argparse.ArgumentParser(
        prog="mocap2mesh",
        description="Raw facial motion capture to head-stabilized markers, face meshes "
                    "and blendshape bases.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        module = importlib.import_module(f"fit.cli.commands.{name}")
        module.add_parser(sub)
    return parser


def _format_warning(message, category, filename, lineno, line=None):
    return f"mocap2mesh: warning: {message}\n"


def main(argv=None) -> int:
    """Run the command line; returns the exit code."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:          # argparse: --help (0) or usage error (2)
        return int(exc.code or 0)
    warnings.formatwarning = _format_warning
    try:
        return int(args.run(args) or EXIT_OK)
    except Mocap2MeshError as exc:
        print(f"mocap2mesh {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("mocap2mesh: interrupted", file=sys.stderr)
        return 130


def console() -> None:  # pragma: no cover - the installed entry point
    """Entry point of the ``mocap2mesh`` console script."""
    sys.exit(main())


if __name__ == "__main__":  # pragma: no cover
    console()
