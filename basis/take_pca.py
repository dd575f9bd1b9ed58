"""PCA of whole takes: of retargeted archives on disk, and of captures through their operator."""

from __future__ import annotations

import numpy as np

import mocap
from basis.pca import PCAModel, pca_from_operator, pca_streaming
from mocap.clean.ingest import IngestOptions, ingest
from mocap.retarget.archive import ArchiveFrames
from mocap.retarget.retargeting import RetargetOptions, retarget

__all__ = ["pca_of_retargeted", "pca_of_captures"]


def pca_of_retargeted(paths, n_vertices: int, *,
                      chunk_frames: int = 512) -> PCAModel:
    """PCA of the vertex displacements of ``mocap2mesh retarget`` archives, all frames pooled.

    The mesh sequence of a retargeted take has rank at most 3M (M markers),
    so a randomized PCA with 3M components is exact to rounding; the files
    are read in chunks of `chunk_frames` frames, never whole.

    Parameters
    ----------
    paths : sequence of path
        ``.npz`` archives of :func:`mocap.retarget.archive.save_npz` (``vertices`` or
        ``displacements``, (T, N, 3), mesh units).
    n_vertices : int
        N of the neutral mesh; an archive of another mesh is rejected.

    Returns
    -------
    PCAModel
        Method ``"randomized"``, min(3M, ΣT, 3N) components.

    Raises
    ------
    FileFormatError
        An archive of another vertex count (named).
    """
    frames = ArchiveFrames(paths, n_vertices, chunk_frames)
    n_components = min(3 * frames.n_markers, frames.n_frames, 3 * n_vertices)
    return pca_streaming(frames, n_components=n_components, chunk_frames=chunk_frames)


def pca_of_captures(paths, binding, neutral, markerset, *, fill: str = "auto",
                    max_gap: int | None = None, neutral_frame="auto",
                    options: RetargetOptions = RetargetOptions()):
    """Exact PCA of the mesh motion of captures, never forming the mesh sequence.

    Each capture is gap-filled and head-stabilized (:func:`mocap.clean.ingest.ingest`),
    retargeted (:func:`mocap.retarget.retargeting.retarget`: its face-marker displacements D
    from its neutral frame, in mesh units, and the operator W), and the
    displacements of all captures are pooled: Ξ = W·D is analysed by
    :func:`basis.pca.pca_from_operator`. `fill` and `max_gap` are those of
    :class:`mocap.clean.ingest.IngestOptions` (None: the default maximum gap).

    Returns
    -------
    PCAModel
        Method ``"implicit"``.

    Raises
    ------
    MarkerError
        A marker of the set absent from a capture or the binding, a gap that
        filling left.
    """
    displacements, operator = [], None
    for path in paths:
        take = mocap.read(path)
        result = ingest(take, markerset=markerset,
                        options=IngestOptions(fill=fill, max_gap=max_gap, stabilize=True))
        retargeted = retarget(result.take, binding, neutral, markerset, options=options,
                              neutral_frame=result.take.frame_index(neutral_frame,
                                                                    "the neutral frame"))
        displacements.append(retargeted.displacements)
        operator = retargeted.operator.matrix if operator is None else operator
    return pca_from_operator(operator, np.concatenate(displacements))
