"""Out-of-sample errors of the bases a take builds for itself (PCA, quasi-eigen faces).

In-sample, PCA and QE are scored on the frames they were built from: PCA is
then the best basis of its size by construction, and a basis that fits noise
looks excellent. Here each basis is rebuilt from some frames (the training
frames) and scored on others (the test frames), which is what a basis faces
on the next take.

:func:`time_blocked_splits` cuts a take into contiguous blocks (neighbouring
frames are near copies, so a random split would leak), each block tested once
with a guard band of frames left out of its training set on either side;
:func:`held_out_fits` runs any splits with any way of making the bases, so
the other variant, bases from the *other* takes of a session, is
``make_bases=lambda train: session_bases`` with one split testing every frame.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable

import numpy as np

from basis.pca import OperatorFactor, marker_moments, pca_from_operators, pool_moments
from fit.pipeline.options import BasisOptions, FitOptions
from fit.pipeline.stages import BasisResult, basis_stage, fit_stage
from mocap.errors import InputError
from mocap.util.validation import as_int

__all__ = ["HeldOut", "time_blocked_splits", "held_out_fits"]

#: Bases a take builds from its own frames: the ones that need an out-of-sample score.
TAKE_BASES = ("QE", "PCA")


@dataclass(frozen=True, eq=False)
class HeldOut:
    """Reconstructions of every frame by bases that were not built from it.

    Attributes
    ----------
    reconstructed : dict of str to ndarray, shape (T, M, 3), mm
        Per basis, each frame reconstructed by the basis of the split that
        tested it; NaN in frames no split tested.
    label : str
        How the bases were held out, for the report ("5 time-blocked folds ...").
    n_components : list of int
        The PCA size of each split's basis.
    """

    reconstructed: dict
    label: str
    n_components: list


def time_blocked_splits(n_frames: int, n_folds: int = 5, guard: int = 0) -> list:
    """Contiguous test blocks and the training frames of each.

    Parameters
    ----------
    n_frames : int
    n_folds : int
        Number of blocks, at least 2; each frame is tested exactly once.
    guard : int
        Frames on each side of a test block left out of its training set.

    Returns
    -------
    list of (train, test)
        Index arrays (int) into the take's frames.

    Raises
    ------
    InputError
        Fewer frames than folds, or a guard that leaves a fold no training frame.

    Examples
    --------
    >>> [(a.tolist(), b.tolist()) for a, b in time_blocked_splits(6, 3, guard=1)]
    [([3, 4, 5], [0, 1]), ([0, 5], [2, 3]), ([0, 1, 2], [4, 5])]
    """
    n_frames = as_int(n_frames, "n_frames", minimum=1)
    n_folds = as_int(n_folds, "n_folds", minimum=2)
    guard = as_int(guard, "guard", minimum=0)
    if n_frames < n_folds:
        raise InputError(f"{n_frames} frames cannot make {n_folds} time-blocked folds")
    edges = np.linspace(0, n_frames, n_folds + 1).round().astype(int)
    frames = np.arange(n_frames)
    splits = []
    for start, stop in zip(edges[:-1], edges[1:]):
        train = frames[(frames < start - guard) | (frames >= stop + guard)]
        if not len(train):
            raise InputError(f"a guard of {guard} frames leaves the test block "
                             f"{start}..{stop - 1} no training frame")
        splits.append((train, frames[start:stop]))
    return splits


def held_out_fits(take, bound, retargeted, artist, *, splits, label: str,
                  basis_options: BasisOptions = BasisOptions(),
                  fit_options: FitOptions = FitOptions(),
                  make_bases: Callable | None = None, bases=TAKE_BASES) -> HeldOut:
    """Fit the take with bases built without the frames they reconstruct.

    Parameters
    ----------
    take, bound, retargeted
        The take's stages (as :func:`fit.pipeline.stages.fit_stage` takes them).
    artist : basis.artist.ArtistBasis
        E^H (for the quasi-eigen faces).
    splits : sequence of (train, test)
        Frame indices; `train` is given to `make_bases`, the reconstruction is
        kept on `test` (e.g. :func:`time_blocked_splits`).
    label : str
        How the bases were held out (stored in the result).
    basis_options, fit_options
        As for the take itself.
    make_bases : callable, optional
        ``make_bases(train) -> BasisResult``; default the take's own basis
        stage on its training frames (PCA of W·D over them, QE from that PCA).
        Bases of other takes plug in here.
    bases : sequence of str
        The bases to score.

    Returns
    -------
    HeldOut

    Notes
    -----
    With temporal smoothness (or GCV, or a moving average) each split fits the
    whole take, so that they see contiguous frames, and keeps its test frames;
    frames fit independently are fit on the test frames alone. Either way a
    frame's weights come from its own markers, its basis from other frames.
    """
    splits = [(train, _as_slice(np.asarray(test))) for train, test in splits]
    # the take's own basis stage on each training set: its PCA from the set's moments, the
    # operator's factor (its products with the mesh) made once for all the sets
    moments = _training_moments(retargeted.displacements, splits) if make_bases is None \
        else [None] * len(splits)
    factor = OperatorFactor.of([retargeted.operator.matrix]) if make_bases is None else None
    shape = (take.n_frames, len(retargeted.labels), 3)
    out = {name: np.full(shape, np.nan) for name in bases}
    sizes = []
    # without smoothing over time each frame's fit is its own: only the test frames are fit
    independent = fit_options.smoothness == 0 and fit_options.moving_average <= 1
    for (train, test), training in zip(splits, moments):
        made = make_bases(train) if training is None else \
            _bases_from_moments(retargeted, artist, training, basis_options, factor)
        if not isinstance(made, BasisResult):
            raise InputError(f"make_bases must return a BasisResult, got {type(made).__name__}")
        chosen = BasisResult(bases={n: made.bases[n] for n in bases}, pca=made.pca,
                             n_components=made.n_components, qe=made.qe)
        fitted = fit_stage(take, bound, dataclasses.replace(
            retargeted, displacements=retargeted.displacements[test]) if independent
            else retargeted, chosen, options=fit_options)
        for name in bases:
            out[name][test] = fitted.reconstructed[name] if independent \
                else fitted.reconstructed[name][test]
        sizes.append(made.n_components)
    return HeldOut(reconstructed=out, label=label, n_components=sizes)


#: Training sets cut into more runs than one per this many frames are scattered: their
#: moments are taken from a copy of their frames instead of pooled from the runs.
_MIN_MEAN_RUN = 32


def _training_moments(displacements: np.ndarray, splits) -> list:
    """Marker moments of each split's training frames, ``displacements`` (T, M, 3).

    The frames are cut into the runs that every training set takes whole or leaves out
    (the test blocks and guard bands of :func:`time_blocked_splits`); each run's moments
    are taken once, on a view, and each training set's are pooled from its runs. With
    training sets scattered over many short runs, each set's moments come from its
    frames directly.
    """
    n_frames = len(displacements)
    member = np.zeros((len(splits), n_frames), bool)
    for row, (train, _) in zip(member, splits):
        row[train] = True
    starts = np.flatnonzero(np.r_[True, (member[:, 1:] != member[:, :-1]).any(axis=0)])
    if len(starts) * _MIN_MEAN_RUN > n_frames:
        return [marker_moments(displacements[train]) for train, _ in splits]
    stops = np.r_[starts[1:], n_frames]
    taken = member[:, starts]                                   # (splits, runs)
    runs = {r: marker_moments(displacements[starts[r]:stops[r]])
            for r in np.flatnonzero(taken.any(axis=0))}
    return [pool_moments([runs[r] for r in np.flatnonzero(row)]) for row in taken]


def _bases_from_moments(retargeted, artist, moments, options: BasisOptions,
                        factor: OperatorFactor) -> BasisResult:
    """The basis stage of a take on the frames whose marker `moments` are given (`factor`:
    of the take's operator)."""
    pca = pca_from_operators([retargeted.operator.matrix], [moments],
                             n_components=options.pca_components,
                             coverage=None if options.pca_components else options.pca_coverage,
                             factor=factor)
    return basis_stage(retargeted, artist, options=options, pca=pca)


def _as_slice(frames: np.ndarray):
    """`frames` (int, ascending) as a slice when they are one run, so indexing gives a view."""
    if np.issubdtype(frames.dtype, np.integer) and len(frames) \
            and frames[-1] - frames[0] == len(frames) - 1 and np.all(np.diff(frames) == 1):
        return slice(int(frames[0]), int(frames[-1]) + 1)
    return frames
