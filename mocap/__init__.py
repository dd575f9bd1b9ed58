"""mocap: marker tracks, from raw capture files up to mesh displacements."""

import mocap._moved  # noqa: F401,E402 - old import paths, until 0.3
from mocap.errors import FileFormatError, InputError, MarkerError, Mocap2MeshError
from mocap.io import read, write
from mocap.take import FILL_METHODS, Analog, SourceInfo, Take

__all__ = ["Take", "SourceInfo", "Analog", "FILL_METHODS", "read", "write",
           "Mocap2MeshError", "FileFormatError", "MarkerError", "InputError"]
