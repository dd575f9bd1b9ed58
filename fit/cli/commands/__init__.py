"""Subcommands of the ``mocap2mesh`` command line, one module each.

A command's module has ``add_parser(sub)``, which registers its parser, and ``HELP``, a
string literal: its line in the listing of every command, which
:func:`fit.cli.main.build_parser` reads from the module's source without importing it (the
modules import what their commands run: all of them take seconds).
"""
