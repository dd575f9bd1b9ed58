"""Speech-driven facial gestures (Ju & Lee 2008) on two real references, averaged over seeds.

References (the palette, one clip each):

- ``arkit``: ``arkit-performances/alex_rom_3.csv`` (52 ARKit weights resampled to
  30 Hz). No audio: S(t) is the RMS energy in dB of the JawOpen curve over 0.25 s.
- ``sing``: ``captures/facial-sing.c3d`` bound to the ICT face in the head frame
  (``tests/facial_sing_markerset.toml``, ``tests/ict_landmarks.toml``), then
  what ``mocap2mesh gestures analyze`` runs
  (:func:`fit.gestures.reference.clip_from_capture`): gap fill, 30 Hz, head
  stabilization, the 53 ICT shapes sampled at the bound markers in capture mm,
  the decomposition into weights, head motion and the four detail groups. The
  C3D has no analog channel (``take.analog is None``), so S(t) is the stand-in:
  the loudness of the lip opening (section10-2 to section13-2, the marker set's
  lip landmarks, minus its minimum, RMS dB over 0.25 s).

Driving "speech" for both: the JawOpen proxy intensity of the other performance,
alex_rom_4 (first minute). Baseline: spectrum-matched noise (the reference
curves with randomized Fourier phases, what a Perlin-noise generator tuned to
the same spectrum produces), clipped to the reference range.

Figures, each the mean ± standard deviation over ``SEEDS`` seeds: jumps (frames
whose |Δc| exceeds the reference's 99th percentile; 1 % in the reference by
definition), blink rate (left-eye blink weight rising through 0.5, per minute),
blink length (frames a blink stays above 0.5: its shape), brow activity (mean
|Δ| of the brow weights per second), correlation of the synthesized
jaw-opening intensity with the driving intensity, time warps (output frames of
the weight chains copying a frame less than h from the continuation: stalls,
short replays, skips; ``GestureSynthesis.warps``) and the time to synthesize a
minute at 30 fps. The ratio columns divide by the reference. Rows (``CONFIGS``):
blinks and brows on their own chains (the default, :mod:`fit.gestures.features`)
under three settings of run/blend (run=1 blend=4 are the defaults), all
weights in one chain (``weight_groups={}``), as before the split, the chain
without time warps, the driving intensity mapped onto the reference's S by
quantiles (a test of whether the two intensities' scales are the cause), then
the reference's own S(t) (its first minute; 30 s for facial-sing), with and
without time warps and played backwards: the last has the reference's scale
and distribution exactly but not its order, so it separates what a foreign
speech does from what a foreign scale does. The header also prints the
median over frames of the smallest step a transition at least h frames away
can make (feature term only), against the jump threshold: how many smooth
transitions the reference offers at all. facial-sing's blink figures rest on 2
reference "blinks" (the 41-frame average of its eye weights crossing 0.5), not
real blinks: its eye markers sit on the orbit, not on the lids.
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import numpy as np
from _common import shared_data

from fit.gestures import clip_from_performance, speech_intensity, synthesize_gestures
from fit.solve.temporal import moving_average
from mocap.synth.performance import read_performance

RATE = 30.0
MINUTE = int(60 * RATE)
SEEDS = 16
#: Rows: label, options of ``synthesize_gestures``, driving intensity ("other": alex_rom_4's;
#: "quantile": that, mapped onto the reference's S by quantiles; "own": the reference's S;
#: "reversed": the reference's S backwards, on exactly its scale and distribution).
CONFIGS = (("MRF run=1 blend=0", {"blend": 0}, "other"),
           ("MRF run=1 blend=4", {}, "other"),
           ("MRF run=3 blend=4", {"run": 3}, "other"),
           ("MRF 1 chain", {"weight_groups": {}}, "other"),
           ("MRF no time warps", {"time_warps": False}, "other"),
           ("MRF S quantile-mapped", {}, "quantile"),
           ("MRF own S", {}, "own"),
           ("MRF own S no time warps", {"time_warps": False}, "own"),
           ("MRF own S reversed", {}, "reversed"))
#: Row of the defaults of ``synthesize_gestures``, whose time is the speed figure.
DEFAULT_ROW = "MRF run=1 blend=4"
#: History h of the defaults.
HISTORY = 10
TESTS = Path(__file__).resolve().parent.parent / "tests"
#: Column names of each reference: left blink, jaw opening, brows.
NAMES = {
    "arkit": ("EyeBlinkLeft", "JawOpen", ("BrowDownLeft", "BrowDownRight", "BrowInnerUp",
                                          "BrowOuterUpLeft", "BrowOuterUpRight")),
    "sing": ("eyeBlink_L", "jawOpen", ("browDown_L", "browDown_R", "browInnerUp_L",
                                       "browInnerUp_R", "browOuterUp_L", "browOuterUp_R")),
}


def jumps(weights, threshold):
    return float(np.mean(np.linalg.norm(np.diff(weights, axis=0), axis=1) > threshold))


def blink_rate(weights, names, blink):
    eye = weights[:, names.index(blink)] > 0.5
    return float(np.count_nonzero(eye[1:] & ~eye[:-1]) / (len(weights) / RATE / 60))


def blink_length(weights, names, blink):
    """Mean number of frames a blink stays above 0.5 (NaN without blinks)."""
    eye = np.concatenate([[0], (weights[:, names.index(blink)] > 0.5).astype(int), [0]])
    edges = np.diff(eye)
    lengths = np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)
    return float(lengths.mean()) if lengths.size else float("nan")


def brow_activity(weights, names, brows):
    cols = [names.index(b) for b in brows]
    return float(np.abs(np.diff(weights[:, cols], axis=0)).sum(axis=1).mean() * RATE)


def sync(weights, names, jaw, drive):
    own = speech_intensity(np.maximum(weights[:, names.index(jaw)], 0.0), RATE,
                           frame_rate=RATE, n_frames=len(weights), window=0.25)
    a, b = (moving_average(np.maximum(x, np.percentile(x, 95) - 60), window=15)
            for x in (own, drive))
    return float(np.corrcoef(a, b)[0, 1])


def quantile_map(x, onto):
    """x (n,) mapped monotonically onto the distribution of `onto`: its frame of rank r
    takes the (r + 0.5)/n quantile of `onto`."""
    ranks = np.argsort(np.argsort(x, kind="stable"), kind="stable")
    return np.quantile(onto, (ranks + 0.5) / len(x))


def best_transitions(weights, threshold, h=HISTORY):
    """Median over frames of the smallest step a transition can make, in units of `threshold`.

    For each frame f, the window c(f−h+1 .. f) is matched against every window of the
    clip at least h frames from it (feature term only, as the chain without time warps
    may jump); the step is |c(t̂ + 1) − c(f + 1)| of the best match t̂.
    """
    win = np.lib.stride_tricks.sliding_window_view(weights, (h, weights.shape[1]))[:, 0]
    win = win.reshape(len(win), -1)[:-1]                 # windows followed by a frame
    sq = np.einsum("ij,ij->i", win, win)
    idx = np.arange(len(win))
    steps = []
    for lo in range(0, len(win), 512):                  # rows in chunks (memory)
        rows = idx[lo:lo + 512]
        d = sq[rows, None] + sq[None] - 2.0 * win[rows] @ win.T
        d[np.abs(rows[:, None] - idx[None]) < h] = np.inf
        best = np.argmin(d, axis=1)
        steps.append(np.linalg.norm(weights[best + h] - weights[rows + h], axis=1))
    return float(np.median(np.concatenate(steps)) / threshold)


def phase_noise(reference, n, rng):
    """Curves (n, d) with the reference's amplitude spectrum and random phases."""
    n = min(n, len(reference))
    seg = reference[:n] - reference[:n].mean(axis=0)
    spec = np.fft.rfft(seg, axis=0)
    phases = np.exp(2j * np.pi * rng.random(spec.shape))
    phases[0] = 1.0
    out = np.fft.irfft(np.abs(spec) * phases, n=n, axis=0) + reference[:n].mean(axis=0)
    return np.clip(out, reference.min(axis=0), reference.max(axis=0))


def arkit_clips(data):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = clip_from_performance(read_performance(data / "alex_rom_3.csv"), name="arkit",
                                    rate=RATE)
        other = clip_from_performance(read_performance(data / "alex_rom_4.csv"), name="rom4",
                                      rate=RATE)
    return ref, other.intensity[:MINUTE]


def sing_clip(data):
    """The facial-sing capture analysed on the ICT basis (see the module docstring)."""
    import mocap
    from basis.artist import load_artist_basis
    from fit.gestures.reference import clip_from_capture
    from mocap.bind import bind_take
    from mocap.markerset import load_markerset
    from mocap.mesh.landmarks import load_mesh_landmarks
    from mocap.mesh.mesh import load_mesh

    take = mocap.read(data / "captures" / "facial-sing.c3d")
    assert take.analog is None, "facial-sing.c3d has an analog channel: use it for S(t)"
    markerset = load_markerset(TESTS / "facial_sing_markerset.toml")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mesh = load_mesh(data / "ict-face" / "generic_neutral_mesh.obj", units="cm")
        landmarks = load_mesh_landmarks(TESTS / "ict_landmarks.toml", mesh)
        binding = bind_take(take, markerset, mesh, landmarks, head_frame=True).binding
        basis = load_artist_basis(mesh, data / "ict-face" / "expressions")
        made = clip_from_capture(take, markerset, binding, basis, name="sing", rate=RATE)
    return made.clip, made.message, binding


def mean_sd(values, fmt="{:.2f}"):
    """Mean ± standard deviation over the seeds that have a value (blink length: NaN
    for a seed without blinks)."""
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return "-"
    return f"{fmt.format(values.mean())}±{fmt.format(values.std())}"


def table(ref, drive, kind):
    names = ref.names
    blink, jaw, brows = NAMES[kind]
    p99 = np.percentile(np.linalg.norm(np.diff(ref.weights, axis=0), axis=1), 99)
    blink0, brow0 = blink_rate(ref.weights, names, blink), brow_activity(ref.weights, names,
                                                                         brows)
    length0 = blink_length(ref.weights, names, blink)
    sync0 = sync(ref.weights, names, jaw, ref.intensity)
    print(f"\n[{kind}] {ref.n_frames} frames at {RATE:g} Hz, features "
          f"{list(ref.features())}; |dc| p99 = {p99:.4f}; reference: {blink0:.1f} blinks/min of "
          f"{length0:.1f} frames, brow activity {brow0:.3f}/s, corr(own jaw, own S) {sync0:.3f}")
    print(f"the best transition at least h = {HISTORY} frames away steps "
          f"{best_transitions(ref.weights, p99):.2f} x p99 (median over frames)")
    drives = {"other": drive, "quantile": quantile_map(drive, ref.intensity),
              "own": ref.intensity[:MINUTE], "reversed": ref.intensity[:MINUTE][::-1].copy()}
    print(f"{'method':<26}{'jumps>p99 %':>12}{'blink ratio':>12}{'blink len':>12}"
          f"{'brow ratio':>12}{'corr(S)':>13}{'warps %':>10}{'time s':>12}")
    times = {}
    for label, options, speech in (*CONFIGS, ("spectrum noise", None, "other")):
        speech, rows = drives[speech], []
        for seed in range(SEEDS):
            start = time.perf_counter()
            if options is None:
                w, warped = phase_noise(ref.weights, MINUTE, np.random.default_rng(seed)), 0.0
            else:
                syn = synthesize_gestures(speech, [ref], rate=RATE, seed=seed, **options)
                w = syn.weights
                chains = [f for f in ("weights", "blinks", "brows") if f in syn.warps]
                warped = 100 * np.mean([syn.warps[f] for f in chains]) / len(w)
            seconds = time.perf_counter() - start
            rows.append((100 * jumps(w, p99), blink_rate(w, names, blink) / blink0,
                         blink_length(w, names, blink) / length0,
                         brow_activity(w, names, brows) / brow0,
                         sync(w, names, jaw, speech[:len(w)]), warped, seconds))
        cols = list(zip(*rows))
        times[label] = np.mean(cols[6])
        print(f"{label:<26}" + "".join(f"{mean_sd(c):>12}" for c in cols[:4])
              + f"{mean_sd(cols[4], '{:.3f}'):>13}{mean_sd(cols[5], '{:.0f}'):>10}"
              + f"{mean_sd(cols[6], '{:.3f}'):>12}")
    mrf, noise = times[DEFAULT_ROW], times["spectrum noise"]
    print(f"speed: one minute at 30 fps in {mrf:.2f} s (defaults; aim < 5 s); noise baseline "
          f"{noise:.4f} s, ratio {mrf / noise:.0f}x")


def main() -> None:
    data = shared_data()
    ref, drive = arkit_clips(data / "arkit-performances")
    print(f"driving: JawOpen proxy intensity of alex_rom_4, {len(drive)} frames; "
          f"{SEEDS} seeds per row (mean ± standard deviation)")
    table(ref, drive, "arkit")
    start = time.perf_counter()
    sing, message, binding = sing_clip(data)
    print(f"\nfacial-sing: bind + ICT basis + ingest + analysis in "
          f"{time.perf_counter() - start:.1f} s; bind: {binding.message}, rms "
          f"{binding.rms:.2f} mm; {message}")
    table(sing, drive, "sing")


if __name__ == "__main__":
    main()
