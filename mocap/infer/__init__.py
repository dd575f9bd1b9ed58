"""What ``mocap2mesh init`` infers of a capture and a face mesh it has never seen.

- :mod:`mocap.infer.names`: subject prefixes, unlabeled markers, naming conventions;
- :mod:`mocap.infer.axes`: a face's symmetry plane, forward and up from its geometry;
- :mod:`mocap.infer.mesh_landmarks`: the Maskle's ten landmarks (and four more) of a mesh;
- :mod:`mocap.infer.alignment`: a neutral frame's markers placed on the mesh;
- :mod:`mocap.infer.regions`: facial regions from geometry and names;
- :mod:`mocap.infer.landmark_pairs`: the marker on each anatomical point;
- :mod:`mocap.infer.capture`: all of it for one capture (:func:`infer_capture`);
- :mod:`mocap.infer.files`, :mod:`mocap.infer.picture`: the marker set, the mesh
  landmarks and the pictures it writes.
"""

from mocap.infer.capture import Inference, OpenQuestion, infer_capture

__all__ = ["Inference", "OpenQuestion", "infer_capture"]
