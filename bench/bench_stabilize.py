"""Benchmark head stabilization: accuracy on a synthetic take, speed against scipy, real data.

Run: ``python bench/bench_stabilize.py [--frames 35000] [--baseline-frames N]``

1. Accuracy: a synthetic take with known smooth head motion (rotations up to
   +-30 deg per axis, translations up to +-200 mm), 0.2 mm marker noise,
   6 head-band markers, one of them slipping 5 mm for 100 frames. Prints the
   median and 95th-percentile rotation (deg) and translation (mm) error and
   the slips found. Aims: median <= 0.1 deg and <= 0.2 mm; the slip found.
2. Speed: stabilizing 6 head + 66 face markers against a per-frame loop of
   ``scipy.spatial.transform.Rotation.align_vectors`` (aim >= 20x).
3. The real capture ``captures/facial-sing.c3d`` (head markers root-1..root-6):
   head residual statistics, when ``mocap.read`` can open it.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from _common import best_time, peak_memory_mb, shared_data
from scipy.spatial.transform import Rotation

import mocap
from mocap.stabilize import stabilize

HEAD = [f"head-{i}" for i in range(1, 7)]
SLIP_MARKER, SLIP_START, SLIP_FRAMES, SLIP_MM = 2, 1000, 100, 5.0
RATE = 120.0


def head_band() -> np.ndarray:
    """Six head markers laid out as root-1..root-6 of facial-sing.c3d (mm, about their centre)."""
    return np.array([[120, 25, 12], [-116, 17, 7], [33, -32, 64],
                     [-42, -14, 65], [75, 4, -74], [-70, 0, -73]], float)


def face_markers(n: int, rng) -> np.ndarray:
    """`n` markers on the front of an ellipsoidal face (mm)."""
    u = rng.uniform(-0.9, 0.9, n)
    z = rng.uniform(-95, 35, n)
    return np.column_stack([70 * np.sin(u), 95 * np.cos(u) * np.sqrt(1 - (z / 160) ** 2), z])


def smooth(rng, n_frames: int, amplitude: float, n_axes: int = 3) -> np.ndarray:
    """Sums of slow sinusoids (0.03-0.5 Hz), each axis scaled to +-amplitude."""
    t = np.arange(n_frames) / RATE
    freq = rng.uniform(0.03, 0.5, (4, n_axes))
    phase = rng.uniform(0, 2 * np.pi, (4, n_axes))
    wave = np.sin(2 * np.pi * freq[None] * t[:, None, None] + phase[None]).sum(axis=1)
    return amplitude * wave / np.abs(wave).max(axis=0)


def synthetic_take(n_frames: int, n_face: int, seed: int = 0):
    """A take with known head motion: (take, true R, true t, head shape in the head frame)."""
    rng = np.random.default_rng(seed)
    head = head_band()
    face = face_markers(n_face, rng)
    local = np.broadcast_to(np.vstack([head, face]), (n_frames, 6 + n_face, 3)).copy()
    local[:, 6:] += smooth(rng, n_frames, 4.0, 3 * n_face).reshape(n_frames, n_face, 3)
    stop = min(SLIP_START + SLIP_FRAMES, n_frames)
    local[SLIP_START:stop, SLIP_MARKER] += SLIP_MM * np.array([0.6, 0.0, 0.8])
    rot = Rotation.from_euler("xyz", smooth(rng, n_frames, 30.0), degrees=True).as_matrix()
    trans = smooth(rng, n_frames, 200.0) + [0.0, 0.0, 1500.0]
    world = np.einsum("tij,tmj->tmi", rot, local) + trans[:, None]
    world += rng.normal(0.0, 0.2, world.shape)
    labels = HEAD + [f"face-{i}" for i in range(1, n_face + 1)]
    return mocap.Take(labels, world, rate=RATE), rot, trans, head


def errors(st, rot, trans, head):
    """Rotation (deg) and head-centre translation (mm) errors, after matching head frames.

    The estimated head frame is the world frame at the reference frame; one
    rigid fit of the true head shape onto ``st.reference_shape`` (Q, q) maps
    it to the true head frame: R_true ~ R Q and t_true ~ R q + t.
    """
    from mocap.rigid import fit_rigid
    gauge = fit_rigid(head, st.reference_shape)
    r_est = st.rotation @ gauge.rotation
    t_est = np.einsum("tij,j->ti", st.rotation, gauge.translation) + st.translation
    rot_err = Rotation.from_matrix(np.swapaxes(rot, 1, 2) @ r_est).magnitude()
    return np.degrees(rot_err), np.linalg.norm(t_est - trans, axis=1)


def align_vectors_loop(head_positions: np.ndarray, shape: np.ndarray):
    """The baseline: one scipy fit per frame, then the take moved into the head frame."""
    n_frames = head_positions.shape[0]
    rotation = np.empty((n_frames, 3, 3))
    translation = np.empty((n_frames, 3))
    ref_c = shape - shape.mean(axis=0)
    for t in range(n_frames):
        centre = head_positions[t].mean(axis=0)
        r, _ = Rotation.align_vectors(head_positions[t] - centre, ref_c)
        rotation[t] = r.as_matrix()
        translation[t] = centre - rotation[t] @ shape.mean(axis=0)
    return rotation, translation


def accuracy(n_frames: int) -> None:
    take, rot, trans, head = synthetic_take(n_frames, 66)
    st = stabilize(take, HEAD)
    rot_err, trans_err = errors(st, rot, trans, head)
    print(f"\n1. Accuracy, synthetic take: {n_frames} frames, 6 head + 66 face markers, "
          f"0.2 mm noise, {HEAD[SLIP_MARKER]} slips {SLIP_MM} mm in frame indices "
          f"{SLIP_START}-{SLIP_START + SLIP_FRAMES - 1}")
    print(f"   {st.message}")
    print(f"   {'':28s}{'median':>10s}{'95th pct':>10s}{'max':>10s}{'aim (median)':>14s}")
    for name, err, aim in (("rotation error (deg)", rot_err, 0.1),
                           ("translation error (mm)", trans_err, 0.2)):
        print(f"   {name:28s}{np.median(err):10.4f}{np.percentile(err, 95):10.4f}"
              f"{err.max():10.4f}{aim:14.2f}")
    window = slice(SLIP_START, SLIP_START + SLIP_FRAMES)
    print(f"   during the slip: median rotation error {np.median(rot_err[window]):.4f} deg, "
          f"translation {np.median(trans_err[window]):.4f} mm; slipped marker's weight "
          f"{np.median(st.weights[window, SLIP_MARKER]):.3g}")
    for slip in st.slips:
        print(f"   slip found: {slip.marker} frame indices {slip.start}-{slip.stop - 1}, "
              f"max residual {slip.max_residual:.2f} mm")
    if not st.slips:
        print("   no slip found")
    from mocap.rigid import fit_rigid
    w = np.ones((n_frames, 6))
    w[SLIP_START:SLIP_START + SLIP_FRAMES, SLIP_MARKER] = 0.0
    ideal = fit_rigid(head, take.positions[:, :6], w)
    ideal_rot = np.degrees(Rotation.from_matrix(np.swapaxes(rot, 1, 2) @ ideal.rotation)
                           .magnitude())
    ideal_trans = np.linalg.norm(ideal.translation - trans, axis=1)
    print(f"   noise floor (per-frame fit to the TRUE shape, slipped samples dropped): median "
          f"{np.median(ideal_rot):.4f} deg, {np.median(ideal_trans):.4f} mm")
    plain = stabilize(take, HEAD, robust=False)
    rot_plain, trans_plain = errors(plain, rot, trans, head)
    print(f"   without robust weights, during the slip: median rotation error "
          f"{np.median(rot_plain[window]):.4f} deg, translation "
          f"{np.median(trans_plain[window]):.4f} mm")


def speed(n_frames: int, n_baseline: int) -> None:
    take, _, _, _ = synthetic_take(n_frames, 66, seed=1)
    head = take.positions[:, :6]
    shape = head[0]
    ours = best_time(lambda: stabilize(take, HEAD), repeat=3)
    ours_frame = best_time(lambda: stabilize(take, HEAD, reference="frame", reference_frame=0,
                                             robust=False), repeat=3)

    def baseline():
        r, t = align_vectors_loop(head[:n_baseline], shape)
        return np.matmul(take.positions[:n_baseline] - t[:, None], r)

    base = best_time(baseline, repeat=1) * n_frames / n_baseline
    memory = peak_memory_mb(lambda: stabilize(take, HEAD))
    print(f"\n2. Speed: {n_frames} frames, 6 head + 66 face markers "
          f"(baseline timed on {n_baseline} frames, scaled)")
    print(f"   {'method':58s}{'time (s)':>10s}{'vs loop':>10s}")
    print(f"   {'scipy align_vectors loop, one fit per frame':58s}{base:10.3f}{1.0:10.1f}")
    print(f"   {'stabilize(reference=frame, robust=False), one fit':58s}{ours_frame:10.3f}"
          f"{base / ours_frame:10.1f}")
    print(f"   {'stabilize(reference=mean, robust=True): GPA + IRLS':58s}{ours:10.3f}"
          f"{base / ours:10.1f}")
    print(f"   peak memory of stabilize: {memory:.0f} MB")


def real_capture() -> None:
    path = shared_data() / "captures" / "facial-sing.c3d"
    print(f"\n3. Real capture {path.name}")
    try:
        take = mocap.read(path)
    except Exception as exc:          # the C3D reader is being written elsewhere
        print(f"   skipped: mocap.read failed ({type(exc).__name__}: {exc})")
        return
    head = [f"root-{i}" for i in range(1, 7)]
    st = stabilize(take, head, min_slip_frames=10)
    print(f"   {take.n_frames} frames at {take.rate} Hz; {st.message} (runs of >= 10 frames)")
    print(f"   {'marker':10s}{'median':>9s}{'95th pct':>10s}{'max':>9s}{'missing':>9s}"
          f"{'weight<0.5':>12s}   (residuals, mm)")
    for j, label in enumerate(head):
        r = st.head_residuals[:, j]
        seen = r[~np.isnan(r)]
        print(f"   {label:10s}{np.median(seen):9.3f}{np.percentile(seen, 95):10.3f}"
              f"{seen.max():9.3f}{int(np.isnan(r).sum()):9d}"
              f"{int((st.weights[:, j] < 0.5).sum()):12d}")
    for slip in st.slips:
        print(f"   slip: {slip.marker} frame indices {slip.start}-{slip.stop - 1}, "
              f"max residual {slip.max_residual:.2f} mm")
    moved = np.ptp(st.translation[st.valid], axis=0)
    print(f"   head translation range {np.round(moved, 1)} mm; stabilized face markers "
          f"move {np.nanmedian(np.nanstd(st.take.positions, axis=0)):.2f} mm (median std)")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=35000)
    parser.add_argument("--baseline-frames", type=int, default=35000,
                        help="frames of the scipy loop actually timed (scaled to --frames)")
    args = parser.parse_args(argv)
    accuracy(min(args.frames, 6000))
    speed(args.frames, min(args.baseline_frames, args.frames))
    real_capture()
    return 0


if __name__ == "__main__":
    sys.exit(main())
