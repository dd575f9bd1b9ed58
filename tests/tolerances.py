"""Tolerances used across the tests, in one place.

The shared ones (what rounding alone allows) come first, then one group per topic.
"""

# ---------------------------------------------------------------- rounding only

#: An exact identity in float64 on values of order 1-100 (rotations, determinants, unit
#: vectors, weights, sums to 1, costs, s, px): a few operations' rounding; abs or rel.
EXACT_FLOAT64 = 1e-12
#: An O(1) value from a handful of float64 operations (a kernel or Shepard formula) against
#: its exact value or another evaluation of the same formula: a few ulps.
FEW_ULPS = 1e-14
#: Positions and motions in mm (up to ~2 m from the origin) that only float64 rounding
#: separates from their oracle (transforms applied and undone, parts summed back), mm.
EXACT_MM = 1e-9
#: Mesh-geometry results that only rounding separates from their oracle (normals, closest
#: points, ray hits, exact geodesics, barycentric coordinates), mesh units.
MESH_EXACT = 1e-9
#: A vectorized computation against a plain loop over the same formula (float64, sums in
#: another order), on values up to ~100: absolute, or relative.
LOOP_ORACLE = 1e-9
#: Values stored or computed in float32 (glTF, mesh sequences, float32 archives and C3D
#: files), relative to the largest magnitude compared (abs for O(1)): 6e-8 with margin.
FLOAT32_REL = 1e-6
#: Files that store float32 (glTF, PLY, mesh sequences): positions of a ~20 cm face
#: agree to this, cm.
FLOAT32_FACE_CM = 1e-5

# ---------------------------------------------------------------- by topic

#: Our C3D reader against ezc3d on the same file, mm.
C3D_VS_EZC3D_MM = 1e-4
#: Vicon CSV against the same trial's C3D, mm (the issue asks for 0.01).
CSV_VS_C3D_MM = 0.01
#: A rigid transform recovered from exact data: rotation (deg) and translation (mm).
RIGID_EXACT_DEG = 1e-8
RIGID_EXACT_MM = 1e-8
#: Implicit PCA (operator) against a dense SVD of the materialized mesh sequence:
#: eigenvalues, relative to each eigenvalue.
PCA_IMPLICIT_RTOL = 1e-8
#: Streaming PCA (randomized, incremental) eigenvalues against a dense SVD when the
#: data is a low-rank signal plus noise 1e-3 times smaller (exact to rounding when
#: the rank is at most n_components + 10).
PCA_STREAMING_RTOL = 1e-5
#: Largest principal angle between a fitted and the dense PCA subspace, radians.
PCA_ANGLE_RAD = 1e-6
#: Exact identities of PCA/quasi-eigen maths (projections, traces), relative.
PCA_EXACT_RTOL = 1e-10
#: Distances between the 8 markers of the rigid box, markers.trc vs markers.c3d
#: (two trials of one session): marker jitter, mm.
TRC_BOX_VS_C3D_MM = 1.0
#: A similarity recovered by marker binding from exact data: scale (relative), rotation, mm.
BIND_EXACT = 1e-8
#: Bound marker points vs the layout they were simulated from (0.2 mm noise, 2 mm skin
#: offset), mm: mean and worst marker.
BIND_LAYOUT_MEAN_MM = 0.5
BIND_LAYOUT_MAX_MM = 1.5
#: Objective of the batched weight solver against lsq_linear(bvls) / lstsq, relative.
SOLVE_OBJECTIVE_REL = 1e-9
#: Independent KKT check of solved weights (relative to the gradient's terms).
SOLVE_KKT_REL = 1e-8
#: Heat-method geodesic distance against the exact distance (relative), max and mean.
GEODESIC_HEAT_MAX_REL = 0.08
GEODESIC_HEAT_MEAN_REL = 0.03
#: RBF operator against scipy.interpolate.RBFInterpolator (relative to the data scale).
RBF_VS_SCIPY_RTOL = 1e-9
#: Rigid-cluster gap fill of noise-free rigid data, mm.
GAPFILL_RIGID_MM = 1e-9
#: PCA gap fill of noise-free data of low rank, mm (iterative path: converged to 1e-10).
GAPFILL_LOW_RANK_MM = 1e-6
#: Our gap-aware low-pass against scipy.signal.sosfiltfilt on gap-free data, mm.
LOWPASS_VS_SCIPY_MM = 1e-9
#: Absolute floor of eigenvalue comparisons, as a fraction of the largest eigenvalue:
#: a covariance (Gram) method knows every eigenvalue to ~ε·λ₁ only.
PCA_EIG_FLOOR = 1e-13
#: Simulated markers (mesh evaluated at the layout's vertices only) vs the layout on the
#: dense mesh v0 + sum w e, mm.
SYNTH_VS_DENSE_MM = 1e-9
#: Head motion of a noise-free simulated capture recovered by stabilize: rotation
#: entries and translation (mm, the head ~1.6 m from the origin).
SYNTH_HEAD_EXACT = 1e-9
#: `mocap2mesh bind` on a simulated capture (0.2 mm noise, 2 mm skin offset, neutral
#: frame picked automatically): bound points vs the layout, mm (the issue asks < 1 mm).
BIND_CLI_SIM_MEAN_MM = 0.5
BIND_CLI_SIM_MAX_MM = 1.0
#: Rendered sphere silhouette (pixels not background) against pi r^2, relative.
RENDER_SILHOUETTE_REL = 0.01
#: Rendered colour against the shading formula, 8-bit levels (rounding, colour-map LUT).
RENDER_RGB_LEVELS = 2
#: Retargeting: an RBF operator at its own centres, and an affine field through TPS of
#: degree 1 (relative to the data scale; float64 solves of well-conditioned systems).
RETARGET_EXACT = 1e-8
#: `mocap2mesh retarget` on a simulated capture (0.2 mm noise, head motion, gaps filled):
#: RMS error at the face markers' skin points, as a fraction of their RMS motion (the
#: operator interpolates there: what is left is noise, skin offset and binding error).
RETARGET_CLI_SIM_REL = 0.3
#: `mocap2mesh basis` on a synthetic take (float32 archive of the retargeted vertices, a
#: randomized PCA exact to rounding at rank <= m + 10): bases and moves vs a dense SVD,
#: relative to the largest value compared.
BASIS_CLI_REL = 1e-5
