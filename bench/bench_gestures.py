"""Speech-driven facial gestures (Ju & Lee 2008) on real ARKit performances.

Reference clip: ``arkit-performances/alex_rom_3.csv`` (52 ARKit weights, resampled
to 30 Hz). The performances have no audio, so S(t) is a proxy: the RMS energy in
dB of the JawOpen curve over 0.25 s (mouth opening follows speech energy). The
driving "speech" is the proxy intensity of the other performance, alex_rom_4
(first minute). Baseline: spectrum-matched noise, the reference curves with
randomized Fourier phases (what a Perlin-noise generator tuned to the same
spectrum produces), clipped to the reference range.

Figures: jumps (frames whose |Δc| exceeds the reference's 99th percentile; the
reference has 1 % by definition), blink rate (EyeBlinkLeft rising through 0.5,
per minute), brow activity (mean |Δ| of the brow weights per second),
correlation of the synthesized mouth-activity intensity with the driving
intensity, and the time to synthesize a minute at 30 fps.

The singing capture (facial-sing.c3d: stabilize, bind, solve) is not benchmarked here.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from _common import shared_data
from fit.gestures import clip_from_performance, speech_intensity, synthesize_gestures
from fit.temporal import moving_average
from mocap.performance import read_performance

RATE = 30.0
MINUTE = int(60 * RATE)
BROWS = ("BrowDownLeft", "BrowDownRight", "BrowInnerUp", "BrowOuterUpLeft", "BrowOuterUpRight")


def jumps(weights, threshold):
    return float(np.mean(np.linalg.norm(np.diff(weights, axis=0), axis=1) > threshold))


def blink_rate(weights, names):
    eye = weights[:, names.index("EyeBlinkLeft")] > 0.5
    return float(np.count_nonzero(eye[1:] & ~eye[:-1]) / (len(weights) / RATE / 60))


def brow_activity(weights, names):
    cols = [names.index(b) for b in BROWS]
    return float(np.abs(np.diff(weights[:, cols], axis=0)).sum(axis=1).mean() * RATE)


def sync(weights, names, drive):
    own = speech_intensity(weights[:, names.index("JawOpen")], RATE, frame_rate=RATE,
                           n_frames=len(weights), window=0.25)
    a, b = (moving_average(np.maximum(x, np.percentile(x, 95) - 60), window=15)
            for x in (own, drive))
    return float(np.corrcoef(a, b)[0, 1])


def phase_noise(reference, n, rng):
    """Curves (n, d) with the reference's amplitude spectrum and random phases."""
    seg = reference[:n] - reference[:n].mean(axis=0)
    spec = np.fft.rfft(seg, axis=0)
    phases = np.exp(2j * np.pi * rng.random(spec.shape))
    phases[0] = 1.0
    out = np.fft.irfft(np.abs(spec) * phases, n=n, axis=0) + reference[:n].mean(axis=0)
    return np.clip(out, reference.min(axis=0), reference.max(axis=0))


def main() -> None:
    data = shared_data() / "arkit-performances"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = clip_from_performance(read_performance(data / "alex_rom_3.csv"), name="rom3",
                                    rate=RATE)
        other = clip_from_performance(read_performance(data / "alex_rom_4.csv"), name="rom4",
                                      rate=RATE)
    names, drive = ref.names, other.intensity[:MINUTE]
    p99 = np.percentile(np.linalg.norm(np.diff(ref.weights, axis=0), axis=1), 99)
    print(f"reference {ref.name}: {ref.n_frames} frames at {RATE:g} Hz; driving: proxy "
          f"intensity of {other.name}, {len(drive)} frames; |dc| p99 = {p99:.4f}")
    rows = [("reference", ref.weights, np.nan)]
    for run, blend in ((1, 0), (1, 4), (3, 4)):
        start = time.perf_counter()
        syn = synthesize_gestures(drive, [ref], rate=RATE, run=run, blend=blend, seed=0)
        rows.append((f"MRF run={run} blend={blend}", syn.weights, time.perf_counter() - start))
    start = time.perf_counter()
    noise = phase_noise(ref.weights, MINUTE, np.random.default_rng(0))
    rows.append(("spectrum noise", noise, time.perf_counter() - start))
    blink0, brow0 = blink_rate(ref.weights, names), brow_activity(ref.weights, names)
    print(f"\n{'method':<22}{'jumps>p99':>10}{'blinks/min':>11}{'(ratio)':>8}"
          f"{'brow act/s':>11}{'(ratio)':>8}{'corr(S)':>9}{'time s':>8}")
    for label, w, seconds in rows:
        blink, brow = blink_rate(w, names), brow_activity(w, names)
        corr = sync(w[:MINUTE], names, drive) if label != "reference" else np.nan
        print(f"{label:<22}{100 * jumps(w, p99):>9.2f}%{blink:>11.1f}{blink / blink0:>8.2f}"
              f"{brow:>11.3f}{brow / brow0:>8.2f}{corr:>9.3f}{seconds:>8.2f}")
    mrf_time = rows[1][2]
    print(f"\nspeed: one minute at 30 fps in {mrf_time:.2f} s (run=1; aim < 5 s); "
          f"noise baseline {rows[-1][2]:.4f} s, ratio {mrf_time / rows[-1][2]:.0f}x")


if __name__ == "__main__":
    main()
