"""The anatomical points that marker sets and mesh landmark files name.

A marker-set landmark and a mesh landmark meet when they carry the same name
from this vocabulary. Left and right are the subject's own.
"""

from __future__ import annotations

__all__ = ["ANATOMICAL_POINTS", "MASKLE_POINTS"]

#: The ten points the Maskle paper places its mask with.
MASKLE_POINTS = (
    "mouth_corner_left", "mouth_corner_right",
    "upper_lip_top", "upper_lip_bottom",      # midline: vermilion border, lip contact
    "lower_lip_top", "lower_lip_bottom",
    "eye_inner_left", "eye_outer_left",
    "eye_inner_right", "eye_outer_right",
)

#: Every anatomical point name a landmark may use.
ANATOMICAL_POINTS = MASKLE_POINTS + (
    "nose_tip", "nose_bridge", "nose_left", "nose_right", "subnasale",
    "chin", "jaw_left", "jaw_right",
    "brow_inner_left", "brow_mid_left", "brow_outer_left",
    "brow_inner_right", "brow_mid_right", "brow_outer_right",
    "cheek_left", "cheek_right", "forehead",
)
