"""The demo session: everything the chain needs, generated from nothing into one directory.

Files written by :func:`make_demo_session`:

==================  ============================================================
``neutral.obj``     the face (:mod:`fit.demo.face`), mm (``# units: mm``)
``shapes/``         the 18 muscle shapes (:func:`basis.basis_io.save_basis`:
                    ``neutral.obj``, one OBJ per shape, ``basis.json``)
``landmarks.toml``  mesh landmarks (:func:`mocap.mesh.landmarks.load_mesh_landmarks`)
``layout.toml``     markers on the mesh (:func:`mocap.mesh.layout.load_marker_layout`)
``markerset.toml``  head markers, regions, landmarks (:func:`mocap.markerset.load_markerset`)
``capture.c3d``     the simulated capture: head motion, noise, gaps (:func:`mocap.io.read`)
``truth.npz``       ground truth (keys below)
==================  ============================================================

``truth.npz`` keys: ``shape_names`` (18), ``weights`` (T, 18) muscle
activations, ``hidden_names`` (3) and ``hidden_weights`` (T, 3) of the
deformations outside the basis (blinks, cheek puff), ``truth_shape_names``
(22) and ``truth_weights`` (T, 22) that reproduce the true face linearly
(:func:`fit.demo.performance.truth_basis`), ``rotation`` (T, 3, 3) and
``translation`` (T, 3) mm (world = R @ head + t), ``markers_world`` and
``markers_head`` (T, M, 3) mm before noise and gaps, ``missing`` (T, M),
``labels`` (M), ``head_markers``, ``rate`` (Hz), ``seed``, ``noise_mm``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

import mocap
from basis.artist import ArtistBasis
from basis.basis_io import save_basis
from fit.demo.face import FaceModel, make_face
from fit.demo.markers import HEAD_MARKERS, demo_layout, landmarks_toml, markerset_toml
from fit.demo.muscles import muscle_basis
from fit.demo.performance import (
    HIDDEN,
    TRUTH_SHAPES,
    DemoPerformance,
    make_performance,
    truth_basis,
)
from mocap.mesh.layout import MarkerLayout, save_marker_layout
from mocap.mesh.mesh import save_obj
from mocap.synth.capture import SimulatedCapture, simulate_capture
from mocap.synth.performance import Performance
from mocap.util.atomic import atomic_path
from mocap.util.validation import as_int, as_positive_float

__all__ = ["DemoSession", "make_demo_session", "SESSION_FILES"]

#: Files (and the shapes directory) of a session, by key of :attr:`DemoSession.paths`.
SESSION_FILES = {"neutral": "neutral.obj", "shapes": "shapes", "landmarks": "landmarks.toml",
                 "layout": "layout.toml", "markerset": "markerset.toml",
                 "capture": "capture.c3d", "truth": "truth.npz"}


@dataclass(frozen=True, eq=False)
class DemoSession:
    """A generated demo session: its files and the arrays they hold.

    Attributes
    ----------
    paths : dict of str to Path
        The written files by key of :data:`SESSION_FILES`.
    face : FaceModel
        The neutral mesh (mm) and its landmarks.
    basis : ArtistBasis
        The 18 muscle shapes (mm).
    truth_basis : ArtistBasis
        The muscle shapes and the hidden shapes (22); the true face of frame t
        is ``truth_basis.evaluate(performance.truth_weights()[t])``.
    performance : DemoPerformance
        Muscle and hidden activations, at the capture's rate.
    layout : MarkerLayout
        65 markers on the face (mm, 2 mm off the skin), head markers first.
    head_markers : tuple of str
    capture : SimulatedCapture
        ``take`` as written to ``capture.c3d`` (mm, world frame, NaN gaps) and
        ``truth`` (head motion, true markers, occlusion mask).
    """

    paths: dict
    face: FaceModel
    basis: ArtistBasis
    truth_basis: ArtistBasis
    performance: DemoPerformance
    layout: MarkerLayout
    head_markers: tuple
    capture: SimulatedCapture


def make_demo_session(out_dir, *, seed: int = 7, seconds: float = 20.0, rate: float = 120.0,
                      noise_mm: float = 0.2, n_gaps: int = 60) -> DemoSession:
    """Generate the demo session and write it into `out_dir`.

    Parameters
    ----------
    out_dir : str or os.PathLike
        Directory to write into (created if needed; the session's files in
        it are replaced).
    seed : int, default 7
        Seed of the performance, the head motion, the noise and the gaps.
    seconds : float, default 20, s
    rate : float, default 120, Hz
    noise_mm : float, default 0.2
        Standard deviation of the marker noise per coordinate, mm.
    n_gaps : int, default 60
        Occlusion gaps in the capture.

    Returns
    -------
    DemoSession

    Raises
    ------
    InputError
        A negative seed or gap count, a non-positive duration or rate.
    """
    seed = as_int(seed, "seed", minimum=0)
    seconds = as_positive_float(seconds, "seconds")
    rate = as_positive_float(rate, "rate")
    n_gaps = as_int(n_gaps, "n_gaps", minimum=0)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {key: out / name for key, name in SESSION_FILES.items()}

    face = make_face()
    basis = muscle_basis(face)
    truth = truth_basis(face, basis)
    performance = make_performance(seconds=seconds, rate=rate, seed=seed)
    layout = demo_layout(face)
    weights = performance.truth_weights()
    capture = simulate_capture(
        truth, Performance(TRUTH_SHAPES, performance.times, weights, rate), layout,
        tuple(HEAD_MARKERS), rate=rate, noise_mm=noise_mm, n_gaps=n_gaps, seed=seed)

    save_obj(face.mesh, paths["neutral"])
    save_basis(basis, paths["shapes"])
    _write_text(paths["landmarks"], landmarks_toml(face))
    save_marker_layout(layout, paths["layout"], description="mocap2mesh demo layout: 5 head "
                       "markers (upper forehead, temples), 60 face markers, 2 mm off the skin")
    _write_text(paths["markerset"], markerset_toml())
    mocap.write(capture.take, paths["capture"])
    _save_truth(paths["truth"], performance, weights, capture, seed, noise_mm)
    return DemoSession(paths=paths, face=face, basis=basis, truth_basis=truth,
                       performance=performance, layout=layout,
                       head_markers=tuple(HEAD_MARKERS), capture=capture)


def _write_text(path: Path, text: str) -> None:
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")


def _save_truth(path, performance, weights, capture, seed, noise_mm) -> None:
    truth = capture.truth
    arrays = {"shape_names": np.array(TRUTH_SHAPES[:performance.activations.shape[1]]),
              "weights": performance.activations,
              "hidden_names": np.array(HIDDEN[1:]), "hidden_weights": performance.hidden,
              "truth_shape_names": np.array(TRUTH_SHAPES), "truth_weights": weights,
              "rotation": truth.rotation, "translation": truth.translation,
              "markers_world": truth.markers_world, "markers_head": truth.markers_head,
              "missing": truth.missing, "labels": np.array(truth.labels),
              "head_markers": np.array(truth.head_markers), "rate": np.float64(truth.rate),
              "seed": np.int64(seed), "noise_mm": np.float64(noise_mm)}
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **arrays)
