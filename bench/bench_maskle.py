"""Maskle vs envelope weights against gold weights from the ICT artist shapes.

Gold weights per bone (basis.maskle.gold) on the generic ICT face; the default
mask is repainted from them on the generic face (basis.maskle.paint_mask), and
an envelope baseline is calibrated on the same face (best origins and radii).
Both are then transferred to 8 target faces made from the neutral and random
combinations of the 10 identity modes (coefficients ~ N(0, 2), seed 1), using
only each face's geometry and its ten landmarks. The error is the paper's:
mean absolute weight difference (% of full weight) over the vertices whose
rays hit the mask, per bone, then averaged. No procedural face mesh exists in
the project (fit/demo_session.py makes markers only), so none is used.

    python bench/bench_maskle.py [--pictures DIR]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import REPO, shared_data  # noqa: E402

from basis.artist import load_artist_basis  # noqa: E402
from basis.maskle import (MaskleWeights, calibrate_envelope, fit_mask,  # noqa: E402
                          load_default_mask, paint_mask, transfer_operator)
from basis.maskle.build_default import BONES  # noqa: E402
from basis.maskle.gold import GOLD_SHAPES, gold_weights  # noqa: E402
from basis.maskle.picture import save_weights_picture  # noqa: E402
from mocap.mesh import load_mesh  # noqa: E402
from mocap.mesh_landmarks import load_mesh_landmarks  # noqa: E402

N_FACES, SIGMA, SEED = 8, 2.0, 1
SHORT = ("jaw", "ulL", "ulR", "llL", "llR", "brL", "brR")


def lip_crossings(weights: np.ndarray, gold: np.ndarray, hit: np.ndarray) -> int:
    """Upper-lip vertices (gold) with a lower-lip weight > 0.1, and the reverse."""
    upper, lower = gold[:, 1:3].max(axis=1), gold[:, 3:5].max(axis=1)
    w_upper, w_lower = weights[:, 1:3].max(axis=1), weights[:, 3:5].max(axis=1)
    up = hit & (upper > 0.5) & (lower < 0.1)
    low = hit & (lower > 0.5) & (upper < 0.1)
    return int((up & (w_lower > 0.1)).sum() + (low & (w_upper > 0.1)).sum())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pictures", help="folder for front-view PNGs of the weights")
    args = parser.parse_args()
    ict = shared_data() / "ict-face"
    neutral = load_mesh(ict / "generic_neutral_mesh.obj")
    marks = load_mesh_landmarks(REPO / "tests" / "ict_landmarks.toml", neutral)
    names = sorted({s for shapes in GOLD_SHAPES.values() for s in shapes})
    gold = gold_weights(load_artist_basis(neutral, ict / "expressions", names=names), marks, BONES)
    mask = load_default_mask()
    fit0 = fit_mask(mask, neutral, marks)
    mask = paint_mask(mask, fit0, neutral, gold, BONES)
    envelope = calibrate_envelope(neutral.vertices, gold, fit0)
    bone_cols = [mask.channel_names.index(b) for b in BONES]
    modes = np.stack([load_mesh(ict / "identities" / f"identity{k:03d}.obj").vertices
                      - neutral.vertices for k in range(10)])
    rng = np.random.default_rng(SEED)
    faces = [("generic", neutral)] + [
        (f"id-mix {i}", neutral.with_vertices(neutral.vertices + np.tensordot(
            rng.normal(0.0, SIGMA, len(modes)), modes, axes=1))) for i in range(N_FACES)]
    print(f"mask: {mask.n_vertices} vertices, {len(mask.polygons)} polygons; "
          f"target faces: {N_FACES} identity mixes (coefficients ~ N(0, {SIGMA:g})) + generic")
    head = " ".join(f"{s:>5}" for s in SHORT)
    print(f"{'face':<10} {'method':<8} {head}  {'mean%':>6} {'cross':>5} {'time s':>6}  fit")
    rows = []
    for name, face in faces:
        start = time.perf_counter()
        fit = fit_mask(mask, face, marks)
        op = transfer_operator(mask, fit, face)
        ours = op.apply(mask.weights[:, bone_cols])
        t_ours = time.perf_counter() - start
        start = time.perf_counter()
        env = envelope.weights(face.vertices, fit)
        t_env = time.perf_counter() - start
        hit = op.hit
        per = {}
        for method, w, dt in (("maskle", ours, t_ours), ("envelope", env, t_env)):
            err = np.abs(w[hit] - gold[hit]).mean(axis=0) * 100
            per[method] = err.mean()
            cells = " ".join(f"{e:5.2f}" for e in err)
            extra = f"{fit.status} ({fit.n_iterations} it)" if method == "maskle" else \
                "(+ maskle placement)"
            print(f"{name:<10} {method:<8} {cells}  {err.mean():6.2f} "
                  f"{lip_crossings(w, gold, hit):5d} {dt:6.2f}  {extra}")
        rows.append((name, per["maskle"], per["envelope"], t_ours, int(hit.sum())))
        if args.pictures and name in ("generic", "id-mix 0"):
            folder = Path(args.pictures)
            folder.mkdir(parents=True, exist_ok=True)
            for method, w in (("maskle", ours), ("envelope", np.where(hit[:, None], env,
                                                                      np.nan))):
                res = MaskleWeights(BONES, ("bone",) * len(BONES), w, hit, op.missed, fit)
                save_weights_picture(face, res, folder / f"{name.replace(' ', '')}_{method}.png",
                                     title=f"{name}: {method}", mask_vertices=fit.vertices)
    targets = rows[1:]
    ours = np.array([r[1] for r in targets])
    env = np.array([r[2] for r in targets])
    print()
    print(f"{'':<22} {'maskle':>8} {'envelope':>9} {'ratio':>6}")
    print(f"{'mean over targets %':<22} {ours.mean():8.2f} {env.mean():9.2f} "
          f"{env.mean() / ours.mean():6.2f}")
    print(f"{'best / worst %':<22} {ours.min():4.2f}/{ours.max():4.2f} "
          f"{env.min():5.2f}/{env.max():4.2f}")
    print(f"{'paper %':<22} {'2.63':>8} {'8.73':>9} {8.73 / 2.63:6.2f}")
    print(f"time per face (fit + transfer): mean {np.mean([r[3] for r in targets]):.2f} s, "
          f"max {max(r[3] for r in targets):.2f} s; hit vertices "
          f"{min(r[4] for r in targets)}-{max(r[4] for r in targets)}")


if __name__ == "__main__":
    main()
