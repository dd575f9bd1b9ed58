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
from functools import cached_property, partial
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

import mocap
from basis.artist import ArtistBasis
from basis.basis_io import load_any_basis, save_basis
from basis.gltf import write_gltf
from fit.exports import MeshSequence, weights_frame, write_mesh_sequence, write_weights_csv
from fit.gestures.transfer import head_motion_on_mesh
from fit.metrics import reconstruction_errors
from fit.pipeline.config import STAGE_TABLES, RunConfig, load_run_config, stage_options
from fit.pipeline.gaps import require_complete
from fit.pipeline.holdout import HeldOut, held_out_fits, time_blocked_splits
from fit.pipeline.options import BasisOptions, BindOptions, FitOptions, ReportOptions
from fit.pipeline.provenance import stage_grades, take_provenance
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
from fit.pipeline.take_warnings import recorded_warnings, warn_unconverged
from fit.report import build_report
from fit.report.figure_queue import FigureQueue
from fit.report.html import Figure
from fit.report.ingest_plots import GapChart, HeadResiduals, plot_gaps, plot_head_residuals
from fit.report.mesh_views import MeshSpace
from mocap.bind import Binding, BoundTake
from mocap.clean.ingest import IngestOptions, IngestResult, save_head_motion
from mocap.errors import InputError
from mocap.markerset import MarkerSet, load_markerset
from mocap.mesh import Mesh, load_mesh
from mocap.mesh.landmarks import load_mesh_landmarks
from mocap.retarget.lip_seal import LipSealCheck
from mocap.retarget.retargeting import Retargeting, RetargetOptions
from mocap.take import Take
from mocap.units import mm_per_unit
from mocap.util.blas import TasksBeside
from mocap.util.float_text import compiled_lines_ready
from mocap.util.order_statistics import nan_column_medians

__all__ = ["Reconstruction", "SharedReconstruction", "PreparedTake", "ReconstructionResult"]


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
        for name in STAGE_TABLES:           # options first: a wrong one costs no loading
            attr = "basis_options" if name == "basis" else name
            fields[attr] = _options(name, getattr(self, attr))
        markerset = fields["markerset"]
        if (fields["ingest"].stabilize or "head") == "head" and not markerset.head:
            raise InputError(f"ingest.stabilize = 'head', but marker set {markerset.name!r} "
                             "names no head markers: set ingest.stabilize = 'auto' "
                             "(stabilization markers found among the face markers) or 'none' "
                             "(the takes are in the head frame already)")
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

    def prepare(self, capture) -> "PreparedTake":
        """Run one capture through ingest, bind and retarget (the stages before the bases).

        Parameters
        ----------
        capture : path or Take
            A capture file (C3D, Vicon CSV, TRC, take ``.npz``) or a take read already.

        Returns
        -------
        PreparedTake

        Raises
        ------
        Mocap2MeshError
            Any stage's error, naming the file, marker or frame at fault (a
            face marker left with gaps by ingestion: :func:`fit.pipeline.gaps.require_complete`).
        """
        seconds = {}
        tic = time.perf_counter()
        raw = capture if isinstance(capture, Take) else mocap.read(capture)
        ingested = ingest_stage(raw, self.markerset, self.ingest)
        take = complete_span(ingested.take, self.markerset.face_markers)
        require_complete(take, self.markerset.face_markers, ingested.fill)
        seconds["ingest"] = time.perf_counter() - tic
        tic = time.perf_counter()
        bound = bind_stage(take, self.markerset, self.mesh, self.landmarks, options=self.bind)
        seconds["bind"] = time.perf_counter() - tic
        tic = time.perf_counter()
        retargeted = retarget_stage(take, bound, self.mesh, self.markerset, self.retarget,
                                    mesh_landmarks=self.landmarks)
        seconds["retarget"] = time.perf_counter() - tic
        source = raw.source.path
        return PreparedTake(name=Path(source).stem if source else "take", ingested=ingested,
                            take=take, bound=bound, retargeted=retargeted,
                            stage_seconds=seconds)

    def process(self, capture, *, session_basis=None) -> "ReconstructionResult":
        """Run one capture through the chain.

        Parameters
        ----------
        capture : path, Take or PreparedTake
            A capture file (C3D, Vicon CSV, TRC, take ``.npz``), a take read
            already, or a take through :meth:`prepare`.
        session_basis : fit.pipeline.session_basis.SessionBasis, optional
            The PCA shared by the takes of a session (``[basis] scope =
            "session"``); its PCA and quasi-eigen bases replace the take's own.
            Default: the take's own PCA.

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
            The stages' own (gap filling, binding distances) and a basis whose
            weights did not converge in every frame.
            A mesh whose mouth stays shut while the lip markers open it (or
            the reverse), naming the capture's frames
            (:attr:`ReconstructionResult.lip_seal`).
        """
        prepared = capture if isinstance(capture, PreparedTake) else self.prepare(capture)
        seconds = dict(prepared.stage_seconds)
        tic = time.perf_counter()
        bases = basis_stage(prepared.retargeted, self.basis, options=self.basis_options,
                            pca=None if session_basis is None else session_basis.pca)
        seconds["basis"] = time.perf_counter() - tic
        tic = time.perf_counter()
        fitted = fit_stage(prepared.take, prepared.bound, prepared.retargeted, bases,
                           options=self.fit)
        warn_unconverged(fitted.solutions, first_frame=prepared.take.first_frame)
        seconds["fit"] = time.perf_counter() - tic
        tic = time.perf_counter()
        lips = lip_seal_stage(prepared.take, prepared.bound, prepared.retargeted, bases, fitted)
        seconds["lip seal"] = time.perf_counter() - tic
        for message in (lips.messages() if lips is not None else ()):
            warnings.warn(f"{prepared.ingested.raw.source.path or prepared.name}: {message}",
                          stacklevel=2)
        return ReconstructionResult(reconstruction=self, name=prepared.name,
                                    ingested=prepared.ingested, take=prepared.take,
                                    bound=prepared.bound, retargeted=prepared.retargeted,
                                    bases=bases, fitted=fitted, stage_seconds=seconds,
                                    session_basis=session_basis, lip_seal=lips)


@dataclass(frozen=True, eq=False)
class SharedReconstruction:
    """A run's :class:`Reconstruction`, built once for all its takes, and the warnings its
    building raised (the shared inputs': each take raises them again, as when it built
    its own). Its mesh and basis are read and checked once: about 0.6 s a take for the ICT
    face and its 53 shapes, against 13 MB sent to each worker.

    Attributes
    ----------
    reconstruction : Reconstruction
    warnings : tuple of (str, type)
        Message and category, in the order raised.
    """

    reconstruction: Reconstruction
    warnings: tuple

    @classmethod
    def build(cls, config) -> "SharedReconstruction":
        """:meth:`Reconstruction.from_config` of `config`, with its warnings.

        Raises
        ------
        Mocap2MeshError
            As :meth:`Reconstruction.from_config`.
        """
        with recorded_warnings() as caught:
            reconstruction = Reconstruction.from_config(config)
        return cls(reconstruction, tuple(caught))


@dataclass(frozen=True, eq=False)
class PreparedTake:
    """One capture through the stages before the bases (:meth:`Reconstruction.prepare`).

    Attributes
    ----------
    name : str
        The capture's file stem.
    ingested : IngestResult
    take : Take
        Head-stabilized, cut to the frames where every face marker is present.
    bound : BoundTake
    retargeted : Retargeting
        The take's operator W and marker displacements D (mesh units).
    stage_seconds : dict of str to float
    """

    name: str
    ingested: IngestResult
    take: Take
    bound: BoundTake
    retargeted: Retargeting
    stage_seconds: dict


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
    session_basis : SessionBasis or None
        The session's shared PCA the take was fitted in (None: its own).
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
    session_basis: object = None
    lip_seal: LipSealCheck | None = None

    @property
    def binding(self) -> Binding:
        """The face markers bound to the mesh."""
        return self.bound.binding

    @cached_property
    def face(self) -> Take:
        """The take's face markers (the ones reconstructed), head frame, mm (gathered once:
        the errors and the report both read them)."""
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

    @cached_property
    def head_motion(self) -> tuple:
        """The head motion of the take as a rigid motion of the mesh, one per frame.

        Returns
        -------
        rotation : ndarray of shape (T, 3, 3)
        translation : ndarray of shape (T, 3), mesh units
            Frame t of a mesh sequence is placed at ``rotation[t] @ v + translation[t]``
            (:func:`fit.gestures.transfer.head_motion_on_mesh` of the stabilization's
            R(t), t(t) over the take's frames).
        """
        stab = self.ingested.stabilization
        start = self.take.first_frame - stab.take.first_frame
        frames = slice(start, start + self.take.n_frames)
        return head_motion_on_mesh(self.binding, stab.rotation[frames],
                                   stab.translation[frames])

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
                            first_frame=self.take.first_frame, rotation=self.head_motion[0],
                            translation=self.head_motion[1])

    def save(self, directory, *, inputs=(), figures: FigureQueue | None = None,
             wait: bool = True) -> list:
        """Write the take's exports into `directory` (created); returns the paths.

        ``take.c3d`` (cleaned, head-stabilized), ``head_motion.npz``,
        ``binding.json``, and per basis B: ``basis-B.npz``, ``weights-B.csv``,
        ``mesh-B.npz`` (compact sequence with the head motion), ``face-B.glb``
        (morph targets, weight animation at the take's rate keyed on the
        capture's frame numbers, the head motion as the node's rotation and
        translation). Every file atomically; none over one of `inputs`. With
        `figures` (:class:`~fit.report.figure_queue.FigureQueue`), the weights
        CSVs (text, the slowest to write) are queued first, for its helpers to
        write while this process writes the other files, unless this process
        has the compiled CSV text loaded (numba, the ``speed`` extra): a thread of
        its own then writes them meanwhile. All are written when this returns,
        and the first error is raised here, unless ``wait=False``: the queued
        CSVs are then left to the queue's helpers while this process goes on
        (with the report's work), and the queue's next
        :meth:`~fit.report.figure_queue.FigureQueue.run` writes what is left and
        raises their first error (a queue closed before it drops them).
        """
        if figures is None:
            with FigureQueue(helpers=0) as figures:
                return self.save(directory, inputs=inputs, figures=figures)
        out = Path(directory)
        out.mkdir(parents=True, exist_ok=True)
        timing = dict(rate=self.take.rate, first_frame=self.take.first_frame)
        # the CSVs' text by the compiled kernel costs less here than the weights' trip to a
        # helper and its NumPy formatting there (three times the kernel's time); the kernel
        # lets go of the GIL, so a thread writes them while this one writes the others, and
        # this one takes those it has not started once its own are written
        here = compiled_lines_ready()
        csvs = [(out / f"weights-{name}.csv", self.fitted.weights[name], basis.names)
                for name, basis in self.bases.bases.items()]
        if not here:
            for task in csvs:
                figures.submit(write_weights_csv, *task, inputs=inputs, **timing)
        texts = TasksBeside(partial(write_weights_csv, *task, inputs=inputs, **timing)
                            for task in csvs) if here else None
        try:
            files = self._save_binary(out, inputs, timing)
        except BaseException:
            figures.close()     # a CSV a helper is writing is finished, the others dropped
            if texts is not None:
                texts.cancel()  # nor does our thread write on behind the error
            raise
        if texts is not None:
            texts.finish()
        if wait or not figures.helpers:
            figures.run()
        return files

    def _save_binary(self, out: Path, inputs, timing) -> list:
        """The exports of :meth:`save` but the weights CSVs, written here; all the paths."""
        mesh = self.reconstruction.mesh
        files = [out / "take.c3d", out / "head_motion.npz", out / "binding.json"]
        mocap.write(self.take, files[0], inputs=inputs)
        save_head_motion(self.ingested.head_frame, files[1], inputs=inputs)
        self.binding.save(files[2])
        rotation, translation = self.head_motion
        turning = Rotation.from_matrix(rotation)  # the .glb files' quaternions, made once
        for name, basis in self.bases.bases.items():
            weights = self.fitted.weights[name]
            paths = [out / f"basis-{name}.npz", out / f"weights-{name}.csv",
                     out / f"mesh-{name}.npz", out / f"face-{name}.glb"]
            save_basis(ArtistBasis(basis.names, mesh, basis.displacements), paths[0],
                       dtype="float32", inputs=inputs)
            write_mesh_sequence(paths[2], mesh, basis.displacements, weights,
                                names=basis.names, rotation=rotation, translation=translation,
                                inputs=inputs, **timing)
            write_gltf(paths[3], mesh, basis.displacements, basis.names, weights=weights,
                       rotation=turning, translation=translation,
                       name=f"{self.name}-{name}", inputs=inputs, **timing)
            files += paths
        return files

    def held_out(self) -> HeldOut | None:
        """Out-of-sample reconstructions of QE and PCA (time-blocked folds of the take), or
        None when ``report.held_out_folds`` is 0 or the take is too short for them."""
        options = self.reconstruction.report
        folds, n_frames = options.held_out_folds, self.take.n_frames
        if folds == 0 or n_frames < 2 * folds:
            return None
        # a short take gets a shorter guard, so that every fold keeps training frames
        guard = min(int(round(options.held_out_guard_s * self.take.rate)),
                    n_frames // folds // 2)
        splits = time_blocked_splits(n_frames, folds, guard=guard)
        label = (f"{folds} time-blocked folds, each block of ~{n_frames // folds} frames "
                 f"reconstructed by QE and PCA built from the rest of the take less "
                 f"{guard} frames ({guard / self.take.rate:.2g} s) on either side")
        return held_out_fits(self.take, self.bound, self.retargeted, self.reconstruction.basis,
                             splits=splits, label=label,
                             basis_options=self.reconstruction.basis_options,
                             fit_options=self.reconstruction.fit)

    def mesh_space(self) -> MeshSpace:
        """What the report's mesh renders need (the bases, their weights, W and D)."""
        mesh = self.reconstruction.mesh
        return MeshSpace(faces=mesh.faces, neutral=mesh.vertices,
                         mm_per_unit=(mm_per_unit(mesh.units) if mesh.units
                                      else 1.0 / self.binding.scale),
                         bases={n: (b.displacements, self.fitted.weights[n])
                                for n, b in self.bases.bases.items()},
                         operator=np.asarray(self.retargeted.operator.matrix),
                         displacements=self.retargeted.displacements,
                         to_mesh=self.binding.to_mesh)

    def report(self, directory, *, inputs=None, warnings=(), figures=None) -> list:
        """Write the QA pictures, videos and ``<name>.html`` into `directory`; returns the paths.

        `inputs` (role to path, hashed, or to ``{"path", "sha256"}``, a digest known
        already) are the report's provenance (default the capture, the mesh and the
        marker set); `warnings` (messages) are
        listed in a section of the page of their own. `figures`
        (:class:`fit.report.figure_queue.FigureQueue`) draws the figures; default one of
        its own, with :func:`~fit.report.figure_queue.default_helpers` helper processes.
        """
        if figures is None:
            with FigureQueue() as figures:
                return self.report(directory, inputs=inputs, warnings=warnings,
                                   figures=figures)
        qa = Path(directory)
        qa.mkdir(parents=True, exist_ok=True)
        options = self.reconstruction.report
        face = self.face
        # the figures get what they show, not the take: a helper receives it by pickle
        figures.submit(plot_gaps, GapChart.of(self.ingested.cleaned), qa / "gaps.png")
        figures.submit(plot_head_residuals, HeadResiduals.of(self.ingested.stabilization),
                       qa / "head_residuals.png")
        files = [qa / "gaps.png", qa / "head_residuals.png"]
        pictures = {
            "gaps": Figure(files[0], "Gaps: present, missing, filled by method",
                           "One row per marker over time: grey present, black still missing, "
                           "coloured where a gap was filled (by the method in the legend)."),
            "head": Figure(files[1], "Head-marker residuals",
                           "Distance of each head marker from its place on the rigidly fitted "
                           "head; shaded spans are slips, numbered as in the provenance's slip "
                           "table. Residuals near the noise level mean a clean stabilization.")}
        files += build_report(face, self.fitted.reconstructed,
                              self.bound.neutral_pose(face.positions), qa,
                              markerset=self.reconstruction.markerset, pca=self.bases.pca,
                              ingest=self.ingested, video=options.video, pictures=pictures,
                              video_step=options.video_step, n_worst=options.n_worst,
                              exaggerate=options.exaggerate, name=self.name,
                              warnings=warnings,
                              provenance=take_provenance(self, inputs=inputs),
                              grades=stage_grades(self), held_out=self.held_out,
                              mesh_space=self.mesh_space() if options.mesh_views else None,
                              cross_validation=self.retargeted.cross_validation,
                              selection=self.retargeted.selection,
                              lip_seal=self.lip_seal, figures=figures,
                              errors=self.errors).values()
        return files

    def _head_frame_summary(self) -> dict:
        """How the head frame was found: method, markers and their median residuals (mm)."""
        head = self.ingested.head_frame
        st = head.stabilization
        residuals = {label: (None if np.isnan(r) else float(r))
                     for label, r in zip(st.head_markers,
                                         nan_column_medians(st.head_residuals)
                                         if st.head_markers else [])}
        out = {"method": head.method, "markers": list(st.head_markers),
               "median_residual_mm": residuals, "slips": len(st.slips),
               "robust": st.robust, "robust_disagreements": len(st.disagreements)}
        if head.motion is not None:
            out["face_motion"] = {"median_deg": head.motion.median_angle,
                                  "median_mm": head.motion.median_shift}
        return out

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
        """What the manifest records of the take: frames, binding, retargeting, lips, bases,
        fit and metrics."""
        take, ingested = self.take, self.ingested

        def finite(summary: dict) -> dict:
            return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                    for k, v in summary.items()}
        return {"frames": {"first": take.first_frame, "count": take.n_frames,
                           "trimmed": ingested.take.n_frames - take.n_frames,
                           "neutral": take.first_frame + self.bound.frame,
                           "neutral_window": self.bound.window, "rate": take.rate},
                "head_frame": self._head_frame_summary(),
                "binding_rms_mm": self.binding.rms,
                "retarget": self._retarget_summary(),
                "lip_seal": None if self.lip_seal is None else self.lip_seal.summary(),
                "pca_components": self.bases.n_components,
                "qe_missing_axes": self.bases.qe.missing_axes.tolist(),
                "basis": {"scope": self.bases.scope,
                          "pca_sha256": self.bases.pca.truncate(self.bases.n_components).sha256()},
                "fit": {name: {"status": s.status, "message": s.message}
                        for name, s in self.fitted.solutions.items()},
                "metrics": {name: finite(errors.summary()
                                         | {"worst_frame": take.first_frame
                                            + errors.summary()["worst_frame"],
                                            "smoothness": self.fitted.solutions[name].smoothness})
                            for name, errors in self.errors.items()}}
