"""``mocap2mesh gestures analyze|synthesize``: reference clips from captures, gestures from speech.

``gestures analyze CAPTURE --markerset MS --binding B --mesh N --shapes S -o CLIP.npz``
builds a reference clip (:func:`fit.gestures.reference.clip_from_capture`).

``gestures synthesize SPEECH --palette CLIP... -o DIR`` writes into DIR:
``weights.csv`` (c̃(t)), ``prosody.csv`` (S̃(t), F0), ``phones.csv`` and
``visemes.csv`` (the lips: phone segments, d̃_l(t); not with ``--no-lips``),
``head.npz`` (R̃, T̃, if the palette has head motion), ``details.npz`` (D̃_j in
mm, if it has details), and with ``--mesh``/``--shapes`` the animated face
``mesh.npz`` (neutral + morph targets + weights: the lip region from the
visemes, the rest from the MRF, the details transferred by compact RBFs when
``--binding`` is given) and ``gestures.glb`` (morph-target animation; with
``--binding``, the head motion too, as the node's rotation and translation);
with ``--video``, ``talking.webm`` (the face with the speech as its sound) and
``index.html`` showing it.

``gestures phones SPEECH [--transcript T] -o phones.csv``: the phone segments alone.
"""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np

from fit.cli.arguments import (
    add_binding,
    add_capture,
    add_fill,
    add_markerset,
    add_mesh,
    add_neutral_frame,
    add_stabilize,
    add_units,
    stabilize_options,
)
from fit.gestures.analysis import ESTIMATORS
from fit.gestures.phones import RECOGNIZERS
from fit.gestures.prosody import PROSODY_METHODS
from mocap.errors import InputError
from mocap.synth.performance import read_performance

HELP = "facial gestures: reference clips from captures, synthesis from speech"

__all__ = ["add_parser", "run_analyze", "run_synthesize", "run_phones", "load_palette"]


def _pair(text: str) -> tuple:
    parts = tuple(x.strip() for x in text.split(","))
    if len(parts) != 2 or not all(parts):
        raise ValueError(text)
    return parts


def add_parser(sub) -> None:
    p = sub.add_parser(
        "gestures", help=HELP,
        description="Expressive facial gestures (Ju & Lee 2008): 'analyze' decomposes a "
                    "capture into a reference clip (blend weights, blinks, brows, head motion, "
                    "details, speech intensity); 'synthesize' drives a Markov random field over "
                    "such clips with a speech WAV file.")
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    _add_analyze(actions)
    _add_synthesize(actions)
    _add_phones(actions)


def _add_analyze(actions) -> None:
    p = actions.add_parser(
        "analyze", help="build a reference clip from a capture",
        description="Fill the capture's gaps, resample it to RATE, stabilize it in the head "
                    "frame, sample the expression shapes at the bound markers, fit the blend "
                    "weights to the moving average of the markers (-eps <= c <= 1 + eps), split "
                    "the residual into lips and the detail groups (brows, eyes), and take the "
                    "speech intensity S(t) from --speech, --analog or, without audio, the "
                    "loudness of the lip opening (stated in a warning and in the clip). "
                    "Writes OUT.npz, read by 'gestures synthesize --palette'.")
    add_capture(p)
    add_markerset(p)
    add_binding(p, help="binding .json of the capture to --mesh, in the head frame "
                        "('mocap2mesh bind --stabilize')")
    add_mesh(p, help="neutral face mesh of the binding")
    p.add_argument("--shapes", required=True, type=Path,
                   help="expression shapes (OBJ directory or glTF/GLB, e.g. a basis written "
                        "by 'mocap2mesh basis')")
    add_units(p)
    p.add_argument("-o", "--output", required=True, type=Path, help="clip .npz")
    p.add_argument("--name", help="style name of the clip (default: the output's stem)")
    speech = p.add_mutually_exclusive_group()
    speech.add_argument("--speech", type=Path, metavar="WAV",
                        help="speech recorded with the capture, from its first frame")
    speech.add_argument("--analog", metavar="CHANNEL",
                        help="analog channel of the capture holding the speech")
    speech.add_argument("--opening", type=_pair, metavar="UPPER,LOWER",
                        help="lip markers of the stand-in (default: the marker set's "
                             "upper_lip_top and lower_lip_bottom landmarks)")
    p.add_argument("--intensity-window", type=float, metavar="S",
                   help="RMS window of S(t) (default 0.05 for speech, 0.25 for the stand-in)")
    _add_intensity(p)
    p.add_argument("--rate", type=float, default=30.0, metavar="HZ",
                   help="frame rate of the clip: the synthesis rate (default 30)")
    p.add_argument("--window", type=int, default=41, metavar="FRAMES",
                   help="moving-average window of the weight fit (default 41, the paper's)")
    p.add_argument("--epsilon", type=float, default=0.1, help="weight bounds (default 0.1)")
    p.add_argument("--estimator", choices=ESTIMATORS, default="exact",
                   help="bounded least squares (default), or the paper's sampling estimator")
    add_neutral_frame(p, "--neutral-frame",
                      help="0-based frame index at RATE of the neutral, 'auto' (default): the "
                           "frame closest to the median pose, or 'hold': the mean pose of the "
                           "neutral hold the take starts with")
    add_fill(p)
    p.add_argument("--lowpass", type=float, metavar="HZ", help="Butterworth cut-off")
    add_stabilize(p)
    p.add_argument("--seed", type=int, default=0, help="seed of the sampling estimator")
    p.set_defaults(run=run_analyze)


def _add_synthesize(actions) -> None:
    p = actions.add_parser(
        "synthesize", help="synthesize gestures (weights, head motion, details) from speech",
        description="Drive a Markov random field over reference clips (Ju & Lee 2008) with the "
                    "intensity of a speech WAV file: the expression weights, the blinks, the "
                    "brows, the head motion and each detail group follow their own chains; a "
                    "TOML timeline paints styles (clip names) on time segments, per feature.")
    p.add_argument("speech", type=Path, help="driving speech .wav")
    p.add_argument("--palette", required=True, type=Path, nargs="+", metavar="CLIP",
                   help="reference clips: .npz ('gestures analyze') or performance .csv "
                        "(mouth opening stands in for speech); named by file stem")
    p.add_argument("-o", "--output", required=True, type=Path, help="output directory")
    p.add_argument("--timeline", type=Path, help="timeline TOML of styles")
    p.add_argument("--rate", type=float, default=30.0, metavar="HZ",
                   help="output frame rate (default 30)")
    p.add_argument("--window", type=float, default=0.05, metavar="S",
                   help="RMS window of the speech intensity (default 0.05)")
    p.add_argument("--history", type=int, default=10, help="frames matched, h (default 10)")
    p.add_argument("--alpha", type=float, default=1.0, help="weight of speech (default 1)")
    p.add_argument("--sigma", type=float, default=0.05, help="sigma of exp(-dist/sigma)")
    p.add_argument("--candidates", type=int, default=3, help="best candidates drawn from")
    p.add_argument("--run", type=int, default=1, dest="run_frames",
                   help="frames copied per pick (default 1)")
    p.add_argument("--blend", type=int, default=4, help="frames fading out a jump (default 4)")
    p.add_argument("--no-time-warps", action="store_true",
                   help="candidates are the continuation and frames at least --history from "
                        "it: no stalls, short replays or skips")
    p.add_argument("--one-chain", action="store_true",
                   help="blinks and brows in the chain of the other weights (default: their own)")
    p.add_argument("--seed", type=int, default=0)
    add_mesh(p, required=False, help="target neutral mesh")
    p.add_argument("--shapes", type=Path, help="target expression shapes (OBJ dir or glTF)")
    add_units(p)
    add_binding(p, required=False,
                help="binding .json of the reference capture to --mesh (head frame): places "
                     "the details and the head motion on the mesh")
    p.add_argument("--support", type=float, help="RBF support radius, mesh units")
    _add_intensity(p)
    lips = p.add_mutually_exclusive_group()
    _add_transcript(lips)
    lips.add_argument("--phones", type=Path, metavar="CSV",
                      help="phone segments (start,end,phone,confidence) instead of recognizing "
                           "them")
    lips.add_argument("--no-lips", action="store_true",
                      help="no phones, no visemes: the MRF alone moves the mouth")
    _add_recognizer(p)
    p.add_argument("--visemes", type=Path, metavar="DIR",
                   help="viseme shapes, one OBJ per class (a e i o u eu eo open closed "
                        "labiodental); default: combinations of the ARKit-style --shapes")
    p.add_argument("--video", action="store_true",
                   help="also talking.webm (VP9 + Opus: the face rendered with the speech as "
                        "its sound) and index.html showing it")
    p.add_argument("--video-size", type=int, nargs=2, default=(480, 480),
                   metavar=("W", "H"), help="video size in pixels (default 480 480)")
    p.set_defaults(run=run_synthesize)


def _add_intensity(p) -> None:
    p.add_argument("--intensity", choices=PROSODY_METHODS, default="auto",
                   help="loudness S(t) of a WAV: Praat's intensity (the 'speech' extra), the "
                        "RMS level, or 'auto' (default): Praat when installed, else RMS with a "
                        "warning")


def _add_transcript(group) -> None:
    group.add_argument("--transcript", metavar="TEXT|FILE",
                       help="the words spoken (or a text file of them): forced alignment")


def _add_recognizer(p) -> None:
    p.add_argument("--recognizer", choices=RECOGNIZERS, default="phones",
                   help="without a transcript: 'phones' (default) recognizes phones directly, "
                        "'words' recognizes words then aligns them (slower, fewer errors)")


def _add_phones(actions) -> None:
    p = actions.add_parser(
        "phones", help="phone segments of speech (PocketSphinx) as CSV",
        description="Recognize the phones of a speech WAV with PocketSphinx (its English "
                    "model ships in the wheel; the 'speech' extra), or align a transcript; "
                    "writes start,end,phone,confidence rows (s, s, ARPAbet, 0-1).")
    p.add_argument("speech", type=Path, help="speech .wav")
    _add_transcript(p)
    _add_recognizer(p)
    p.add_argument("-o", "--output", required=True, type=Path, help="phones .csv")
    p.set_defaults(run=run_phones)


def run_phones(args) -> int:
    from fit.gestures.phones import phones_from_wav, write_phones_csv
    from mocap.util.atomic import refuse_overwrite

    refuse_overwrite(args.output, [args.speech])
    segments = phones_from_wav(args.speech, transcript=args.transcript,
                               recognizer=args.recognizer)
    write_phones_csv(args.output, segments, inputs=[args.speech])
    return 0


def run_analyze(args) -> int:
    import mocap
    from basis.artist import load_artist_basis
    from fit.gestures import save_clip
    from fit.gestures.reference import clip_from_capture
    from mocap.bind import load_binding
    from mocap.clean.ingest import IngestOptions
    from mocap.markerset import load_markerset
    from mocap.util.atomic import refuse_overwrite

    if args.output.suffix.lower() != ".npz":
        raise InputError(f"{args.output}: a clip is written as .npz")
    inputs = [x for x in (args.capture, args.markerset, args.binding, args.mesh, args.shapes,
                          args.speech) if x is not None]
    refuse_overwrite(args.output, inputs)
    markerset = load_markerset(args.markerset)
    binding = load_binding(args.binding)
    basis = load_artist_basis(args.mesh, args.shapes, units=args.units)
    take = mocap.read(args.capture)
    options = IngestOptions(fill=args.fill, max_gap=args.max_gap, lowpass_hz=args.lowpass,
                            stabilize=args.stabilize, **stabilize_options(args))
    made = clip_from_capture(take, markerset, binding, basis, name=args.name or args.output.stem,
                             rate=args.rate, wav=args.speech, analog=args.analog,
                             opening=args.opening, intensity_window=args.intensity_window,
                             intensity=args.intensity,
                             options=options, neutral_frame=args.neutral_frame,
                             epsilon=args.epsilon, window=args.window,
                             estimator=args.estimator, seed=args.seed)
    save_clip(args.output, made.clip, inputs=inputs)
    return 0


def load_palette(paths, *, rate: float, shapes=None) -> list:
    """Clips from ``.npz`` files and performance ``.csv`` files, named by stem."""
    from fit.gestures import clip_from_performance, load_clip

    clips = []
    for path in paths:
        if path.suffix.lower() == ".csv":
            clips.append(clip_from_performance(read_performance(path), name=path.stem,
                                               rate=rate, shapes=shapes))
        elif path.suffix.lower() == ".npz":
            clips.append(_in_basis(load_clip(path), shapes))
        else:
            raise InputError(f"{path}: a palette clip is a .npz clip or a performance .csv")
    return clips


def _in_basis(clip, shapes):
    """The clip with its weights in the order of `shapes` (unchanged without shapes)."""
    if shapes is None or tuple(shapes) == clip.names:
        return clip
    absent = [s for s in clip.names if s not in shapes]
    if absent:
        raise InputError(f"clip {clip.name!r}: shapes {absent} are not in the target basis")
    weights = np.zeros((clip.n_frames, len(shapes)))
    weights[:, [list(shapes).index(s) for s in clip.names]] = clip.weights
    return dataclasses.replace(clip, weights=weights, names=tuple(shapes))


def run_synthesize(args) -> int:
    from basis.artist import load_artist_basis
    from fit.exports import write_weights_csv
    from fit.gestures import load_timeline, synthesize_gestures
    from fit.gestures.phones import write_phones_csv
    from fit.gestures.talking import analyze_speech, write_prosody_csv
    from fit.gestures.visemes import write_visemes_csv
    from mocap.bind import load_binding
    from mocap.util.atomic import atomic_path

    if (args.mesh is None) != (args.shapes is None):
        raise InputError("--mesh and --shapes go together")
    if args.binding is not None and args.mesh is None:
        raise InputError("--binding needs --mesh and --shapes")
    if (args.video or args.visemes is not None) and args.mesh is None:
        raise InputError("--video and --visemes need --mesh and --shapes")
    if args.visemes is not None and args.no_lips:
        raise InputError("--visemes and --no-lips contradict each other")
    if not args.output.is_dir():
        raise InputError(f"{args.output}: the output directory does not exist")
    basis = None if args.mesh is None else load_artist_basis(args.mesh, args.shapes,
                                                             units=args.units)
    binding = None if args.binding is None else load_binding(args.binding)
    visemes = None if basis is None or args.no_lips else _viseme_basis(basis, args)
    rate = args.rate
    clips = load_palette(args.palette, rate=rate,
                         shapes=None if basis is None else basis.names)
    timeline = None if args.timeline is None else load_timeline(args.timeline)
    speech = analyze_speech(args.speech, rate=rate, intensity=args.intensity,
                            window=args.window, lips=not args.no_lips,
                            transcript=args.transcript, recognizer=args.recognizer,
                            phones=args.phones)
    syn = synthesize_gestures(speech.prosody.intensity, clips, rate=rate, timeline=timeline,
                              history=args.history, alpha=args.alpha, sigma=args.sigma,
                              n_candidates=args.candidates, run=args.run_frames, blend=args.blend,
                              time_warps=not args.no_time_warps,
                              weight_groups={} if args.one_chain else None, seed=args.seed)
    inputs = [args.speech, *args.palette, args.timeline, args.mesh, args.binding, args.phones]
    inputs = [x for x in inputs if x is not None]
    out = args.output
    write_weights_csv(out / "weights.csv", syn.weights, syn.names, rate=rate, inputs=inputs)
    write_prosody_csv(out / "prosody.csv", speech.prosody, inputs=inputs)
    if speech.phones is not None:
        write_phones_csv(out / "phones.csv", speech.phones, inputs=inputs)
        write_visemes_csv(out / "visemes.csv", speech.visemes, inputs=inputs)
    if syn.head_rotation is not None:
        with atomic_path(out / "head.npz", inputs=inputs) as tmp, open(tmp, "wb") as fh:
            np.savez(fh, rotation=syn.head_rotation, translation=syn.head_translation,
                     rate=np.float64(rate))
    if syn.details:
        with atomic_path(out / "details.npz", inputs=inputs) as tmp, open(tmp, "wb") as fh:
            np.savez(fh, rate=np.float64(rate), **{f"details.{g}": v
                                                   for g, v in syn.details.items()},
                     **{f"labels.{g}": np.array(v, dtype=str)
                        for g, v in syn.detail_labels.items()})
    if basis is not None:
        _write_face(out, syn, basis, binding, speech, visemes, args, inputs=inputs)
    return 0


def _viseme_basis(basis, args):
    from fit.gestures.viseme_basis import load_viseme_basis, viseme_basis_from_shapes

    if args.visemes is not None:
        return load_viseme_basis(basis.neutral, args.visemes)
    return viseme_basis_from_shapes(basis)


def _write_face(out: Path, syn, basis, binding, speech, visemes, args, *, inputs) -> None:
    """``mesh.npz`` and ``gestures.glb``: the synthesis on the target face (lips from the
    visemes, details and head motion placed on it with a binding); with ``--video`` the
    talking video and its page."""
    from basis.gltf import write_gltf
    from fit.exports import write_mesh_sequence
    from fit.gestures.lipsync import talking_face
    from fit.gestures.transfer import build_detail_transfer, head_motion_on_mesh

    extra = dict(extra=None, extra_names=(), extra_weights=None)
    if binding is not None and syn.details:
        transfer = build_detail_transfer(binding, basis.neutral, syn.detail_labels,
                                         support=args.support)
        fields, names = transfer.shapes()
        extra = dict(extra=fields, extra_names=names, extra_weights=transfer.weights(syn.details))
    if visemes is not None:
        face = talking_face(basis, syn.weights, visemes, speech.visemes, **extra)
        fields, names, weights = face.displacements, face.names, face.weights
    else:
        fields, names, weights = basis.displacements, basis.names, syn.weights
        if extra["extra"] is not None:
            fields = np.concatenate([fields, extra["extra"]])
            names = names + tuple(extra["extra_names"])
            weights = np.concatenate([weights, extra["extra_weights"]], axis=1)
    motion = {}
    if syn.head_rotation is not None and binding is None:
        warnings.warn("the head motion is in head.npz only: --binding places it on the mesh "
                      "(gestures.glb)", stacklevel=3)
    elif syn.head_rotation is not None:
        rotation, translation = head_motion_on_mesh(binding, syn.head_rotation,
                                                    syn.head_translation)
        motion = {"rotation": rotation, "translation": translation}
    # frame numbers from 1, as weights.csv
    write_mesh_sequence(out / "mesh.npz", basis.neutral, fields, weights, names=names,
                        rate=syn.rate, first_frame=1, inputs=inputs, **motion)
    write_gltf(out / "gestures.glb", basis.neutral, fields, names, weights=weights,
               rate=syn.rate, first_frame=1, inputs=inputs, **motion)
    if args.video:
        _write_video(out, basis.neutral, fields, weights, motion, speech, syn, args,
                     inputs=inputs)


def _write_video(out, neutral, fields, weights, motion, speech, syn, args, *, inputs):
    from fit.gestures.page import write_speech_figure, write_synthesis_page
    from fit.gestures.video import write_talking_video

    write_talking_video(out / "talking.webm", neutral, fields, weights, rate=syn.rate,
                        audio=args.speech,
                        size=tuple(args.video_size), inputs=inputs, **motion)
    write_speech_figure(out / "speech.png", speech)
    files = [f for f in ("weights.csv", "prosody.csv", "phones.csv", "visemes.csv", "head.npz",
                         "details.npz", "mesh.npz", "gestures.glb") if (out / f).exists()]
    write_synthesis_page(out, speech_name=args.speech.name,
                         summary=[speech.message, syn.message], video="talking.webm",
                         figure="speech.png", files=files, inputs=inputs)
