"""fit: weight solving, reconstruction, QA output and the command line."""

import fit._moved  # noqa: F401 - old import paths, until 0.3
