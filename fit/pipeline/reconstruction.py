"""The scripting entry point: a capture through the whole chain in one call.

A :class:`Reconstruction` holds what every take of a face needs (the marker
set, the neutral mesh, its landmarks, the artist basis) and the options of
each stage, built from keyword arguments or from a ``run.toml``
(:meth:`Reconstruction.from_config`); :meth:`Reconstruction.process` runs one
capture through ingest → bind → retarget → bases → fit and returns a
:class:`ReconstructionResult`: weights per basis as DataFrames indexed by the
capture's frame numbers, errors, the binding, mesh sequences evaluated on
demand, and :meth:`~ReconstructionResult.save` /
:meth:`~ReconstructionResult.report` for the files ``mocap2mesh run`` writes::

    recon = Reconstruction.from_config("run.toml")
    result = recon.process("take1.c3d")
    result.weights["H"].loc[120, "jawOpen"]     # frame 120 of the capture
    result.save("out/take1")

The README's Python section is a complete script (run as a test).
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

import mocap
from basis.artist import ArtistBasis
from basis.basis_io import load_any_basis, save_basis
from basis.gltf import write_gltf
from fit.exports import MeshSequence, weights_frame, write_mesh_sequence, write_weights_csv
from fit.metrics import reconstruction_errors
from fit.pipeline.config import STAGE_TABLES, RunConfig, load_run_config, stage_options
from fit.pipeline.options import BasisOptions, BindOptions, FitOptions, ReportOptions
from fit.pipeline.stages import (
    BasisResult,
    FitResult,
    basis_stage,
    bind_stage,
    complete_span,
    fit_stage,
    ingest_stage,
    lip_seal_stage,
    retarget_stage,
)
from fit.report import build_report
from fit.report.ingest_plots import plot_gaps, plot_head_residuals
from mocap.bind import Binding, BoundTake
from mocap.clean.ingest import IngestOptions, IngestResult, save_head_motion
from mocap.errors import InputError
from mocap.markerset import MarkerSet, load_markerset
from mocap.mesh import Mesh, load_mesh
from mocap.mesh.landmarks import load_mesh_landmarks
from mocap.retarget.lip_seal import LipSealCheck
from mocap.retarget.retargeting import Retargeting, RetargetOptions
from mocap.take import Take

__all__ = ["Reconstruction", "ReconstructionResult"]


def _options(name: str, value):
    """A stage's options from its dataclass, a mapping of its keys, or None (defaults)."""
    cls = STAGE_TABLES[name]
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    if isinstance(value, dict):
        return stage_options(name, value, where="options")
    raise InputError(f"{name} options must be a {cls.__name__} or a dict of its keys, got "
                     f"{type(value).__name__}")


@dataclass(frozen=True, eq=False)
class Reconstruction:
    """The whole chain for the takes of one face, with the options of every stage.

    Parameters
    ----------
    markerset : MarkerSet or path
        Head markers, regions and landmark markers of the captures.
    mesh : Mesh or path
        The neutral face mesh (its own units; `mesh_units` when the file does
        not say).
    landmarks : mapping of str to int, or path
        The mesh landmarks (anatomical point -> vertex id).
    basis : ArtistBasis or path
        The artist basis on the mesh's topology
        (:func:`basis.basis_io.load_any_basis`).
    mesh_units : str, optional
        Units of the mesh file, when it is given as a path.
    ingest, bind, retarget, basis_options, fit, report
        Each stage's options: its dataclass (:class:`IngestOptions`,
        :class:`BindOptions`, :class:`RetargetOptions`, :class:`BasisOptions`,
        :class:`FitOptions`, :class:`ReportOptions`) or a dict of the keys of
        its ``run.toml`` table; default the defaults.

    Examples
    --------
    From files, with one option changed::

        Reconstruction(markerset="markerset.toml", mesh="neutral.obj",
                       landmarks="landmarks.toml", basis="shapes/",
                       fit={"smoothness": "gcv"})
    """

    markerset: MarkerSet
    mesh: Mesh
    landmarks: dict
    basis: ArtistBasis
    mesh_units: str | None = None
    ingest: IngestOptions = IngestOptions()
    bind: BindOptions = BindOptions()
    retarget: RetargetOptions = RetargetOptions()
    basis_options: BasisOptions = BasisOptions()
    fit: FitOptions = FitOptions()
    report: ReportOptions = ReportOptions()

    def __post_init__(self):
        fields = {"markerset": self.markerset, "mesh": self.mesh}
        if not isinstance(self.markerset, MarkerSet):
            fields["markerset"] = load_markerset(self.markerset)
        if not isinstance(self.mesh, Mesh):
            fields["mesh"] = load_mesh(self.mesh, units=self.mesh_units)
        mesh = fields["mesh"]
        fields["landmarks"] = load_mesh_landmarks(self.landmarks, mesh) \
            if isinstance(self.landmarks, (str, Path)) else dict(self.landmarks)
        if not isinstance(self.basis, ArtistBasis):
            fields["basis"] = load_any_basis(self.basis, mesh)
        elif self.basis.neutral.n_vertices != mesh.n_vertices:
            raise InputError(f"the basis has {self.basis.neutral.n_vertices} vertices, the "
                             f"mesh {mesh.n_vertices}: they must share a topology")
        for name in STAGE_TABLES:
            attr = "basis_options" if name == "basis" else name
            fields[attr] = _options(name, getattr(self, attr))
        for attr, value in fields.items():
            object.__setattr__(self, attr, value)

    @classmethod
    def from_config(cls, config) -> "Reconstruction":
        """The reconstruction a run configuration describes (a path or a :class:`RunConfig`)."""
        if not isinstance(config, RunConfig):
            config = load_run_config(config)
        return cls(markerset=config.markerset, mesh=config.mesh, landmarks=config.landmarks,
                   basis=config.basis, mesh_units=config.mesh_units, ingest=config.ingest,
                   bind=config.bind, retarget=config.retarget,
                   basis_options=config.basis_options, fit=config.fit, report=config.report)

    def process(self, capture) -> "ReconstructionResult":
        """Run one capture through the chain.

        Parameters
        ----------
        capture : path or Take
            A capture file (C3D, Vicon CSV, TRC, take ``.npz``) or a take read already.

        Returns
        -------
        ReconstructionResult

        Raises
        ------
        Mocap2MeshError
            Any stage's error, naming the file, marker or frame at fault.

        Warns
        -----
        UserWarning
            A mesh whose mouth stays shut while the lip markers open it (or
            the reverse), naming the capture's frames
            (:attr:`ReconstructionResult.lip_seal`).
        """
        seconds = {}
        tic = time.perf_counter()
        raw = capture if isinstance(capture, Take) else mocap.read(capture)
        ingested = ingest_stage(raw, self.markerset, self.ingest)
        take = complete_span(ingested.take, self.markerset.face_markers)
        seconds["ingest"] = time.perf_counter() - tic
        tic = time.perf_counter()
        bound = bind_stage(take, self.markerset, self.mesh, self.landmarks, options=self.bind)
        seconds["bind"] = time.perf_counter() - tic
        tic = time.perf_counter()
        retargeted = retarget_stage(take, bound, self.mesh, self.markerset, self.retarget,
                                    mesh_landmarks=self.landmarks)
        seconds["retarget"] = time.perf_counter() - tic
        tic = time.perf_counter()
        bases = basis_stage(retargeted, self.basis, options=self.basis_options)
        seconds["basis"] = time.perf_counter() - tic
        tic = time.perf_counter()
        fitted = fit_stage(take, bound, retargeted, bases, options=self.fit)
        seconds["fit"] = time.perf_counter() - tic
        lips = lip_seal_stage(take, bound, retargeted, bases, fitted)
        for message in (lips.messages() if lips is not None else ()):
            warnings.warn(f"{raw.source.path or 'the take'}: {message}", stacklevel=2)
        source = raw.source.path
        name = Path(source).stem if source else "take"
        return ReconstructionResult(reconstruction=self, name=name, ingested=ingested,
                                    take=take, bound=bound, retargeted=retargeted,
                                    bases=bases, fitted=fitted, stage_seconds=seconds,
                                    lip_seal=lips)


@dataclass(frozen=True, eq=False)
class ReconstructionResult:
    """One capture reconstructed: every stage's result, and its outputs on demand.

    Attributes
    ----------
    reconstruction : Reconstruction
        What made it.
    name : str
        The capture's file stem (file names and titles).
    ingested : IngestResult
    take : Take
        Head-stabilized, cut to the frames where every face marker is present.
    bound : BoundTake
    retargeted : Retargeting
    bases : BasisResult
    fitted : FitResult
    stage_seconds : dict of str to float
        Wall time of each stage.
    lip_seal : mocap.retarget.lip_seal.LipSealCheck or None
        The lip gap of W·D and of each basis's mesh against the lip markers'.
    """

    reconstruction: Reconstruction
    name: str
    ingested: IngestResult
    take: Take
    bound: BoundTake
    retargeted: Retargeting
    bases: BasisResult
    fitted: FitResult
    stage_seconds: dict
    lip_seal: LipSealCheck | None = None

    @property
    def binding(self) -> Binding:
        """The face markers bound to the mesh."""
        return self.bound.binding

    @property
    def face(self) -> Take:
        """The take's face markers (the ones reconstructed), head frame, mm."""
        return self.take.select(self.retargeted.labels)

    @cached_property
    def weights(self) -> dict:
        """Weights per basis: DataFrames indexed by the capture's frame numbers.

        Columns ``time`` (s from the first frame) then one per shape (fixed
        shapes, such as the PCA mean, included at weight 1).
        """
        return {name: weights_frame(self.fitted.weights[name], basis.names,
                                    rate=self.take.rate, first_frame=self.take.first_frame)
                for name, basis in self.bases.bases.items()}

    @cached_property
    def errors(self) -> dict:
        """:class:`fit.metrics.ReconstructionErrors` per basis, at the face markers."""
        face = self.face
        neutral = self.bound.neutral_pose(face.positions)
        return {name: reconstruction_errors(face.positions, rec, neutral, labels=face.labels,
                                            name=name)
                for name, rec in self.fitted.reconstructed.items()}

    def meshes(self, basis: str) -> MeshSequence:
        """The mesh sequence of one basis, evaluated frame by frame on demand.

        ``meshes("H").vertices(t)`` is frame t's vertices (N, 3), mesh units;
        ``vertices()`` all of them (T, N, 3).
        """
        if basis not in self.bases.bases:
            raise InputError(f"no basis {basis!r}; the bases are {', '.join(self.bases.bases)}")
        named = self.bases.bases[basis]
        mesh = self.reconstruction.mesh
        return MeshSequence(faces=mesh.faces, neutral=mesh.vertices,
                            displacements=named.displacements,
                            weights=np.array(self.fitted.weights[basis]), materialized=None,
                            names=named.names, units=mesh.units, rate=self.take.rate,
                            first_frame=self.take.first_frame)

    def save(self, directory, *, inputs=()) -> list:
        """Write the take's exports into `directory` (created); returns the paths.

        ``take.c3d`` (cleaned, head-stabilized), ``head_motion.npz``,
        ``binding.json``, and per basis B: ``basis-B.npz``, ``weights-B.csv``,
        ``mesh-B.npz`` (compact sequence), ``face-B.glb`` (morph targets, weight
        animation at the take's rate). Every file atomically; none over one of
        `inputs`.
        """
        out = Path(directory)
        out.mkdir(parents=True, exist_ok=True)
        mesh, take = self.reconstruction.mesh, self.take
        files = [out / "take.c3d", out / "head_motion.npz", out / "binding.json"]
        mocap.write(take, files[0], inputs=inputs)
        save_head_motion(self.ingested.stabilization, files[1], inputs=inputs)
        self.binding.save(files[2])
        timing = dict(rate=take.rate, first_frame=take.first_frame)
        for name, basis in self.bases.bases.items():
            weights = self.fitted.weights[name]
            paths = [out / f"basis-{name}.npz", out / f"weights-{name}.csv",
                     out / f"mesh-{name}.npz", out / f"face-{name}.glb"]
            save_basis(ArtistBasis(basis.names, mesh, basis.displacements), paths[0],
                       dtype="float32", inputs=inputs)
            write_weights_csv(paths[1], weights, basis.names, inputs=inputs, **timing)
            write_mesh_sequence(paths[2], mesh, basis.displacements, weights,
                                names=basis.names, inputs=inputs, **timing)
            write_gltf(paths[3], mesh, basis.displacements, basis.names, weights=weights,
                       rate=take.rate, name=f"{self.name}-{name}", inputs=inputs)
            files += paths
        return files

    def report(self, directory) -> list:
        """Write the QA pictures, videos and ``<name>.html`` into `directory`; returns the paths."""
        qa = Path(directory)
        qa.mkdir(parents=True, exist_ok=True)
        options = self.reconstruction.report
        face = self.face
        plot_gaps(self.ingested.cleaned, qa / "gaps.png")
        plot_head_residuals(self.ingested.stabilization, qa / "head_residuals.png")
        files = [qa / "gaps.png", qa / "head_residuals.png"]
        files += build_report(face, self.fitted.reconstructed, self.bound.neutral_pose(face.positions),
                              qa, markerset=self.reconstruction.markerset, pca=self.bases.pca,
                              ingest=self.ingested, video=options.video,
                              pictures={"gaps: present, missing, filled by method": files[0],
                                        "head-marker residuals": files[1]},
                              video_step=options.video_step, n_worst=options.n_worst,
                              exaggerate=options.exaggerate, name=self.name,
                              cross_validation=self.retargeted.cross_validation,
                              selection=self.retargeted.selection,
                              lip_seal=self.lip_seal).values()
        return files

    def _retarget_summary(self) -> dict:
        """The retargeting variant used, its held-out errors and what ``"auto"`` tried."""
        retargeted = self.retargeted
        options = retargeted.options
        cv = retargeted.cross_validation
        return {"kernel": options.kernel, "epsilon": options.epsilon, "degree": options.degree,
                "distance": options.distance, "use_regions": options.use_regions,
                "cross_validation": None if cv is None else cv.summary(),
                "selection": None if retargeted.selection is None
                else retargeted.selection.to_dict()}

    def summary(self) -> dict:
        """What the manifest records of the take: frames, binding, retargeting, lips, bases, fit and metrics."""
        take, ingested = self.take, self.ingested

        def finite(summary: dict) -> dict:
            return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                    for k, v in summary.items()}
        return {"frames": {"first": take.first_frame, "count": take.n_frames,
                           "trimmed": ingested.take.n_frames - take.n_frames,
                           "neutral": take.first_frame + self.bound.frame,
                           "neutral_window": self.bound.window, "rate": take.rate},
                "binding_rms_mm": self.binding.rms,
                "retarget": self._retarget_summary(),
                "lip_seal": None if self.lip_seal is None else self.lip_seal.summary(),
                "pca_components": self.bases.n_components,
                "qe_missing_axes": self.bases.qe.missing_axes.tolist(),
                "fit": {name: {"status": s.status, "message": s.message}
                        for name, s in self.fitted.solutions.items()},
                "metrics": {name: finite(errors.summary()
                                         | {"smoothness": self.fitted.solutions[name].smoothness})
                            for name, errors in self.errors.items()}}
