"""Numerics of the gesture Markov random field: window banks, distances, picks, blending.

A *bank* holds the candidate frames t̂ of a set of reference clips for one
feature. The distance of a candidate to the output's history,
``α Σ_{j<h} |S̃(t−j) − S(t̂−j)|² + Σ_{1≤j≤h} |c̃(t−j) − c(t̂−j)|²``, expands into
``|q|² + |z(t̂)|² − 2 q·z(t̂)``; ``|z|²`` is precomputed, the speech cross term
is one (n, h) matrix-vector product and the feature cross term
``A_t(t̂) = Σ_{j=1..h} g_{t−j}(t̂−j)``, with ``g_u = F c̃(u)`` over all reference
frames, is updated as each output frame arrives:
``A_{t+1}(p) = A_t(p−1) + g_t(p−1) − g_{t−h}(p−1−h)`` — O(frames · d) per
output frame instead of O(frames · h · d).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy.signal import lfilter

from mocap.errors import InputError

#: Dynamic range kept of an intensity curve below its 95th percentile, dB.
INTENSITY_RANGE_DB = 60.0


@dataclass(frozen=True)
class Bank:
    """Candidates of some clips for one feature.

    features (N, d): the clips' frames end to end; speech (n, h): √α S of each
    candidate's speech window; norms (n,): |z|² (inf for windows with NaN);
    position (n,): row of each candidate t̂ in `features`; clip (n,)
    and frame (n,) of each candidate t̂; first (n,): first candidate of its clip.
    """

    features: np.ndarray
    speech: np.ndarray
    norms: np.ndarray
    position: np.ndarray
    clip: np.ndarray
    frame: np.ndarray
    first: np.ndarray


def standardize_intensity(s: np.ndarray) -> np.ndarray:
    """Z-score of an intensity curve floored at 60 dB below its 95th percentile."""
    finite = s[np.isfinite(s)]
    if finite.size == 0:
        return s.copy()
    s = np.maximum(s, np.percentile(finite, 95) - INTENSITY_RANGE_DB)
    spread = np.nanstd(s)
    return (s - np.nanmean(s)) / (spread if spread > 0 else 1.0)


def part_scales(values: list, parts: list) -> np.ndarray:
    """Per-dimension divisor (d,): each part's total variance over all clips becomes 1."""
    stacked = np.concatenate(values)
    var = np.nanvar(stacked, axis=0) if np.isfinite(stacked).any() else np.zeros(
        stacked.shape[1])
    scale = np.ones(stacked.shape[1])
    for part in parts:
        total = float(np.sqrt(np.nansum(var[part])))
        scale[part] = total if total > 0 else 1.0
    return scale


def build_bank(intensities: list, features: list, clips, *, h: int, alpha: float,
               start: bool = False) -> Bank:
    """The bank of candidates of `clips` (indices into the lists).

    ``start=True``: the first block, speech only: windows ``S(t̂ .. t̂+h−1)``,
    t̂ in [0, T − h]. Otherwise t̂ in [h, T − 1]. Windows with NaN (in the
    matched frames or frame t̂; the first h frames for a start bank) get an
    infinite norm.
    """
    parts, offset = [], 0
    root = np.sqrt(alpha)
    for c in clips:
        s, f = intensities[c], features[c]
        n_frames, d = f.shape
        lo, hi = (0, n_frames - h) if start else (h, n_frames - 1)
        if hi >= lo:
            frames = np.arange(lo, hi + 1)
            speech = root * sliding_window_view(s, h)[frames - (0 if start else h - 1)]
            copied = sliding_window_view(f, (h if start else 1, d))[:, 0][frames]
            bad = np.isnan(speech).any(axis=1) | np.isnan(copied).any(axis=(1, 2))
            norms = np.einsum("ij,ij->i", speech, speech)
            if not start:
                past = sliding_window_view(f, (h, d))[:, 0][frames - h]
                bad |= np.isnan(past).any(axis=(1, 2))
                norms = norms + np.einsum("ijk,ijk->i", past, past)
            first = frames == lo
            parts.append((np.nan_to_num(speech), np.where(bad, np.inf, norms),
                          np.full(len(frames), c), frames, first, offset + frames))
        offset += len(f)
    if not parts:
        raise InputError(f"no reference clip is long enough: a clip needs more than "
                         f"{h} frames (the history)")
    speech, norms, clip, frame, first, position = (np.concatenate(x) for x in zip(*parts))
    stacked = np.nan_to_num(np.concatenate([features[c] for c in clips]))
    return Bank(stacked, speech, norms, position, clip, frame, first)


def distances(bank: Bank, speech_query: np.ndarray, feature_cross: np.ndarray | None = None,
              history_sq: float = 0.0) -> np.ndarray:
    """dist(t̂) of every candidate (inf for invalid windows).

    speech_query (h,): √α S̃ of the output's speech window; feature_cross (N,):
    A_t over every row of ``bank.features`` (None for a start bank);
    history_sq: ``Σ_j |c̃(t−j)|²``.
    """
    cross = bank.speech @ speech_query
    sq = speech_query @ speech_query + history_sq
    if feature_cross is not None:
        cross = cross + feature_cross[bank.position]
    return np.maximum(bank.norms - 2.0 * cross + sq, 0.0)


def local_minima(dist: np.ndarray, first: np.ndarray) -> np.ndarray:
    """Candidates no farther than their neighbours in the same clip (bool, finite only)."""
    prev = np.concatenate([[np.inf], dist[:-1]])
    nxt = np.concatenate([dist[1:], [np.inf]])
    prev[first] = np.inf
    nxt[np.concatenate([first[1:], [True]])] = np.inf
    return (dist <= prev) & (dist <= nxt) & np.isfinite(dist)


def without_time_warps(bank: Bank, dist: np.ndarray, previous, h: int) -> np.ndarray:
    """Candidates of a step without time warps (bool): the continuation, local minima past h.

    previous: (clip, frame) the output copied last, or None (then: the local
    minima). The continuation (the next frame of that clip) is a candidate
    whenever its window is valid; the other frames less than h from it are
    not: copying one stalls, replays or skips the stretch being copied. Local
    minima are taken before that zone is cut out, so a valley inside it does
    not leave a candidate at its edge.
    """
    out = local_minima(dist, bank.first)
    if previous is None:
        return out
    clip, nxt = previous[0], previous[1] + 1
    near = (bank.clip == clip) & (np.abs(bank.frame - nxt) < h)
    out &= ~near
    out |= near & (bank.frame == nxt) & np.isfinite(dist)
    return out


def time_warps(src: np.ndarray, h: int) -> int:
    """Output frames copying a frame less than h from the continuation (src (T, 2): clip, frame)."""
    step = src[1:, 1] - src[:-1, 1] - 1
    return int(np.count_nonzero((src[1:, 0] == src[:-1, 0]) & (step != 0) & (np.abs(step) < h)))


def pick(dist: np.ndarray, eligible: np.ndarray, k: int, sigma: float, rng) -> int:
    """Index of one of the k nearest eligible candidates, P ∝ exp(−dist/σ) (σ = 0: the nearest)."""
    idx = np.flatnonzero(eligible)
    if idx.size == 0:
        idx = np.flatnonzero(np.isfinite(dist))
        if idx.size == 0:
            raise InputError("no reference window without missing frames to match")
    if idx.size > k:
        idx = idx[np.argpartition(dist[idx], k - 1)[:k]]
    d = dist[idx]
    if sigma == 0:
        return int(idx[np.argmin(d)])
    cum = np.cumsum(np.exp(-(d - d.min()) / sigma))
    return int(idx[min(np.searchsorted(cum, rng.random() * cum[-1], side="right"),
                       idx.size - 1)])


def cross_terms(products: np.ndarray) -> np.ndarray:
    """A(p) = Σ_{j=1..h} g_{t−j}(p − j) from products (h, N), row r = g_{t−h+r}."""
    h, n = products.shape
    acc = np.zeros(n)
    for j in range(1, h + 1):            # h shifted adds (h is the history length)
        acc[j:] += products[h - j, :n - j]
    return acc


def advance(acc: np.ndarray, newest: np.ndarray, oldest: np.ndarray, h: int) -> np.ndarray:
    """A_{t+1} from A_t, g_t (newest) and g_{t−h} (oldest), all (N,)."""
    step = acc + newest
    step[h:] -= oldest[:-h]
    out = np.empty_like(acc)
    out[0] = 0.0
    out[1:] = step[:-1]
    return out


def transition_blend(values: np.ndarray, jumps: np.ndarray, frames: int) -> np.ndarray:
    """Spread each jump's offset over `frames` frames: linear ramp from the jump to 0.

    values (T, d); jumps (T, d) holds the offset (continuation − copied value)
    at each transition frame, 0 elsewhere; one FIR filter over all frames.
    """
    if frames <= 0 or not jumps.any():
        return values
    ramp = 1.0 - np.arange(frames) / frames
    return values + lfilter(ramp, [1.0], jumps, axis=0)


def chain(target: np.ndarray, intensities: list, features: list, spans: list, *, h: int,
          run: int, alpha: float, k: int, sigma: float, warps: bool = True,
          rng) -> np.ndarray:
    """Run the Markov chain of one feature; returns the source (clip, frame) of each output frame.

    `target` (T,) and `intensities` are standardized, `features` scaled; `spans`
    is ``[(start, stop, clips), ...]`` covering the output. The first h frames
    are copied from the window that best matches the first h frames of speech;
    then every step matches the last h output frames, picks a candidate t̂ and
    copies frames t̂ .. t̂ + L − 1, L = min(run, frames left in the span, frames
    left in the clip before its end or a NaN frame). ``warps=False``: the
    candidates of each step are :func:`without_time_warps`.
    """
    n_out, d = len(target), features[0].shape[1]
    out = np.empty((n_out, d))
    src = np.empty((n_out, 2), np.int64)
    banks = {}
    root = np.sqrt(alpha)

    def copy(bank, dist, t, length):
        if warps or t == 0:
            candidates = local_minima(dist, bank.first)
        else:
            candidates = without_time_warps(bank, dist, tuple(src[t - 1]), h)
        i = pick(dist, candidates, k, sigma, rng)
        c, f = int(bank.clip[i]), int(bank.frame[i])
        block = features[c][f:f + length]
        missing = np.isnan(block).any(axis=1)
        length = int(np.argmax(missing)) if missing.any() else len(block)
        out[t:t + length] = block[:length]
        src[t:t + length, 0] = c
        src[t:t + length, 1] = np.arange(f, f + length)
        return length

    first = build_bank(intensities, features, spans[0][2], h=h, alpha=alpha, start=True)
    copy(first, distances(first, root * target[:h]), 0, h)
    t, span, bank = h, 0, None
    while t < n_out:
        while spans[span][1] <= t:
            span += 1
        clips = spans[span][2]
        if clips not in banks:
            banks[clips] = build_bank(intensities, features, clips, h=h, alpha=alpha)
        if banks[clips] is not bank:
            bank = banks[clips]
            products = out[t - h:t] @ bank.features.T      # g of the last h frames
            acc = cross_terms(products)
            ring = np.empty_like(products)                  # row u % h holds g_u
            ring[np.arange(t - h, t) % h] = products
        history = out[t - h:t]
        dist = distances(bank, root * target[t - h + 1:t + 1], acc,
                         float(np.einsum("ij,ij->", history, history)))
        length = copy(bank, dist, t, min(run, spans[span][1] - t))
        for u in range(t, t + length):                   # the frames just copied
            newest = bank.features @ out[u]
            acc = advance(acc, newest, ring[u % h], h)
            ring[u % h] = newest
        t += length
    return src
