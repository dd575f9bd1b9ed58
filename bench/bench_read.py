"""Read the largest C3D files of the corpus with our reader and with ezc3d, side by side.

    python bench/bench_read.py

Prints, per file, the best of 5 reads (s) for ours and ezc3d, the ratio
ours/ezc3d (< 1 means ours is faster) and our peak traced memory. The largest
files ezc3d opens are compared; ezc3d cannot open facial-sing.c3d (non-standard
parameter section), the MIPS files and bad_parameter_section.c3d (it crashes with
ignore_bad_formatting), so those rows have ours only.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ezc3d  # noqa: E402
from _common import best_time, peak_memory_mb, shared_data  # noqa: E402

from mocap.io.c3d import read_c3d  # noqa: E402

COMPARED = ["vicon-nexus/markers.c3d", "c3d-samples/sample_33/bigparlove.c3d",
            "c3d-samples/sample_01/Eb015pr.c3d", "c3d-samples/sample_01/Eb015vr.c3d",
            "c3d-samples/sample_01/Eb015pi.c3d"]
OURS_ONLY = ["captures/facial-sing.c3d", "c3d-samples/sample_18/bad_parameter_section.c3d",
             "c3d-samples/sample_01/Eb015sr.c3d"]
REPEAT = 5


def _ours(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return read_c3d(path)


def main() -> None:
    data = shared_data()
    rows = [(data / name, True) for name in COMPARED] + \
        [(data / name, False) for name in OURS_ONLY]
    print(f"{'file':<50}{'MB':>6}{'frames':>8}{'ours s':>10}{'ezc3d s':>10}"
          f"{'ours/ez':>9}{'ours MB':>9}")
    for path, with_ezc3d in rows:
        take = _ours(path)
        ours = best_time(lambda: _ours(path), repeat=REPEAT)
        theirs = best_time(lambda: ezc3d.c3d(str(path)), repeat=REPEAT) if with_ezc3d else None
        memory = peak_memory_mb(lambda: _ours(path))
        name = str(path.relative_to(data))
        ez = f"{theirs:10.4f}{ours / theirs:9.2f}" if theirs else f"{'fails':>10}{'-':>9}"
        print(f"{name:<50}{path.stat().st_size / 1e6:6.2f}{take.n_frames:8d}{ours:10.4f}{ez}"
              f"{memory:9.1f}")


if __name__ == "__main__":
    main()
