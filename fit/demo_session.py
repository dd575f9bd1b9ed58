"""The project's own demo session: a synthetic facial capture made from nothing.

A head band of six markers and 40 face markers laid out on an ellipsoidal face
(mouth, brows, eyes, cheeks, nose, chin), moved by six smooth "muscle" modes
(jaw opening, smile left/right, lip pucker, brow raise, blink), carried by a
smooth head motion, with marker noise and seeded occlusion gaps. Everything is
seeded and deterministic.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from mocap.take import SourceInfo, Take

__all__ = ["DemoSession", "make_demo_session", "MARKERSET_TOML"]

#: Head markers: a band over forehead and temples (head frame, mm).
_HEAD = {"head-1": (-70, 95, 40), "head-2": (0, 110, 70), "head-3": (70, 95, 40),
         "head-4": (-85, 60, -20), "head-5": (85, 60, -20), "head-6": (0, 130, 20)}

# Face markers by region: (x, y) on the face, z from the face ellipsoid.
_REGIONS = {
    "upper_lip": {"ulip-r2": (-22, -38), "ulip-r1": (-11, -34), "ulip-c": (0, -33),
                  "ulip-l1": (11, -34), "ulip-l2": (22, -38)},
    "lower_lip": {"llip-r2": (-20, -47), "llip-r1": (-10, -51), "llip-c": (0, -52),
                  "llip-l1": (10, -51), "llip-l2": (20, -47)},
    "left_brow": {"lbrow-in": (15, 38), "lbrow-mid": (33, 42), "lbrow-out": (50, 37)},
    "right_brow": {"rbrow-in": (-15, 38), "rbrow-mid": (-33, 42), "rbrow-out": (-50, 37)},
    "left_eye": {"leye-in": (18, 20), "leye-out": (50, 20), "leye-lid": (34, 27),
                 "leye-low": (34, 11)},
    "right_eye": {"reye-in": (-18, 20), "reye-out": (-50, 20), "reye-lid": (-34, 27),
                  "reye-low": (-34, 11)},
    "other": {"mouth-l": (29, -42), "mouth-r": (-29, -42), "nose-tip": (0, -5),
              "nose-l": (14, -15), "nose-r": (-14, -15), "chin": (0, -78),
              "chin-l": (25, -70), "chin-r": (-25, -70), "cheek-l": (50, -15),
              "cheek-r": (-50, -15), "cheek-l2": (42, -45), "cheek-r2": (-42, -45),
              "jaw-l": (65, -50), "jaw-r": (-65, -50), "forehead": (0, 60)},
}
_LANDMARKS = {"mouth_corner_left": "mouth-l", "mouth_corner_right": "mouth-r",
              "upper_lip_top": "ulip-c", "lower_lip_bottom": "llip-c",
              "eye_inner_left": "leye-in", "eye_outer_left": "leye-out",
              "eye_inner_right": "reye-in", "eye_outer_right": "reye-out",
              "nose_tip": "nose-tip", "chin": "chin"}


def _toml_list(labels) -> str:
    return "[" + ", ".join(f'"{s}"' for s in labels) + "]"


#: The marker-set file of the demo session.
MARKERSET_TOML = "\n".join(
    ['name = "demo"', f"head = {_toml_list(_HEAD)}", "", "[regions]"]
    + [f"{region} = {_toml_list(markers)}" for region, markers in _REGIONS.items()]
    + ["", "[landmarks]"] + [f'{point} = "{label}"' for point, label in _LANDMARKS.items()]
) + "\n"


@dataclass(frozen=True)
class DemoSession:
    """A generated capture with its ground truth.

    Attributes
    ----------
    take : Take
        The capture as a system would record it (noise, gaps, head motion), mm.
    rotation : ndarray of shape (T, 3, 3)
        True head rotation, world = R @ head + t.
    translation : ndarray of shape (T, 3), mm
    head_frame_positions : ndarray of shape (T, M, 3), mm
        True noise-free markers in the head frame.
    """

    take: Take
    rotation: np.ndarray
    translation: np.ndarray
    head_frame_positions: np.ndarray


def _smooth_noise(rng, n_frames, n_channels, rate, cutoff_hz):
    """Band-limited random curves in [-1, 1], shape (n_frames, n_channels)."""
    n_knots = max(4, int(n_frames / rate * cutoff_hz * 2))
    knots = rng.uniform(-1, 1, (n_knots, n_channels))
    x = np.linspace(0, n_knots - 1, n_frames)
    i = np.minimum(x.astype(int), n_knots - 2)
    f = x - i
    f = f * f * (3 - 2 * f)                                   # smoothstep between knots
    return knots[i] * (1 - f[:, None]) + knots[i + 1] * f[:, None]


def _face_rest() -> tuple[list[str], np.ndarray, list[str]]:
    labels, points, regions = [], [], []
    for region, markers in _REGIONS.items():
        for label, (x, y) in markers.items():
            z = 95 * np.sqrt(max(0.0, 1 - (x / 80) ** 2 - (y / 120) ** 2))
            z += 22 * np.exp(-(x ** 2 + (y + 8) ** 2) / 300)   # the nose
            labels.append(label)
            points.append((x, y, z))
            regions.append(region)
    return labels, np.array(points, float), regions


def _expression_modes(labels, rest) -> np.ndarray:
    """Six displacement fields (6, M, 3), mm at full activation."""
    x, y = rest[:, 0], rest[:, 1]
    below_mouth = np.clip((-42 - y) / 30 + 1, 0, 1) * (y < -40)
    jaw = np.stack([0 * x, -14 * below_mouth, -4 * below_mouth], axis=1)
    modes = [jaw]
    for side in (1, -1):                                      # smile left, right
        w = np.exp(-((x - side * 29) ** 2 + (y + 42) ** 2) / 500)
        modes.append(np.stack([side * 7 * w, 5 * w, -2 * w], axis=1))
    w = np.exp(-(x ** 2 + (y + 42) ** 2) / 400)               # pucker
    modes.append(np.stack([-0.3 * x * w, 0 * w, 8 * w], axis=1))
    w = np.clip((y - 20) / 20, 0, 1)                          # brow raise
    modes.append(np.stack([0 * w, 8 * w, 1 * w], axis=1))
    lid = np.array([s.endswith("-lid") for s in labels], float)  # blink
    modes.append(np.stack([0 * lid, -9 * lid, 1 * lid], axis=1))
    return np.stack(modes)


def _weights(rng, n_frames, rate) -> np.ndarray:
    """Activation curves of the six modes, (T, 6), in [0, 1]."""
    w = 0.5 + 0.5 * _smooth_noise(rng, n_frames, 5, rate, 0.6)
    w = np.clip(1.4 * w - 0.35, 0, 1)
    t = np.arange(n_frames) / rate
    blinks = rng.uniform(0, t[-1], size=max(1, int(t[-1] / 3.5)))
    blink = np.exp(-((t[:, None] - blinks[None]) / 0.07) ** 2).sum(axis=1)
    return np.column_stack([w, np.clip(blink, 0, 1)])


def _occlusions(rng, n_frames, n_markers, n_gaps) -> np.ndarray:
    """Missing mask (T, M): gaps of realistic lengths (a few frames to ~1 s)."""
    missing = np.zeros((n_frames, n_markers), bool)
    lengths = np.clip(rng.lognormal(np.log(20), 0.9, n_gaps).astype(int), 2, 150)
    markers = rng.integers(0, n_markers, n_gaps)
    starts = rng.integers(0, n_frames - lengths)
    for m, s, n in zip(markers, starts, lengths):            # loop over gaps, not frames
        missing[s:s + n, m] = True
    return missing


def make_demo_session(*, seed: int = 7, rate: float = 120.0, seconds: float = 20.0,
                      noise_mm: float = 0.2, n_gaps: int = 60) -> DemoSession:
    """Generate the demo capture.

    Parameters
    ----------
    seed : int
        Seed of every random choice.
    rate : float
        Frame rate, Hz.
    seconds : float
        Length of the take, s.
    noise_mm : float
        Standard deviation of the marker noise, mm.
    n_gaps : int
        Number of occlusion gaps over the face markers (head markers get a few too).

    Returns
    -------
    DemoSession
    """
    rng = np.random.default_rng(seed)
    n_frames = int(round(seconds * rate))
    face_labels, face_rest, _ = _face_rest()
    labels = list(_HEAD) + face_labels
    head_rest = np.array(list(_HEAD.values()), float)
    modes = _expression_modes(face_labels, face_rest)
    weights = _weights(rng, n_frames, rate)
    face = face_rest + np.einsum("tk,kmc->tmc", weights, modes)
    local = np.concatenate([np.broadcast_to(head_rest, (n_frames,) + head_rest.shape),
                            face], axis=1)
    angles = _smooth_noise(rng, n_frames, 3, rate, 0.3) * np.array([15.0, 25.0, 8.0])
    rotation = Rotation.from_euler("xyz", angles, degrees=True).as_matrix()
    translation = _smooth_noise(rng, n_frames, 3, rate, 0.2) * 40 + np.array([0, 1500, 300])
    world = np.einsum("tij,tmj->tmi", rotation, local) + translation[:, None]
    world = world + rng.normal(0, noise_mm, world.shape)
    missing = _occlusions(rng, n_frames, len(labels), n_gaps)
    missing[:, :len(_HEAD)] &= rng.random(len(_HEAD)) < 0.35  # a few head gaps only
    world[missing] = np.nan
    take = Take(tuple(labels), world, rate, source=SourceInfo(
        format="memory", producer=f"mocap2mesh demo session (seed {seed})"))
    return DemoSession(take, rotation, translation, local)
