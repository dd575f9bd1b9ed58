"""Subcommands of the ``mocap2mesh`` command line, one module each."""
