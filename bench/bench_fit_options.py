"""Benchmark: the fit's temporal and sampling options through ``mocap2mesh run``, against the truth.

A ground-truth session is simulated with ``mocap2mesh synth``: the ICT face
(53 shapes) driven by the real ARKit performance ``alex_rom_4.csv``, the
66-marker layout of ``tests/ict_marker_layout.toml``, 30 Hz, 0.2 mm noise,
head motion, 40 gaps and a 2 s neutral lead-in. ``mocap2mesh run`` then runs
the whole chain on it once per set of fit options (``bind.frame = "hold"``,
marker space, H bounds [0, 1], no video), and this script reads back what
``run`` wrote: ``weights-H.csv`` and ``manifest.json``.

Options: the exact solver (frames independent); temporal smoothness λ
(``fit.smoothness``: Σ ½‖B w_t − d_t‖² + ½ λ Σ ‖w_t − w_{t−1}‖², solved
exactly over the take), at fixed λ (a sweep, shown, never picked on the
truth) and chosen by generalized cross-validation (``fit.smoothness =
"gcv"``, per basis, without the truth; its λ for H read from the
manifest's metrics); the gestures paper's centred moving average of the
markers before solving (``fit.moving_average``, its 41 frames, and 11); the
paper's sampling estimator (``fit.h_solver = "sampling"``, 1000 samples,
60 neighbours), alone and after the 41-frame average as in the paper.

Columns: RMSE of the H weights against the true weights and against the
exact solver's; the marker RMS error (mm) of the reconstruction against the
captured markers (from the manifest); the fit stage's time and the whole
run's (wall clock, both from the same run), and the fit time over the exact
one's. The exact and the GCV fits, which the speed aim compares (GCV ≤ 2×
exact), run ``PAIRS`` times, alternated: their fit times are the medians, and
each pair's ratio is printed under the table; so are those of the same two fits
run warm in this process (:func:`warm_fit_seconds`: a fresh ``run`` adds the same
fixed costs to both, which flatters the ratio). All λ values tried are shown:
none was picked on the truth.

Usage: ``python bench/bench_fit_options.py`` (writes into bench/out/fit-options).
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
import time
import warnings
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from _common import REPO, memory_as_the_command, shared_data  # noqa: E402

import mocap  # noqa: E402
from fit.cli.main import main as cli  # noqa: E402
from fit.pipeline import Reconstruction, basis_stage, fit_stage  # noqa: E402
from mocap.synth.capture import load_capture_truth  # noqa: E402

OUT = REPO / "bench" / "out" / "fit-options"
MAX_GAP_FRAMES = 60
VARIANTS = (
    ("exact", {}),
    *((f"smoothness λ = {lam:g}", {"smoothness": lam})
      for lam in (0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0, 1000.0)),
    ("smoothness GCV", {"smoothness": "gcv"}),
    ("moving average 11", {"moving_average": 11}),
    ("moving average 41 (paper)", {"moving_average": 41}),
    ("sampling 1000/60 (paper)", {"h_solver": "sampling"}),
    ("moving average 41 + sampling", {"moving_average": 41, "h_solver": "sampling"}),
)


def simulate(root: Path) -> tuple[Path, Path]:
    ict = root / "ict-face"
    capture, truth = OUT / "alex_rom_4.c3d", OUT / "alex_rom_4.truth.npz"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")             # TongueOut: no ICT shape
        code = cli(["synth", "--mesh", str(ict / "generic_neutral_mesh.obj"),
                    "--shapes", str(ict / "expressions"),
                    "--performance", str(root / "arkit-performances" / "alex_rom_4.csv"),
                    "--layout", str(REPO / "tests" / "ict_marker_layout.toml"),
                    "--markerset", str(REPO / "tests" / "ict_markerset.toml"),
                    "-o", str(capture), "--truth", str(truth), "--rate", "30",
                    "--noise", "0.2", "--gaps", "40", "--seed", "1", "--neutral-lead", "2"])
    if code:
        sys.exit(f"mocap2mesh synth failed with exit code {code}")
    return capture, truth


def config_text(root: Path, capture: Path, output: Path, fit: dict) -> str:
    ict = root / "ict-face"
    fit_lines = "".join(f"{key} = {json.dumps(value)}\n" for key, value in fit.items())
    return (f'[inputs]\ncaptures = ["{capture}"]\n'
            f'markerset = "{REPO / "tests" / "ict_markerset.toml"}"\n'
            f'mesh = "{ict / "generic_neutral_mesh.obj"}"\nmesh_units = "cm"\n'
            f'landmarks = "{REPO / "tests" / "ict_landmarks.toml"}"\n'
            f'basis = "{ict / "expressions"}"\n\n'
            f'[output]\ndirectory = "{output}"\n\n[run]\nworkers = 1\n\n'
            # synth's 40 gaps last up to 1 s: fill them all (the default is 0.1 s)
            f'[ingest]\nmax_gap = {MAX_GAP_FRAMES}\n\n'
            f'[bind]\nframe = "hold"\nskin_offset = 2.0\n\n'
            f'[fit]\nspace = "marker"\n{fit_lines}\n[report]\nvideo = false\n')


def run_variant(root, capture, index, fit):
    output = OUT / f"run-{index}"
    shutil.rmtree(output, ignore_errors=True)
    config = OUT / f"run-{index}.toml"
    config.write_text(config_text(root, capture, output, fit), encoding="utf-8")
    tic = time.perf_counter()
    done = subprocess.run([str(Path(sys.executable).parent / "mocap2mesh"), "run", str(config)],
                          capture_output=True, text=True)
    seconds = time.perf_counter() - tic
    if done.returncode:
        sys.exit(f"mocap2mesh run {config} failed ({done.returncode}): {done.stderr}")
    take = json.loads((output / "manifest.json").read_text())["takes"][capture.stem]
    weights = pd.read_csv(output / capture.stem / "weights-H.csv", index_col="frame")
    return weights.drop(columns="time"), take, seconds


#: The variants the speed aim compares (GCV ≤ 2× exact).
COMPARED = ("exact", "smoothness GCV")
#: Runs of the exact and the GCV variants, alternated: their fit times are the medians
#: (this machine's speed changes from one minute to the next; one run each is noise).
PAIRS = 3


def warm_fit_seconds(root: Path, capture: Path) -> dict:
    """The fit stage of the exact and the GCV options in this process, on the take as
    ``run`` prepares it with the configuration of :func:`config_text`: each run once first
    (numba's kernels loaded, the memory touched), then alternated ``PAIRS`` times; label
    to its seconds, run by run.

    A fresh ``run`` adds the same fixed costs to both fits (about 0.4 s on this take: the
    first load of compiled kernels, the first touch of memory): the ratio of the warm fits
    is the solvers' own."""
    config = OUT / "warm.toml"
    config.write_text(config_text(root, capture, OUT / "warm", {}), encoding="utf-8")
    reconstruction = Reconstruction.from_config(config)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        prepared = reconstruction.prepare(capture)
        bases = basis_stage(prepared.retargeted, reconstruction.basis,
                            options=reconstruction.basis_options)
        options = {label: dataclasses.replace(reconstruction.fit, **fit)
                   for label, fit in VARIANTS if label in COMPARED}
        seconds = {label: [] for label in options}
        for rounds in (1, PAIRS):
            for _ in range(rounds):
                for label, fit in options.items():
                    tic = time.perf_counter()
                    fit_stage(prepared.take, prepared.bound, prepared.retargeted, bases,
                              options=fit)
                    seconds[label].append(time.perf_counter() - tic)
    return {label: times[1:] for label, times in seconds.items()}


def main() -> None:
    memory = memory_as_the_command()      # this script calls the command's main in-process
    root = shared_data()
    OUT.mkdir(parents=True, exist_ok=True)
    capture, truth_path = simulate(root)
    truth = load_capture_truth(truth_path)
    first = mocap.read(capture).first_frame
    print(f"alex_rom_4 onto ICT: {truth.n_frames} frames at {truth.rate:g} Hz (2 s neutral "
          f"lead-in), 60 face markers, 0.2 mm noise, 40 gaps; mocap2mesh run per option set, "
          f"bind.frame = 'hold', marker space, H in [0, 1]; "
          f"BLAS threads {os.environ['OPENBLAS_NUM_THREADS']}; {memory}\n")
    # the exact and GCV fits alternated PAIRS times first: the aim compares them
    paired = {label: [] for label in COMPARED}
    for _ in range(PAIRS):
        for index, (label, fit) in enumerate(VARIANTS):
            if label in paired:
                paired[label].append(run_variant(root, capture, index, fit))
    print(f"{'fit options':<30} {'λ of H':>8} {'RMSE w':>7} {'vs exact':>8} {'marker mm':>9} "
          f"{'fit s':>6} {'× exact':>7} {'run s':>6}")
    exact = exact_fit = None
    for index, (label, fit) in enumerate(VARIANTS):
        runs = paired.get(label) or [run_variant(root, capture, index, fit)]
        weights, take, seconds = runs[-1]
        true = pd.DataFrame(truth.weights[weights.index - first], index=weights.index,
                            columns=list(truth.shape_names))[weights.columns]
        w = weights.to_numpy()
        fit_s = float(np.median([run[1]["stage_seconds"]["fit"] for run in runs]))
        if exact is None:
            exact, exact_fit = w, fit_s
        print(f"{label:<30} {take['metrics']['H']['smoothness']:>8.3g} "
              f"{np.sqrt(np.mean((w - true.to_numpy()) ** 2)):>7.4f} "
              f"{np.sqrt(np.mean((w - exact) ** 2)):>8.4f} "
              f"{take['metrics']['H']['rms_mm']:>9.3f} {fit_s:>6.2f} "
              f"{fit_s / exact_fit:>7.2f} {seconds:>6.1f}")
    pairs = [(g[1]["stage_seconds"]["fit"], e[1]["stage_seconds"]["fit"])
             for e, g in zip(paired["exact"], paired["smoothness GCV"])]
    print(f"\nexact and GCV alternated {PAIRS} times (their rows: the median fit s): GCV fit / "
          f"exact fit per pair {', '.join(f'{g:.2f}/{e:.2f} = {g / e:.2f}' for g, e in pairs)}; "
          f"aim ≤ 2")
    warm = warm_fit_seconds(root, capture)
    print(f"the same fits in this process, warm (each run once before), alternated {PAIRS} "
          f"times: GCV fit / exact fit per pair "
          + ", ".join(f"{g:.2f}/{e:.2f} = {g / e:.2f}"
                      for e, g in zip(warm["exact"], warm["smoothness GCV"]))
          + " (a fresh run adds the same fixed costs to both)")
    print("fit s: the fit stage (H, QE and PCA; the options change only H's solve, the "
          "moving average all three); run s: the whole mocap2mesh run (process start, "
          "ingest .. report)")


if __name__ == "__main__":
    main()
