"""Retargeting: marker displacements drive a face mesh through an RBF operator.

- :mod:`.rbf`: the operator W (N, M) (kernels in :mod:`._kernels`);
- :mod:`.retargeting`: a stabilized, bound take made into displacements and W;
- :mod:`.archive`: retargeted takes on disk (``.npz`` archive, OBJ sequence).
"""

from mocap.retarget.archive import (
                                    CONTENTS,
                                    ArchiveFrames,
                                    is_retargeted_archive,
                                    save_npz,
                                    save_obj_sequence,
)
from mocap.retarget.rbf import RBFOperator, RBFSolveInfo, build_rbf_operator
from mocap.retarget.retargeting import (
                                    DISTANCES,
                                    KERNELS,
                                    Retargeting,
                                    RetargetOptions,
                                    align_head_frame,
                                    build_retarget_operator,
                                    marker_displacements,
                                    retarget,
)

__all__ = ["RetargetOptions", "Retargeting", "retarget", "marker_displacements",
           "align_head_frame", "build_retarget_operator", "RBFOperator", "RBFSolveInfo",
           "build_rbf_operator", "KERNELS", "DISTANCES", "CONTENTS", "save_npz",
           "save_obj_sequence", "is_retargeted_archive", "ArchiveFrames"]
