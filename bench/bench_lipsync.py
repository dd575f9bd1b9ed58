"""Talking faces on real speech: phones, lip closure, Praat against RMS, the MRF, speed.

Speech: the five LibriVox recordings of ``speech/`` (16 kHz, 24.7 s in all) with their
transcripts. Figures, each printed with its conditions:

1. Phone boundaries against the shipped alignments. Those were made by a CMU Sphinx
   aligner (PocketSphinx's ``align``), the same family as ours: they are a reference,
   not an independent truth, so agreement with them measures consistency, not accuracy.
   For each reference boundary (a time where one reference segment ends and the next
   starts), the distance to our nearest boundary; median and 90th percentile in ms,
   pooled over the recordings; also the other way (our boundaries to the reference's:
   over-segmentation) and the fraction of 10 ms frames whose viseme class agrees with
   the reference's. Rows: forced alignment of the transcript, the phone recognizer
   (default without a transcript) and word recognition + alignment.
2. Lip closure on the ICT face, each recording driving the whole synthesis (MRF over the
   ARKit reference clip + visemes + the region blend): the mesh's lip gap (inner-lip
   midpoints, iBUG 62-66, mm) on the frames inside the reference's /p b m/ segments
   (closed: gap < 1 mm) and inside its open-vowel segments AA AE AH AO EH (open: > 3 mm).
   Segments are the shipped reference's, so the recognizer's own errors count.
3. Praat's intensity (dB SPL, signal as Pa) against the RMS level of
   ``fit.gestures.speech`` (dB re full scale, 50 ms window) at 30 fps: Pearson correlation
   and the offset (median and spread of the difference) over the frames with speech
   (RMS above -60 dBFS) and over all frames.
4. The MRF driven by these recordings (Praat's S of the five, concatenated: 24.7 s)
   over the ARKit reference clip of ``bench_gestures.py``: its gesture figures (jumps
   above the reference's p99, blink and brow ratios, corr(S)), mean ± sd over seeds,
   beside the same figures with bench_gestures' driving intensity (alex_rom_4's JawOpen
   proxy, first 24.7 s) as the baseline of "still holds".
5. Speed: a minute of speech (the recordings repeated) to a lip-synced, MRF-animated ICT
   mesh: speech analysis (Praat, phones, visemes), MRF, the talking face written as
   ``mesh.npz`` (what ``gestures synthesize`` writes), in seconds per minute of speech
   against the 10 s target; the baseline row is the synthesis without lips (RMS, MRF,
   the expression mesh); the time to evaluate every vertex of every frame is printed too.
"""

from __future__ import annotations

import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import scipy.io.wavfile
from _common import shared_data
from bench_gestures import (
    NAMES,
    blink_length,
    blink_rate,
    brow_activity,
    jumps,
    mean_sd,
    sync,
)

from basis.artist import load_artist_basis
from fit.exports import write_mesh_sequence
from fit.gestures import clip_from_performance, synthesize_gestures
from fit.gestures.lipsync import talking_face
from fit.gestures.phones import phones_from_wav, read_sphinx_alignment
from fit.gestures.prosody import praat_prosody, rms_prosody
from fit.gestures.speech import read_wav
from fit.gestures.talking import analyze_speech
from fit.gestures.viseme_basis import viseme_basis_from_shapes
from fit.gestures.visemes import viseme_curves
from mocap.mesh.mesh import load_mesh
from mocap.synth.performance import read_performance

RATE = 30.0
KEYS = ("0870", "0880", "0890", "0920", "0930")
UPPER_LIP, LOWER_LIP = 5533, 5517
BILABIAL = ("P", "B", "M")
OPEN_VOWELS = ("AA", "AE", "AH", "AO", "EH")
SEEDS = 8


def recordings(data):
    for key in KEYS:
        stem = data / "speech" / f"sense_and_sensibility_01_austen_64kb-{key}"
        yield key, stem.with_suffix(".wav"), stem.with_suffix(".txt"), \
            stem.parent / f"{stem.name}.phone.json"


def nearest(a, b):
    """For each time of `a`, the distance to the nearest time of `b`, ms."""
    return 1000 * np.abs(a[:, None] - b[None]).min(axis=1)


def boundaries(data):
    rows = (("forced alignment (transcript)", dict(transcript=True)),
            ("phone recognizer (no transcript)", dict(recognizer="phones")),
            ("word recognizer + alignment", dict(recognizer="words")))
    print("\n1. phone boundaries against the shipped PocketSphinx alignments (a reference "
          "made by the same family of aligner, not an independent truth)")
    print(f"{'method':<34}{'ref->ours med':>14}{'p90 ms':>8}{'ours->ref med':>15}{'p90 ms':>8}"
          f"{'viseme agree':>14}{'time s':>8}")
    for label, options in rows:
        there, back, agree, seconds = [], [], [], 0.0
        for _, wav, txt, ref in recordings(data):
            start = time.perf_counter()
            kw = dict(options)
            if kw.pop("transcript", False):
                kw["transcript"] = txt
            ours = phones_from_wav(wav, **kw)
            seconds += time.perf_counter() - start
            theirs = read_sphinx_alignment(ref)
            there.append(nearest(theirs.boundaries(), ours.boundaries()))
            back.append(nearest(ours.boundaries(), theirs.boundaries()))
            n = int(theirs.end[-1] * 100)
            a, b = (viseme_curves(s, rate=100.0, n_frames=n).weights.argmax(axis=1)
                    for s in (ours, theirs))
            agree.append(a == b)
        t, k = np.concatenate(there), np.concatenate(back)
        print(f"{label:<34}{np.median(t):>14.0f}{np.percentile(t, 90):>8.0f}"
              f"{np.median(k):>15.0f}{np.percentile(k, 90):>8.0f}"
              f"{100 * np.concatenate(agree).mean():>13.0f}%{seconds:>8.2f}")


def face(data):
    mesh = load_mesh(data / "ict-face" / "generic_neutral_mesh.obj", units="cm")
    basis = load_artist_basis(mesh, data / "ict-face" / "expressions")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        clip = clip_from_performance(read_performance(data / "arkit-performances" /
                                                      "alex_rom_3.csv"),
                                     name="arkit", rate=RATE, shapes=basis.names)
    return basis, viseme_basis_from_shapes(basis), clip


def lip_closure(data, basis, visemes, clip):
    print("\n2. lip closure on the ICT face driven by the five recordings (segments: the "
          "shipped reference's; gap = inner-lip midpoints iBUG 62-66)")
    print(f"{'phones from':<34}{'closed<1mm in /p b m/':>22}{'open>3mm in open V':>20}"
          f"{'frames':>10}")
    for label, options in (("forced alignment (transcript)", "transcript"),
                           ("phone recognizer (no transcript)", "phones"),
                           ("word recognizer + alignment", "words")):
        closed, opened = [], []
        for _, wav, txt, ref in recordings(data):
            kw = dict(transcript=txt) if options == "transcript" else dict(recognizer=options)
            speech = analyze_speech(wav, rate=RATE, **kw)
            syn = synthesize_gestures(speech.prosody.intensity, [clip], rate=RATE, seed=0)
            talk = talking_face(basis, syn.weights, visemes, speech.visemes)
            v = talk.vertices(basis.neutral.vertices)
            gap = 10.0 * (v[:, UPPER_LIP, 1] - v[:, LOWER_LIP, 1])
            theirs = read_sphinx_alignment(ref)
            inside = theirs.at(np.arange(len(gap)) / RATE)
            label_at = np.array(theirs.phone + ("",))[inside]
            closed.append(gap[np.isin(label_at, BILABIAL)] < 1.0)
            opened.append(gap[np.isin(label_at, OPEN_VOWELS)] > 3.0)
        c, o = np.concatenate(closed), np.concatenate(opened)
        print(f"{label:<34}{100 * c.mean():>17.1f}% of {len(c):<3}{100 * o.mean():>14.1f}% "
              f"of {len(o):<4}")


def praat_vs_rms(data):
    print("\n3. Praat's intensity (dB SPL, signal as Pa) against the RMS level (dBFS, 50 ms) "
          "at 30 fps")
    pr, rm = [], []
    for _, wav, _, _ in recordings(data):
        x, rate = read_wav(wav)
        pr.append(praat_prosody(x, rate, frame_rate=RATE).intensity)
        rm.append(rms_prosody(x, rate, frame_rate=RATE).intensity)
    p, r = np.concatenate(pr), np.concatenate(rm)
    for label, keep in (("frames with speech (RMS > -60 dBFS)", r > -60),
                        ("all frames", np.ones_like(r, bool))):
        d = p[keep] - r[keep]
        print(f"{label:<38} n={keep.sum():<5} corr {np.corrcoef(p[keep], r[keep])[0, 1]:.3f}"
              f"  offset median {np.median(d):.2f} dB (IQR {np.percentile(d, 25):.2f}.."
              f"{np.percentile(d, 75):.2f}); 20 log10(1 / 2e-5) = {20 * np.log10(5e4):.2f}")
    return np.concatenate([praat_prosody(*read_wav(w), frame_rate=RATE).intensity
                           for _, w, _, _ in recordings(data)])


def mrf_figures(data, drive_praat):
    print(f"\n4. the MRF over the ARKit reference driven by the recordings (Praat S, "
          f"{len(drive_praat)} frames), {SEEDS} seeds, mean ± sd; ratios to the reference")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = clip_from_performance(read_performance(data / "arkit-performances" /
                                                     "alex_rom_3.csv"), name="arkit", rate=RATE)
        other = clip_from_performance(read_performance(data / "arkit-performances" /
                                                       "alex_rom_4.csv"), name="rom4",
                                      rate=RATE)
    names = ref.names
    blink, jaw, brows = NAMES["arkit"]
    p99 = np.percentile(np.linalg.norm(np.diff(ref.weights, axis=0), axis=1), 99)
    blink0, length0 = blink_rate(ref.weights, names, blink), blink_length(ref.weights, names,
                                                                          blink)
    brow0 = brow_activity(ref.weights, names, brows)
    print(f"{'driving speech':<36}{'jumps>p99 %':>12}{'blink ratio':>12}{'blink len':>12}"
          f"{'brow ratio':>12}{'corr(S)':>13}")
    for label, drive in (("the five recordings (Praat S)", drive_praat),
                         ("alex_rom_4 JawOpen proxy (baseline)",
                          other.intensity[:len(drive_praat)])):
        rows = []
        for seed in range(SEEDS):
            w = synthesize_gestures(drive, [ref], rate=RATE, seed=seed).weights
            rows.append((100 * jumps(w, p99), blink_rate(w, names, blink) / blink0,
                         blink_length(w, names, blink) / length0,
                         brow_activity(w, names, brows) / brow0, sync(w, names, jaw, drive)))
        cols = list(zip(*rows))
        print(f"{label:<36}" + "".join(f"{mean_sd(c):>12}" for c in cols[:4])
              + f"{mean_sd(cols[4], '{:.3f}'):>13}")


def speed(data, basis, visemes, clip):
    waves, words = [], []
    for _, wav, txt, _ in recordings(data):
        x, rate = read_wav(wav)
        waves.append(x)
        words.append(txt.read_text().strip())
    # whole repeats of the five recordings up to a minute, so that the transcript fits
    full = int(np.ceil(60 * rate / sum(len(w) for w in waves)))
    signal = np.concatenate(waves * full)[:int(60 * rate)]
    whole = int(60 * rate) // sum(len(w) for w in waves)
    aligned = np.concatenate(waves * whole)
    transcript = " ".join(words * whole)
    print(f"\n5. speed: a minute of speech (the recordings repeated; {len(aligned) / rate:.1f} s "
          f"of whole repeats with their transcript) to a lip-synced, MRF-animated ICT mesh "
          f"({basis.neutral.n_vertices} vertices): speech analysis, MRF, talking face written "
          f"as mesh.npz (what 'gestures synthesize' writes); measured under load")
    with tempfile.TemporaryDirectory() as tmp:
        minute, part = Path(tmp) / "minute.wav", Path(tmp) / "aligned.wav"
        scipy.io.wavfile.write(minute, int(rate), (signal * 32767).astype(np.int16))
        scipy.io.wavfile.write(part, int(rate), (aligned * 32767).astype(np.int16))
        rows = (("transcript (forced alignment)", part, dict(transcript=transcript)),
                ("no transcript (phone recognizer)", minute, dict(recognizer="phones")),
                ("no transcript (word recognizer)", minute, dict(recognizer="words")),
                ("baseline: no lips, RMS S(t)", minute, dict(lips=False, intensity="rms")))
        for label, path, options in rows:
            seconds = len(read_wav(path)[0]) / rate
            t0 = time.perf_counter()
            speech = analyze_speech(path, rate=RATE, **options)
            t1 = time.perf_counter()
            syn = synthesize_gestures(speech.prosody.intensity, [clip], rate=RATE, seed=0)
            t2 = time.perf_counter()
            if speech.visemes is not None:
                talk = talking_face(basis, syn.weights, visemes, speech.visemes)
                fields, weights = talk.displacements, talk.weights
            else:
                fields, weights = basis.displacements, syn.weights
            write_mesh_sequence(Path(tmp) / "mesh.npz", basis.neutral, fields, weights,
                                rate=RATE)
            t3 = time.perf_counter()
            vertices = (weights @ fields.reshape(len(fields), -1)).reshape(
                len(weights), -1, 3) + basis.neutral.vertices
            t4 = time.perf_counter()
            per_minute = (t3 - t0) * 60 / seconds
            print(f"{label:<34} speech {t1 - t0:5.2f} s, MRF {t2 - t1:5.2f} s, face + mesh.npz "
                  f"{t3 - t2:5.2f} s: {t3 - t0:5.2f} s for {seconds:.1f} s = {per_minute:5.2f} s "
                  f"per minute (target 10 s: ratio {10 / per_minute:4.2f}); every vertex of "
                  f"the {len(vertices)} frames in float64 +{t4 - t3:.2f} s")


def main() -> None:
    data = shared_data()
    boundaries(data)
    start = time.perf_counter()
    basis, visemes, clip = face(data)
    print(f"\n(ICT face: 53 shapes loaded and the visemes built in "
          f"{time.perf_counter() - start:.1f} s, not counted below)")
    lip_closure(data, basis, visemes, clip)
    drive = praat_vs_rms(data)
    mrf_figures(data, drive)
    speed(data, basis, visemes, clip)


if __name__ == "__main__":
    main()
