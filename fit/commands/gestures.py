"""``mocap2mesh gestures SPEECH --palette CLIP... -o DIR``: speech-driven facial gestures.

Writes into DIR: ``weights.csv`` (c̃(t)), ``head.npz`` (R̃, T̃, if the palette
has head motion), ``details.npz`` (D̃_j in mm, if it has details), and with
``--mesh``/``--shapes`` the animated face ``mesh.npz`` (neutral + basis +
weights, the details transferred by compact RBFs when ``--binding`` is given)
and ``gestures.glb`` (morph-target animation).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mocap.errors import InputError
from mocap.performance import read_performance

__all__ = ["add_parser", "run", "load_palette"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "gestures", help="synthesize facial gestures (weights, head motion, details) from speech",
        description="Drive a Markov random field over reference clips (Ju & Lee 2008) with the "
                    "intensity of a speech WAV file; a TOML timeline paints styles (clip names) "
                    "on time segments, per feature.")
    p.add_argument("speech", type=Path, help="driving speech .wav")
    p.add_argument("--palette", required=True, type=Path, nargs="+", metavar="CLIP",
                   help="reference clips: .npz (fit.gestures.save_clip) or performance .csv "
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
    p.add_argument("--blend", type=int, default=0, help="frames fading out a jump (default 0)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--mesh", type=Path, help="target neutral mesh")
    p.add_argument("--shapes", type=Path, help="target expression shapes (OBJ dir or glTF)")
    p.add_argument("--units", help="units of the mesh (e.g. cm)")
    p.add_argument("--binding", type=Path, help="binding .json of the detail markers to --mesh")
    p.add_argument("--support", type=float, help="RBF support radius, mesh units")
    p.set_defaults(run=run)


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
    from fit.gestures import GestureClip

    absent = [s for s in clip.names if s not in shapes]
    if absent:
        raise InputError(f"clip {clip.name!r}: shapes {absent} are not in the target basis")
    weights = np.zeros((clip.n_frames, len(shapes)))
    weights[:, [list(shapes).index(s) for s in clip.names]] = clip.weights
    return GestureClip(clip.name, clip.rate, clip.intensity, weights, tuple(shapes),
                       head=clip.head, details=clip.details, detail_labels=clip.detail_labels)


def run(args) -> int:
    from basis.artist import load_artist_basis
    from basis.gltf import write_gltf
    from fit.exports import write_mesh_sequence, write_weights_csv
    from fit.gestures import load_timeline, synthesize_gestures, wav_intensity
    from fit.gestures.transfer import build_detail_transfer
    from mocap._atomic import atomic_path
    from mocap.bind import load_binding

    if (args.mesh is None) != (args.shapes is None):
        raise InputError("--mesh and --shapes go together")
    if args.binding is not None and args.mesh is None:
        raise InputError("--binding needs --mesh and --shapes")
    if not args.output.is_dir():
        raise InputError(f"{args.output}: the output directory does not exist")
    basis = None if args.mesh is None else load_artist_basis(args.mesh, args.shapes,
                                                             units=args.units)
    rate = args.rate
    clips = load_palette(args.palette, rate=rate,
                         shapes=None if basis is None else basis.names)
    timeline = None if args.timeline is None else load_timeline(args.timeline)
    intensity = wav_intensity(args.speech, frame_rate=rate, window=args.window)
    syn = synthesize_gestures(intensity, clips, rate=rate, timeline=timeline,
                              history=args.history, alpha=args.alpha, sigma=args.sigma,
                              n_candidates=args.candidates, run=args.run_frames, blend=args.blend,
                              seed=args.seed)
    inputs = [args.speech, *args.palette, args.timeline, args.mesh, args.binding]
    inputs = [x for x in inputs if x is not None]
    out = args.output
    write_weights_csv(out / "weights.csv", syn.weights, syn.names, rate=rate, inputs=inputs)
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
    if basis is None:
        return 0
    fields, names, weights = basis.displacements, basis.names, syn.weights
    if args.binding is not None and syn.details:
        transfer = build_detail_transfer(load_binding(args.binding), basis.neutral,
                                         syn.detail_labels, support=args.support)
        extra, extra_names = transfer.shapes()
        fields = np.concatenate([fields, extra])
        names = names + extra_names
        weights = np.concatenate([weights, transfer.weights(syn.details)], axis=1)
    write_mesh_sequence(out / "mesh.npz", basis.neutral, fields, weights, names=names,
                        rate=rate, inputs=inputs)
    write_gltf(out / "gestures.glb", basis.neutral, fields, names, weights=weights, rate=rate,
               inputs=inputs)
    return 0
