"""Build the default mask shipped in ``data/default_mask.npz``.

Run ``python -m basis.maskle.build_default`` to (re)write it. The mask is made
procedurally in the template frame (x to the subject's left, y up, z forward,
cm of an average adult face, origin at the lip contact on the midline):

* a mouth patch of 9 columns (the mouth corners on columns ±3) split along the
  lip-contact line into an upper band of 4 rows and a lower band of 6 (down
  to the chin, 4.2 cm below the lip line: the jaw's reach); each
  band's lip-line row grows a "tongue" strip 2 cm deep into the mouth from
  corner to corner (7 columns), the upper and lower strips 0.04 cm apart (deep
  enough to reach past the inner lip surfaces of a closed mouth: ICT's roll
  0.5 cm in behind the lip contact);
* one eye-and-brow patch per side, 8 × 8 vertices, with the inner and outer
  eye corners on the eye-line row.

Weights are painted analytically with smooth steps: a seven-bone rig (jaw,
upper and lower lip left/right, left and right brow) and the retargeting
regions (:data:`mocap.markerset.REQUIRED_REGIONS`, summing to 1 per vertex).
"""

from __future__ import annotations

import numpy as np

from basis.maskle.mask import DEFAULT_MASK_PATH, Mask, save_mask
from mocap.markerset import REQUIRED_REGIONS

__all__ = ["build_default_mask", "BONES"]

#: The seven bones of the default rig (left/right are the subject's own).
BONES = ("jaw", "upper_lip_left", "upper_lip_right", "lower_lip_left", "lower_lip_right",
         "brow_left", "brow_right")

_MOUTH_HALF = 2.5                          # mouth corner x, cm
_MOUTH_COLS = np.arange(-4, 5) * (_MOUTH_HALF / 3)
_UPPER_ROWS = (0.02, 0.85, 1.7, 2.2)       # offsets from the lip line; rows 0, 1 = landmarks
_LOWER_ROWS = (-0.02, -1.0, -1.8, -2.6, -3.4, -4.2)
_TONGUE_COLS = slice(1, 8)                 # the 7 columns from corner to corner
_TONGUE_DEPTH = 2.0
_EYE_INNER, _EYE_OUTER = np.array([1.8, 6.6]), np.array([4.4, 6.8])
_EYE_COLS = np.r_[0.5, 1.15, 1.8 + np.arange(6) * 0.8 * (2.6 / 2.4)]
_EYE_ROWS = np.arange(-2, 6) * 0.8          # offsets from the eye line


def _smooth(a, b, x):
    """Smooth step from 0 (x <= a) to 1 (x >= b); a > b reverses it."""
    s = np.clip((np.asarray(x, float) - a) / (b - a), 0.0, 1.0)
    return s * s * (3 - 2 * s)


def _lip_line(x):
    return -0.15 * (x / _MOUTH_HALF) ** 2


def _grid_quads(first: int, n_rows: int, n_cols: int, flip: bool) -> np.ndarray:
    """Quads of a row-major vertex grid starting at vertex id `first`."""
    r, c = np.meshgrid(np.arange(n_rows - 1), np.arange(n_cols - 1), indexing="ij")
    a = first + r * n_cols + c
    quads = np.stack([a, a + 1, a + n_cols + 1, a + n_cols], axis=-1).reshape(-1, 4)
    return quads[:, ::-1] if flip else quads


def _mouth():
    """Vertices, quads and landmark/tongue ids of the mouth patch and its tongue."""
    verts, quads = [], []
    for rows, flip in ((_UPPER_ROWS, False), (_LOWER_ROWS, True)):
        first = sum(len(v) for v in verts)
        x = np.tile(_MOUTH_COLS, len(rows))
        o = np.repeat(rows, len(_MOUTH_COLS))
        y = o + _lip_line(x) * np.maximum(0.0, 1 - np.abs(o) / 1.8)
        z = 0.4 - 0.13 * x ** 2 - 0.08 * np.maximum(0.0, -y - 1) ** 2
        verts.append(np.stack([x, y, z], axis=1))
        quads.append(_grid_quads(first, len(rows), len(_MOUTH_COLS), flip))
    n_cols = len(_MOUTH_COLS)
    upper_root = np.arange(n_cols)[_TONGUE_COLS]
    lower_root = len(_UPPER_ROWS) * n_cols + np.arange(n_cols)[_TONGUE_COLS]
    roots, tips = [], []
    for root, flip in ((upper_root, True), (lower_root, False)):
        first = sum(len(v) for v in verts)
        tip_xyz = np.concatenate(verts)[root] - [0.0, 0.0, _TONGUE_DEPTH]
        verts.append(tip_xyz)
        tip = first + np.arange(len(root))
        q = np.stack([root[:-1], root[1:], tip[1:], tip[:-1]], axis=1)
        quads.append(q[:, ::-1] if flip else q)
        roots.append(root)
        tips.append(tip)
    centre = len(_MOUTH_COLS) // 2
    n_upper = len(_UPPER_ROWS) * n_cols
    marks = {"mouth_corner_left": centre + 3, "mouth_corner_right": centre - 3,
             "upper_lip_bottom": centre, "upper_lip_top": n_cols + centre,
             "lower_lip_top": n_upper + centre, "lower_lip_bottom": n_upper + n_cols + centre}
    return (np.concatenate(verts), np.concatenate(quads), marks,
            np.concatenate(roots), np.concatenate(tips))


def _eye(side: float, first: int):
    """Vertices, quads and eye-corner ids of one eye-and-brow patch (side +1 = left)."""
    x = np.tile(_EYE_COLS, len(_EYE_ROWS))
    o = np.repeat(_EYE_ROWS, len(_EYE_COLS))
    y = o + _EYE_INNER[1] + (x - _EYE_INNER[0]) * (_EYE_OUTER[1] - _EYE_INNER[1]) \
        / (_EYE_OUTER[0] - _EYE_INNER[0])
    z = -0.6 - 0.08 * x ** 2
    verts = np.stack([side * x, y, z], axis=1)
    quads = _grid_quads(first, len(_EYE_ROWS), len(_EYE_COLS), flip=side < 0)
    row = int(np.flatnonzero(_EYE_ROWS == 0)[0]) * len(_EYE_COLS)
    name = "left" if side > 0 else "right"
    marks = {f"eye_inner_{name}": first + row + 2, f"eye_outer_{name}": first + row + 5}
    return verts, quads, marks


def _paint(v: np.ndarray, n_mouth: int, n_upper: int):
    """Bone and region weights (V, 7) and (V, 7) of the template vertices."""
    x, y = v[:, 0], v[:, 1]
    n = len(v)
    upper = np.zeros(n, bool)
    upper[:n_upper] = True
    mouth = np.arange(n) < n_mouth
    lower = mouth & ~upper
    off = y - _lip_line(x)                   # signed distance from the lip line
    ax = np.abs(x)
    lip_side = 1 - _smooth(2.6, 3.4, ax)
    bones = {
        "jaw": lower * (0.6 + 0.4 * _smooth(0.0, -1.8, off)) * (1 - 0.5 * _smooth(2.6, 3.4, ax)),
        "upper_lip_left": upper * (1 - _smooth(0.8, 2.0, off)) * _smooth(-1.0, 0.8, x) * lip_side,
        "upper_lip_right": upper * (1 - _smooth(0.8, 2.0, off)) * _smooth(1.0, -0.8, x) * lip_side,
        "lower_lip_left": lower * (1 - _smooth(-0.8, -2.0, off)) * _smooth(-1.0, 0.8, x) * lip_side,
        "lower_lip_right": lower * (1 - _smooth(-0.8, -2.0, off)) * _smooth(1.0, -0.8, x) * lip_side,
        "brow_left": (~mouth & (x > 0)) * _smooth(7.6, 8.8, y) * (1 - _smooth(5.6, 6.3, x)),
        "brow_right": (~mouth & (x < 0)) * _smooth(7.6, 8.8, y) * (1 - _smooth(-5.6, -6.3, x)),
    }
    lip = (1 - _smooth(2.8, 3.4, ax))
    brow = ~mouth * _smooth(7.8, 8.4, y)
    eye = ~mouth * (1 - _smooth(7.8, 8.4, y)) * _smooth(5.2, 5.8, y)
    regions = {
        "upper_lip": upper * (1 - _smooth(1.3, 2.0, off)) * lip,
        "lower_lip": lower * (1 - _smooth(-1.3, -2.0, off)) * lip,
        "left_brow": brow * (x > 0), "right_brow": brow * (x < 0),
        "left_eye": eye * (x > 0), "right_eye": eye * (x < 0),
    }
    regions["other"] = 1 - sum(regions.values())
    return (np.stack([bones[b] for b in BONES], axis=1),
            np.stack([regions[r] for r in REQUIRED_REGIONS], axis=1))


def build_default_mask() -> Mask:
    """The project's default Maskle (see the module docstring)."""
    mv, mq, marks, root, tip = _mouth()
    n_upper = len(_UPPER_ROWS) * len(_MOUTH_COLS)
    verts, polys = [mv], [mq]
    for side in (1.0, -1.0):
        ev, eq, em = _eye(side, sum(len(v) for v in verts))
        verts.append(ev)
        polys.append(eq)
        marks.update(em)
    v = np.concatenate(verts)
    tongue_upper_tips = tip[:len(tip) // 2]
    is_upper = np.zeros(len(v), bool)
    is_upper[:n_upper] = True
    is_upper[tongue_upper_tips] = True
    order = np.r_[np.flatnonzero(is_upper), np.flatnonzero(~is_upper)]
    inverse = np.argsort(order)          # renumber: upper band (and its tongue) first
    bones, regions = _paint(v[order], len(mv), int(is_upper.sum()))
    origins = np.full((len(BONES) + len(REQUIRED_REGIONS), 3), np.nan)
    origins[:len(BONES)] = [[0.0, -2.0, -1.0], [1.2, 0.5, 0.3], [-1.2, 0.5, 0.3],
                            [1.2, -0.6, 0.2], [-1.2, -0.6, 0.2],
                            [3.3, 9.2, -0.8], [-3.3, 9.2, -0.8]]
    return Mask(v[order], inverse[np.concatenate(polys)],
                BONES + REQUIRED_REGIONS,
                ("bone",) * len(BONES) + ("region",) * len(REQUIRED_REGIONS),
                np.clip(np.concatenate([bones, regions], axis=1), 0.0, 1.0), origins,
                {k: int(inverse[i]) for k, i in marks.items()}, inverse[root], inverse[tip])


def main() -> None:  # pragma: no cover - the builder's entry point
    """Write the default mask to ``data/default_mask.npz``."""
    mask = build_default_mask()
    save_mask(mask, DEFAULT_MASK_PATH)
    print(f"wrote {DEFAULT_MASK_PATH}: {mask.n_vertices} vertices, "
          f"{len(mask.polygons)} polygons, channels {', '.join(mask.channel_names)}")


if __name__ == "__main__":  # pragma: no cover
    main()
