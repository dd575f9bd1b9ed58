"""Tolerances used across the tests, in one place."""

#: Our C3D reader against ezc3d on the same file, mm.
C3D_VS_EZC3D_MM = 1e-4
#: Vicon CSV against the same trial's C3D, mm (the issue asks for 0.01).
CSV_VS_C3D_MM = 0.01
#: A rigid transform recovered from exact data: rotation (deg) and translation (mm).
RIGID_EXACT_DEG = 1e-8
RIGID_EXACT_MM = 1e-8
