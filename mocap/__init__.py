"""mocap: marker tracks, from raw capture files up to mesh displacements."""

from mocap.errors import FileFormatError, InputError, MarkerError, Mocap2MeshError
from mocap.io import read, write
from mocap.take import FILL_METHODS, Analog, SourceInfo, Take

__all__ = ["Take", "SourceInfo", "Analog", "FILL_METHODS", "read", "write",
           "Mocap2MeshError", "FileFormatError", "MarkerError", "InputError"]
