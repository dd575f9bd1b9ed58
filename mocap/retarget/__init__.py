"""Retargeting: marker displacements drive a face mesh through an RBF operator.

- :mod:`.rbf`: the operator W (N, M) (kernels in :mod:`._kernels`, systems in :mod:`._system`);
- :mod:`.cross_validation`: its leave-one-marker-out errors, in closed form;
- :mod:`.selection`: ``kernel = "auto"``, the variant chosen by them;
- :mod:`.lip_seal`: does the mesh open its mouth when the lip markers do;
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
from mocap.retarget.cross_validation import (
                                    CrossValidation,
                                    cross_validate,
                                    leave_one_out,
                                    leave_one_out_many,
)
from mocap.retarget.lip_seal import LipSealCheck, check_lip_seal
from mocap.retarget.rbf import RBFOperator, RBFSolveInfo, build_rbf_operator
from mocap.retarget.retargeting import (
                                    DISTANCES,
                                    KERNELS,
                                    RETARGET_KERNELS,
                                    Retargeting,
                                    RetargetOptions,
                                    align_head_frame,
                                    build_retarget_operator,
                                    marker_displacements,
                                    retarget,
)
from mocap.retarget.selection import RetargetSelection, select_variant

__all__ = ["RetargetOptions", "Retargeting", "retarget", "marker_displacements",
           "align_head_frame", "build_retarget_operator", "RBFOperator", "RBFSolveInfo",
           "build_rbf_operator", "KERNELS", "RETARGET_KERNELS", "DISTANCES", "CONTENTS",
           "save_npz", "save_obj_sequence", "is_retargeted_archive", "ArchiveFrames",
           "CrossValidation", "cross_validate", "leave_one_out", "leave_one_out_many",
           "RetargetSelection",
           "select_variant", "LipSealCheck", "check_lip_seal"]
