"""Tolerances used across the tests, in one place.

Each says what it compares, in what unit, and why that size. The shared ones (what
rounding alone allows) come first, then one group per topic. A factor (x) multiplies
a reference error or bound; a fraction (rel) is relative to the value compared.
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

# ---------------------------------------------------------------- capture files

#: Our C3D reader against ezc3d on the same file, mm.
C3D_VS_EZC3D_MM = 1e-4
#: Analog samples against ezc3d's (float32 scaling): absolute floor, V, for samples near 0.
C3D_ANALOG_FLOOR = 1e-9
#: Vicon CSV against the same trial's C3D, mm (the issue asks for 0.01).
CSV_VS_C3D_MM = 0.01
#: Distances between the 8 markers of the rigid box, markers.trc vs markers.c3d
#: (two trials of one session): marker jitter, mm.
TRC_BOX_VS_C3D_MM = 1.0
#: Cells of a Vicon CSV written with the default 5 decimals: half a unit of the last, mm.
VICON_CSV_CELL_MM = 5e-6
#: A simulated capture written as .c3d (float32, positions ~2 m) or .csv and read back, mm.
CAPTURE_FILE_MM = 5e-3
#: Weights read back from a performance CSV written with 6 decimals (5 units of the last).
PERFORMANCE_CSV_WEIGHT = 5e-6
#: Live Link timecodes (~5e4 s since midnight) made seconds from the first frame, against
#: a hand parse: the rounding of hour-sized seconds, s.
TIMECODE_S = 1e-9
#: The rate of a 30 Hz Live Link file from its median time step (timecode rounding), rel.
PERFORMANCE_RATE_REL = 1e-6

# ---------------------------------------------------------------- mesh and layout files

#: OBJ text keeps 10 significant digits: coordinates read back, relative (and absolute on
#: a ~10-unit grid, where it covers the coordinates near 0).
OBJ_TEXT = 1e-9
#: A displacement read back from OBJ text, the difference of two printed ~2 mm
#: coordinates, mm.
OBJ_DISPLACEMENT_MM = 1e-8
#: A marker layout written to TOML (8-decimal barycentric weights) and read back: marker
#: positions on the ICT face, cm.
LAYOUT_TOML_CM = 1e-7

# ---------------------------------------------------------------- the demo session

#: The demo's neutral OBJ read back: absolute floor under OBJ_TEXT, mm (a ~200 mm face).
DEMO_NEUTRAL_MM = 1e-7
#: The demo's shapes read back from OBJ files (differences of printed ~100 mm coordinates), mm.
DEMO_SHAPES_MM = 1e-6
#: The demo's layout file on its OBJ neutral: marker positions, mm.
DEMO_LAYOUT_MM = 1e-5
#: The demo's capture.c3d (float32, positions ~2 m from the origin) read back, mm.
DEMO_CAPTURE_MM = 1e-3
#: The demo's shapes least-squares fitted by themselves: relative residual (one lstsq).
DEMO_SHAPES_SPAN_REL = 1e-10

# ---------------------------------------------------------------- rigid fits, stabilization

#: A rigid transform recovered from exact data: rotation (deg) and translation (mm).
RIGID_EXACT_DEG = 1e-8
RIGID_EXACT_MM = 1e-8
#: A batched rigid fit of noisy points (0.3-5 mm noise, up to ~300 mm away) against another
#: computation of it (a per-frame SVD, scipy's align_vectors): rotation entries; mm.
RIGID_VS_ORACLE = 1e-9
RIGID_VS_ORACLE_MM = 1e-7
#: The scale of a batched similarity fit against the per-frame SVD's, relative: of noisy
#: points; of points mirrored (the best proper fit to a reflection).
RIGID_VS_ORACLE_SCALE = 1e-10
RIGID_MIRRORED_SCALE = 1e-9
#: A rigid fit with zero-weight or NaN points against the fit without them: rotation
#: entries, translation (mm).
RIGID_DROPPED_ROT = 1e-10
RIGID_DROPPED_MM = 1e-8
#: The rigid fill's batched Kabsch fit (2 mm noise, ~100 mm translations) against scipy's
#: align_vectors: rotation entries, translation (mm).
GAPFILL_KABSCH_ROT = 1e-10
GAPFILL_KABSCH_MM = 1e-8
#: The weighted RMS a rigid fit reports against the residual recomputed from it, mm.
RIGID_RMS_MM = 1e-6
#: Stabilization of a take moved rigidly per frame (~1 m) against that of the take:
#: head-frame positions and residuals (mm), and weights.
STABILIZE_INVARIANCE = 1e-9
#: The mean shape of a plain GPA against the mean of the frames it aligned, mm.
GPA_MEAN_MM = 1e-6
#: A converged GPA against its own fixed point, or against the fit from another start, as
#: a fraction of the estimated marker noise.
STABILIZE_CONVERGED_NOISE = 1e-3
#: Robust weights from the subsampled start against those from every frame.
STABILIZE_START_WEIGHTS = 1e-3
#: Head rotation under a 5 mm slip of one head marker against the truth: median over the
#: take (deg); the slip frames' median, as a factor (x) of the others' (it costs nothing).
STABILIZE_SLIP_DEG = 0.1
STABILIZE_SLIP_FACTOR = 1.5
#: Head rotation interpolated over 10 frames of too few head markers, against the truth, deg.
STABILIZE_GAP_DEG = 0.5
#: The reference shape carried to the world against the head markers (0.05 mm noise), mm.
STABILIZE_ON_HEAD_MM = 0.5
#: Median head-marker residual of facial-sing.c3d (markers on the skin of a real head), mm.
STABILIZE_REAL_RESIDUAL_MM = 1.0

#: ``stabilize = "auto"`` against a simulation's true head motion: the issue's aims for the
#: median rotation error (deg) and translation error at the face (mm).
AUTO_HEAD_DEG = 0.3
AUTO_HEAD_MM = 0.5

# ---------------------------------------------------------------- inference (init)

#: A mesh landmark found from the mesh is correct within this of the landmark file written
#: by hand for the ICT face, mm: a tenth of the mouth's width (the Maskle places a mask
#: with them, and the binding's ICP refines what they start).
MESH_LANDMARK_MM = 5.0
#: Regions inferred correctly: the issue's aim, a fraction of the face markers.
REGIONS_CORRECT = 0.95
#: An inferred face axis within this of the truth, degrees (the truth from region
#: centroids is itself a few degrees off a symmetric face's axes).
AXIS_DEG = 15.0

# ---------------------------------------------------------------- binding

#: A similarity recovered by marker binding from exact data: scale (relative), rotation, mm.
BIND_EXACT = 1e-8
#: The closest surface point of the ICT face, rebuilt from its barycentric weights, against
#: a brute-force oracle, cm.
BIND_CLOSEST_POINT_CM = 1e-7
#: Bound marker points vs the layout they were simulated from (0.2 mm noise, 2 mm skin
#: offset), mm: mean and worst marker.
BIND_LAYOUT_MEAN_MM = 0.5
BIND_LAYOUT_MAX_MM = 1.5
#: ICP against landmarks only: the mean error of the bound points divides by at least this.
BIND_ICP_GAIN = 2
#: Scale of a binding of a simulated capture (0.2 mm noise) against the true mm per cm, rel.
BIND_SCALE_REL = 0.01
#: The frame picked as neutral in a noisy take (0.3 mm noise) against the true rest pose:
#: RMS over markers, mm.
NEUTRAL_FRAME_RMS_MM = 1.0
#: `mocap2mesh bind` on a simulated capture (0.2 mm noise, 2 mm skin offset, neutral
#: frame picked automatically): bound points vs the layout, mm (the issue asks < 1 mm).
BIND_CLI_SIM_MEAN_MM = 0.5
BIND_CLI_SIM_MAX_MM = 1.0
#: The frame that binding picks: its true weights (at rest, or where the ramp is still
#: below the 0.2 mm noise).
BIND_CLI_NEUTRAL_WEIGHT = 0.1
#: Marker-to-skin distances of a bound simulated capture against its 2 mm skin offset, mm.
BIND_CLI_SKIN_OFFSET_MM = 1.0
#: Median marker-to-mesh distance of facial-sing.c3d bound to the ICT face (another
#: person's face), mm.
BIND_REAL_MEDIAN_MM = 3.0
#: A neutral hold's mean shape against the noise-free markers, as a factor (x) of the
#: noise of a mean of N frames (noise * sqrt(3 / N) per marker).
HOLD_NOISE_FACTOR = 1.5

# ---------------------------------------------------------------- capture simulation

#: Simulated markers (mesh evaluated at the layout's vertices only) vs the layout on the
#: dense mesh v0 + sum w e, mm.
SYNTH_VS_DENSE_MM = 1e-9
#: Head motion of a noise-free simulated capture recovered by stabilize: rotation
#: entries and translation (mm, the head ~1.6 m from the origin).
SYNTH_HEAD_EXACT = 1e-9
#: A simulated capture's noise against the level asked (0.5 mm, ~1e5 samples): its std
#: (rel) and its mean (mm).
SYNTH_NOISE_STD_REL = 0.05
SYNTH_NOISE_MEAN_MM = 0.05
#: The noise std of `mocap2mesh synth` (0.2 mm asked, coordinates printed or float32), rel.
SYNTH_CLI_NOISE_STD_REL = 0.1

# ---------------------------------------------------------------- filtering, resampling

#: Our gap-aware low-pass against scipy.signal.sosfiltfilt on gap-free data, mm.
LOWPASS_VS_SCIPY_MM = 1e-9
#: The low-pass gain on a 10 mm sine (1000 samples) against |H|^2 of the Butterworth filter.
LOWPASS_GAIN = 1e-3
#: The same gain below half the cutoff (at least) and above twice it (at most).
LOWPASS_PASSBAND = 0.99
LOWPASS_STOPBAND = 0.01
#: A band-limited 10 mm signal resampled against the analytic one away from the ends,
#: mm: at 16 or more times its top frequency, and below that (the filter's transition).
RESAMPLE_MM = 0.02
RESAMPLE_COARSE_MM = 0.05
#: A 20 Hz sine resampled to 30 Hz (above the new Nyquist): what is left, rel to its amplitude.
RESAMPLE_ALIAS_REL = 0.05

# ---------------------------------------------------------------- gap filling, repairs

#: Rigid-cluster gap fill of noise-free rigid data, mm.
GAPFILL_RIGID_MM = 1e-9
#: PCA gap fill of noise-free data of low rank, mm (iterative path: converged to 1e-10).
GAPFILL_LOW_RANK_MM = 1e-6
#: The spline fill of a sinusoid, as a factor (x) of the cubic-spline error bound
#: (5/384) h^4 max|f''''| (room for the spline's end conditions).
SPLINE_BOUND_FACTOR = 2
#: The weighted rigid fill beside a donor wandering 4 mm: its error, as a fraction of the
#: unweighted fill's.
GAPFILL_WANDER_REL = 0.02
#: Samples removed as implausible (an 80 mm teleport) and refilled, against the clean take, mm.
OUTLIER_REFILL_MM = 2.0
#: The largest frame-to-frame step of facial-sing's section3-1 around its mislabel (jumps of
#: ~70 mm) once repaired, mm (100 Hz).
REPAIRED_STEP_MM = 5.0
#: A label swap found: the residual left by the exchange, as a fraction of the jump it explains.
SWAP_RESIDUAL_FRACTION = 0.25
#: `ingest --stabilize` of the demo capture (0.2 mm noise, gaps filled) against the
#: head-frame truth after one rigid alignment: median marker error, mm.
INGEST_STABILIZED_MM = 0.5

# ---------------------------------------------------------------- geodesics

#: Heat-method geodesic distance against the exact distance (relative), max and mean.
GEODESIC_HEAT_MAX_REL = 0.08
GEODESIC_HEAT_MEAN_REL = 0.03

# ---------------------------------------------------------------- RBF operators, retargeting

#: RBF operator against scipy.interpolate.RBFInterpolator (relative to the data scale).
RBF_VS_SCIPY_RTOL = 1e-9
#: An RBF operator with a polynomial part (degree >= 1) reproduces affine fields: O(1)
#: data on the unit cube or a 10-unit grid, absolute.
RBF_AFFINE_EXACT = 1e-9
#: The same for the geodesic TPS on the ICT face (shifted, it no longer interpolates, but
#: affine fields stay in its polynomial part), cm.
RBF_AFFINE_ICT_CM = 1e-8
#: op.apply in float32 against a float64 loop over frames (sums of 25 O(1) products), abs.
RBF_APPLY_FLOAT32 = 1e-4
#: op.apply cut into other tiles (chunk sizes, threads): the BLAS may sum a row's 25
#: products in another order for another row count, so the same result to a few units
#: of rounding of the largest value, in units of the dtype's eps (rel).
RBF_RETILED_EPS = 32
#: Influence of upper-lip centres across the slit of the grid (geodesic support 0.15 <
#: the way around): none, but rounding.
RBF_ACROSS_CUT = 1e-9
#: A region operator against the weighted sum of region operators built alone (the same
#: solves, assembled otherwise).
RBF_REGION_SUM = 1e-10
#: Retargeting: an RBF operator at its own centres (relative to the data scale; float64
#: solves of well-conditioned systems).
RETARGET_EXACT = 1e-8
#: align_head_frame's rotation from a take turned exactly: rotation-matrix entries.
RETARGET_HEAD_ALIGN = 1e-9
#: `mocap2mesh retarget` on a simulated capture (0.2 mm noise, head motion, gaps filled):
#: RMS error at the face markers' skin points, as a fraction of their RMS motion (the
#: operator interpolates there: what is left is noise, skin offset and binding error).
RETARGET_CLI_SIM_REL = 0.3
#: Leave-one-marker-out predictions in closed form against refitting the operator without
#: each marker (O(1) data, systems of ~16 centres solved two ways; the Gaussian's are the
#: worst conditioned), absolute.
LOO_VS_REFIT = 1e-9
#: `kernel = "auto"` on the ICT ground truth: its variant's RMS vertex error against the
#: best variant's of the same grid (the issue asks for within 10 %), as a factor (x).
AUTO_VS_TRUTH_BEST = 1.10

# ---------------------------------------------------------------- rendering

#: Rendered sphere silhouette (pixels not background) against pi r^2, relative.
RENDER_SILHOUETTE_REL = 0.01
#: Rendered colour against the shading formula or the colour map (the colour bar), 8-bit
#: levels (rounding, colour-map LUT).
RENDER_RGB_LEVELS = 2
#: A point's colour dimmed behind the mesh against the blend formula, 8-bit levels (rounding).
RENDER_POINT_RGB_LEVELS = 1
#: The compiled shading against NumPy's, 8-bit levels: the specular power's float32 ``**``
#: may differ from NumPy's in the last bit, which can move a pixel across a rounding edge.
RENDER_KERNEL_LEVELS = 1
#: Share of a render's pixels the compiled shading may give another 8-bit level than NumPy's.
RENDER_KERNEL_PIXELS = 1e-3
#: Pixel coordinates that only float64 rounding separates from their oracle (pixel
#: centres from barycentric coordinates, the framing margin), px.
RENDER_EXACT_PX = 1e-9
#: The centroid of a drawn point's pixels against its projection, px (pixel-centre rounding).
RENDER_POINT_CENTRE_PX = 0.6

# ---------------------------------------------------------------- weight solving

#: Objective of the batched weight solver against lsq_linear(bvls) / lstsq (and scipy's
#: least_squares for the exact marker centres), relative.
SOLVE_OBJECTIVE_REL = 1e-9
#: Absolute floor of that comparison, for frames fitted exactly (costs ~0).
SOLVE_OBJECTIVE_FLOOR = 1e-15
#: Independent KKT check of solved weights (relative to the gradient's terms).
SOLVE_KKT_REL = 1e-8
#: solve_weights' default KKT tolerance: converged frames are below it, unconverged above.
SOLVE_TOL = 1e-9
#: A weight this close to a bound (times max(1, |bound|)) is at the bound: the solver's rule.
SOLVE_AT_BOUND = 1e-12
#: Stationarity of the free weights of a refined reduced solve, relative to the gradient's
#: terms.
SOLVE_REFINED_STATIONARITY = 1e-11
#: Two linear-algebra routes to the same weights (Schur complement or direct, batched or in
#: parts, bordered or fresh), relative to the largest weight: condition ~10, and 1e5.
SOLVE_ROUTES = 1e-10
SOLVE_ROUTES_ILL_CONDITIONED = 1e-6
#: The same problem from another start or another layout of its data: weights (a unique
#: minimizer, solved to SOLVE_TOL).
SOLVE_SAME_MINIMIZER = 1e-9
#: The vectorized KKT residual against its element-by-element definition: one rounding, rel.
SOLVE_KKT_LOOP_REL = 1e-15
#: The KKT residual a frame reports against the residual of its final weights, recomputed.
SOLVE_KKT_RECOMPUTED = 1e-13
#: Smoothed weights against lsq_linear on the stacked sequence problem: weights.
SMOOTH_VS_STACKED = 1e-6
#: The mesh-space reduction against the materialized solve: weights (abs) and cost (rel).
MESH_SPACE_VS_DENSE = 1e-8
#: The same on the demo chain's H basis (bounded, real data): weights.
MESH_SPACE_CHAIN = 1e-7
#: The PCA marker fit against numpy's lstsq with the mean fixed: weights, relative to the
#: largest.
PCA_FIT_VS_LSTSQ_REL = 1e-8
#: GCV scores from the spectral formula against the dense influence matrix, relative.
GCV_SCORE_RTOL = 1e-8
#: Chosen λ against the dense GCV's minimizer, relative (both minimizers stop at 1e-6 in log λ).
GCV_ARGMIN_RTOL = 1e-3
#: λ chosen by GCV against the best λ of a sweep scored by the truth, log10 (a factor 3).
GCV_VS_TRUTH_LOG10 = 0.5
#: The true weight error at GCV's λ, as a factor (x) of the sweep's best, and of the
#: error without smoothing.
GCV_ERROR_FACTOR = 1.1
GCV_VS_UNSMOOTHED = 0.7

# ---------------------------------------------------------------- exact marker centres

#: Noise-free centres 2 mm off the ICT skin, solved with the exact model: weights against
#: the truth; the centres' displacements (cm: 0.1 µm); the cost (cm²).
MARKER_CENTRES_WEIGHTS = 1e-5
MARKER_CENTRES_CM = 1e-6
MARKER_CENTRES_COST = 1e-12
#: With noise: the weights re-solved from their own residual against them (the fixed point,
#: reached to tol 1e-9).
MARKER_CENTRES_FIXED_POINT = 1e-7
#: The chain's exact-centre fit: reported cost against its recomputation (rel); its cost as
#: a factor (x) of scipy's least_squares optimum.
MARKER_CENTRES_COST_REL = 1e-9
MARKER_CENTRES_VS_OPTIMUM = 1.01
#: Marker-basis fields at offset centres (lifted along normals that turn) against the layout
#: lifted by hand: mesh units (divided by the binding's scale in capture mm).
MARKER_BASIS_LIFTED = 1e-7

# ---------------------------------------------------------------- PCA and quasi-eigen bases

#: Implicit PCA (operator) against a dense SVD of the materialized mesh sequence:
#: eigenvalues, relative to each eigenvalue.
PCA_IMPLICIT_RTOL = 1e-8
#: Streaming PCA (randomized, incremental) eigenvalues against a dense SVD when the
#: data is a low-rank signal plus noise 1e-3 times smaller (exact to rounding when
#: the rank is at most n_components + 10).
PCA_STREAMING_RTOL = 1e-5
#: Largest principal angle between a fitted and the dense PCA subspace, radians.
PCA_ANGLE_RAD = 1e-6
#: Exact identities of PCA/quasi-eigen maths (projections, traces, reconstruction in the
#: span), relative, or absolute on values of order 1-10.
PCA_EXACT_RTOL = 1e-10
#: Absolute floor of eigenvalue comparisons, as a fraction of the largest eigenvalue:
#: a covariance (Gram) method knows every eigenvalue to ~ε·λ₁ only.
PCA_EIG_FLOOR = 1e-13
#: A fitted component's |dot product| with the dense SVD's singular vector (both unit).
PCA_COMPONENT_DOT = 1e-9
#: Mean squared reconstruction error of a truncated model against the discarded eigenvalues,
#: rel: implicit PCA; streaming (its discarded part is only approximated).
PCA_DISCARDED_IMPLICIT_RTOL = 1e-6
PCA_DISCARDED_STREAMING_RTOL = 1e-2
#: Streaming PCA of chunks against the same frames as one array (same seed): eigenvalues
#: (rel) and components (abs, unit vectors).
PCA_CHUNKS_RTOL = 1e-9
PCA_CHUNKS_COMPONENTS = 1e-8
#: QE column sums against the construction's |coefficients| (one axis only 1e-4), relative.
QE_COLUMN_SUMS_RTOL = 1e-9
#: ICT expressions in the span of a streaming PCA of their blends: their relative move.
QE_IN_SPAN_REL = 1e-8
#: `mocap2mesh basis` on a synthetic take (float32 archive of the retargeted vertices, a
#: randomized PCA exact to rounding at rank <= m + 10): bases and moves vs a dense SVD,
#: relative to the largest value compared.
BASIS_CLI_REL = 1e-5
#: moves.csv of `basis -m 2` (below the data's rank) against a dense projection: relative
#: and largest vertex moves, rel.
BASIS_CLI_MOVES_RTOL = 1e-4

# ---------------------------------------------------------------- gestures, speech

#: Analysis of a noise-free capture moving rigidly: weights against the moving-average
#: oracle, and the residual of a 1-frame window (mm).
GESTURES_NOISE_FREE = 1e-8
#: The exact estimator's weights reach the upper bound 1 + ε to this.
GESTURES_AT_BOUND = 1e-9
#: Significance level of the chi-square test of 6000 picks against exp(-d / σ).
CHI_SQUARE_PVALUE = 1e-3
#: weights.csv of `gestures synthesize` against the same synthesis in memory (palette and
#: speech read back from their files).
GESTURES_CLI_VS_API = 1e-6
#: `gestures analyze` of a simulated capture (0.1 mm noise, bound with its own errors):
#: weights against the averaged truth.
GESTURES_CLI_WEIGHTS = 0.03
#: Correlation of the lid weights with the truth (lid markers where a 0.3 mm binding error
#: changes the motion).
GESTURES_CLI_LID_CORRELATION = 0.98
#: The analysed head rotation from its first frame against the truth's, deg.
GESTURES_CLI_HEAD_DEG = 0.5
#: A clip's weights within their box [-0.1, 1.1], to rounding.
CLIP_BOUNDS_SLACK = 1e-9
#: Head motion played from the glb's float32 quaternions and translations against
#: head.npz carried by the binding, cm.
GLB_HEAD_MOTION_CM = 1e-3
#: Intensity of a tone burst against 20 log10 of its RMS, dB: 440 Hz in 50 ms windows; the
#: CLI's 200 and 500 Hz bursts.
SPEECH_TONE_DB = 0.02
SPEECH_CLI_TONE_DB = 0.01
#: dB levels that only float64 rounding separates from their oracle (a loop over frames,
#: the level of a constant lip opening), dB.
SPEECH_EXACT_DB = 1e-9
#: Intensity read from a WAV file against that of the float signal it holds (loud frames),
#: dB: 16-bit, 32-bit and float32 samples; 8-bit samples.
WAV_DB = 1e-3
WAV_UINT8_DB = 0.1

# ---------------------------------------------------------------- the Maskle

#: Weights painted on the mask and transferred back, against those they were made from.
MASKLE_PAINT = 0.02
#: Placement on a copy of the face scaled by 2.5 and moved: its scale (rel), and the
#: placed vertices (mesh units).
MASKLE_SIMILAR_SCALE_REL = 1e-10
MASKLE_SIMILAR_PLACED = 1e-8
#: The mask's landmarks against the face's, sideways (in the face's plane), template cm.
MASKLE_LANDMARK_CM = 0.2
#: The tongue strips' parting after fitting (built 0.04 apart), template cm.
MASKLE_PARTING_CM = 0.05
#: The weight of a bone of the other lip on a vertex clearly on one side of the mouth.
MASKLE_LIP_LEAK = 0.1
#: Transfer onto a similar copy of the face: vertices hit on one copy only (a fraction of
#: the hits), and the mean weight difference where both are hit.
MASKLE_SIMILAR_HITS = 0.01
MASKLE_SIMILAR_WEIGHTS = 1e-3
#: The mouth side (1 upper lip, 0 lower) at the lip landmarks.
MOUTH_SIDE_AT_LANDMARK = 0.05

# ---------------------------------------------------------------- talking faces (lip-sync)

#: Praat's intensity of a steady sine against its level in dB SPL (signal as Pa): Praat's
#: window is ~43 ms, its mean subtraction and Kaiser window leave a few thousandths, dB.
PRAAT_TONE_DB = 0.01
#: Praat's F0 of a harmonic tone against its fundamental, Hz (parabolic interpolation).
PRAAT_PITCH_HZ = 0.5
#: Forced alignment of the shipped recordings against their shipped PocketSphinx
#: alignments, median boundary distance, s: one 10 ms analysis frame (the same aligner
#: family, so agreement, not accuracy; bench/bench_lipsync.py measures it).
ALIGN_MEDIAN_S = 0.01
#: Frames whose viseme class agrees with the shipped alignment's, with the phone recognizer
#: alone (no transcript): at least this fraction (speech recognized by phones is noisy; the
#: bench measures it).
RECOGNIZED_VISEME_AGREEMENT = 0.4
#: The lip gap of a closed mouth and of an open vowel, mm (the issue's 1 mm and 3 mm).
LIP_CLOSED_MM = 1.0
LIP_OPEN_MM = 3.0
#: The synthesized mesh read back from mesh.npz (float32) against the blend computed
#: here in float64, cm.
TALKING_MESH_CM = 1e-5

#: A glTF export played back (float32 targets and motion, shapes scaled up to their
#: largest weight, tens of mm of head motion) against the float64 sequence, mm.
GLB_PLAYED_MM = 1e-3
#: The variants of one kernel solved together as stacks (`leave_one_out_many`, the scores of
#: `kernel = "auto"`) against each solved alone (`leave_one_out`): the same LAPACK and BLAS
#: routines on the same matrices, so equal but for the rounding of a stacked product; relative.
BATCHED_VS_ONE_AT_A_TIME = 1e-10
