"""The ``mocap2mesh`` command: a thin layer over the library functions.

Exit codes: 0 success, 1 bad input or an output that cannot be written (a
:class:`mocap.errors.Mocap2MeshError` or an ``OSError``: read-only folder, name
too long, disk full; printed as one line naming the file, marker or frame at
fault), 2 usage error, 130 interrupted, 141 output cut short by a closed pipe
(``mocap2mesh info FILE | head -3``; nothing printed).
"""

from __future__ import annotations

import argparse
import ast
import gc
import importlib
import os
import pkgutil
import re
import sys
import warnings
from pathlib import Path

from fit.cli import commands
from fit.cli.run_heap import expected_run_heap
from mocap.errors import Mocap2MeshError
from mocap.util.pretouch import finish_pretouch, start_pretouch
from mocap.util.process_memory import configure_process_memory

__all__ = ["main", "COMMANDS", "build_parser", "full_parser"]

#: Subcommands: every module of :mod:`fit.cli.commands`, each with ``add_parser`` and ``run``.
COMMANDS = tuple(sorted(m.name for m in pkgutil.iter_modules(commands.__path__)
                        if not m.name.startswith("_")))

EXIT_OK, EXIT_BAD_INPUT, EXIT_USAGE, EXIT_INTERRUPTED, EXIT_CLOSED_PIPE = 0, 1, 2, 130, 141

_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def build_parser(argv=None) -> argparse.ArgumentParser:
    """The argument parser of `argv`: when its first word names a subcommand, with that one
    registered alone (a command's module imports what it runs: the others' imports would
    only slow its start), else with every subcommand listed by its ``HELP`` line, read from
    its module's source (the listing, ``--help`` and the usage errors need no more)."""
    first = next(iter(argv or ()), None)
    if first in COMMANDS:
        return _parser(registered=(first,))
    return _parser(listed=COMMANDS)


def full_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand registered (imports every command)."""
    return _parser(registered=COMMANDS)


def _parser(*, registered=(), listed=()) -> argparse.ArgumentParser:
    """The parser with the commands `registered` (their modules imported) and the commands
    `listed` (a name and a help line each, no arguments: :func:`main` parses again with
    the one named registered)."""
    parser = argparse.ArgumentParser(
        prog="mocap2mesh",
        description="Raw facial motion capture to head-stabilized markers, face meshes "
                    "and blendshape bases.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        if name in registered:
            importlib.import_module(f"fit.cli.commands.{name}").add_parser(sub)
        elif name in listed:
            # every word after the name taken as it is (no option of its own, not even -h)
            listing = sub.add_parser(name, help=_help_line(name), add_help=False,
                                     prefix_chars="\0")
            listing.add_argument("words", nargs=argparse.REMAINDER)
            listing.set_defaults(listed=True)
    return parser


def _help_line(name: str) -> str:
    """The ``HELP`` string of command `name`'s module, from its source (not imported)."""
    source = Path(commands.__path__[0], f"{name}.py").read_text(encoding="utf-8")
    for node in ast.parse(source).body:
        if isinstance(node, ast.Assign) and [getattr(t, "id", None) for t in node.targets] \
                == ["HELP"] and isinstance(node.value, ast.Constant):
            return node.value.value
    raise RuntimeError(f"fit.cli.commands.{name} has no HELP string")


def _format_warning(message, category, filename, lineno, line=None):
    return f"mocap2mesh: warning: {_one_line(str(message))}\n"


def main(argv=None) -> int:
    """Run the command line; returns the exit code."""
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        args = build_parser(argv).parse_args(argv)
        if getattr(args, "listed", False):      # a command named after other words
            args = _parser(registered=(args.command,)).parse_args(argv)
    except SystemExit as exc:          # argparse: --help (0) or usage error (2)
        return int(exc.code or 0)
    warnings.formatwarning = _format_warning
    try:
        return int(args.run(args) or EXIT_OK)
    except Mocap2MeshError as exc:
        return _fail(args.command, str(exc))
    except BrokenPipeError:
        _silence_stdout()
        return EXIT_CLOSED_PIPE
    except OSError as exc:
        where = ": ".join(str(f) for f in (exc.filename, exc.filename2) if f is not None)
        return _fail(args.command, f"{where + ': ' if where else ''}{exc.strerror or exc}")
    except MemoryError:
        return _fail(args.command, "out of memory; a smaller input, fewer workers or a lower "
                                   "MOCAP2MESH_MAX_BYTES make reading refuse it early")
    except KeyboardInterrupt:
        print("mocap2mesh: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


def _one_line(text: str) -> str:
    """`text` with line breaks and other control characters shown as escapes."""
    return _CONTROL.sub(lambda m: repr(m[0])[1:-1], text)


def _fail(command: str, message: str) -> int:
    print(f"mocap2mesh {command}: error: {_one_line(message)}", file=sys.stderr)
    return EXIT_BAD_INPUT


def _silence_stdout() -> None:
    """Point stdout at /dev/null, so that the interpreter's last flush cannot fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):   # stdout is not a file descriptor (captured in tests)
        pass


def console() -> None:  # pragma: no cover - the installed entry point
    """Entry point of the ``mocap2mesh`` console script.

    The objects of the command's imports live as long as the process: the collector is
    off while they are made (its passes would walk the growing heap for nothing, about a
    tenth of the imports' time; the few cycles the imports leave behind stay), then they
    are frozen (:func:`gc.freeze`), so that its full passes during the command skip
    them. So are the command's own at its end, which the interpreter's exit would walk
    again in its last collections. Exit handlers, the flushing of stdout and stderr and
    the objects freed by reference counting go on as before.

    The command and the processes it starts keep the memory they free for reuse, and on a
    virtual machine that reports its free memory to the host, NumPy's huge-page advice is
    off (:func:`mocap.util.process_memory.configure_process_memory`). A command that draws
    figures forks the server of its figure helpers once its imports are done
    (:func:`fit.report.forked_helpers.start_fork_server`). While ``run`` imports, a thread
    writes the pages of a block of its heap as large as its take is expected to need
    (:func:`fit.cli.run_heap.expected_run_heap`), which the take's arrays then reuse
    (:mod:`mocap.util.pretouch`; :func:`fit.pipeline.session.run_takes` frees it).
    """
    configure_process_memory()
    argv = sys.argv[1:]
    if argv[:1] == ["run"]:
        start_pretouch(expected_run_heap(argv[1:]))
    gc.disable()
    try:
        build_parser(argv)  # the command's imports
    finally:
        gc.enable()
    gc.freeze()
    finish_pretouch()
    # a command that draws figures imported the helpers' module: their server is forked
    # now, before any thread starts
    if (helpers := sys.modules.get("fit.report.forked_helpers")) is not None:
        helpers.start_fork_server()
    code = main(argv)
    gc.freeze()
    sys.exit(code)


if __name__ == "__main__":  # pragma: no cover
    console()
