"""Benchmark: the exports of one basis of a 35,000-frame take, against writing their bytes.

As ``bench_chain.py``'s exports stage writes them for each basis: the weights CSV
(:func:`fit.exports.write_weights_csv`), the compact mesh sequence npz
(:func:`fit.exports.write_mesh_sequence`) and the animated ``.glb``
(:func:`basis.gltf.write_gltf`), here of the 53 ICT expressions on the 9,409-vertex ICT
face, with signed weights (so the ``.glb`` carries ``.neg`` targets); the npz also with
the head's motion that ``mocap2mesh run`` stores in it (a rotation and a translation a
frame, float64, written as they are). Each is timed
against ``numpy.ndarray.tofile`` of the bytes it wrote (the file read back as one
uint8 array), alternately in one run (best of three each), so that a load on the
machine weighs on both; both write new files (as the exports of a new take), and the
``.glb`` is timed again over an existing file. The CSV is text: it is also timed
against ``repr`` of every float it holds joined into one string (Python's own
formatting of the same text, number by number: the shortest that reads back exactly),
which is not its floor: :mod:`mocap.util.float_text` formats whole arrays, by NumPy in a
process that has not loaded numba (the table's 1.9M cells do not pay for loading it), by
its compiled kernel in one that has (``mocap2mesh run``, whose fit loads it); both are
timed. A zip member carries the CRC-32 of its bytes: the npz's CRC-32 alone (the writer's,
zlib-ng's with the speed extra and then zlib's too, on one thread; the writer's threads sum
the parts they write) is printed under it,
the npz's floor where it takes longer than writing the bytes; and, since its float32
members are made from float64, the time of converting and writing as many floats plus the
CRC-32, halved (the least two cores could take for the file's work). The ``.glb``'s floats are
float32 made from float64 values: as many float64 converted by NumPy a block at a time and
written are printed under it, the floor of any writer that starts from float64.

Run: ``python bench/bench_exports.py [--frames 35000]``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import zlib
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import best_time, scratch_directory, shared_data  # noqa: E402

from basis.gltf import write_gltf  # noqa: E402
from fit.exports import write_mesh_sequence, write_weights_csv  # noqa: E402
from mocap.mesh.mesh import Mesh  # noqa: E402
from mocap.util.float_text import compiled_lines_ready  # noqa: E402
from mocap.util.npz import crc32 as npz_crc32  # noqa: E402
from mocap.util.optional import available  # noqa: E402

RATE = 276.0
#: Whose CRC-32 the npz writer sums.
CRC_SOURCE = (f"zlib {zlib.ZLIB_RUNTIME_VERSION}" if npz_crc32 is zlib.crc32
              else f"zlib-ng {importlib.import_module('zlib_ng.zlib_ng').ZLIBNG_VERSION}")
N_SHAPES = 53


def alternately(fn, floor, *, fresh=()) -> tuple[float, float]:
    """Best of three of ``fn()`` and of ``floor()``, s, timed one after the other, each
    into new files (the files of `fresh` removed before each call, untimed)."""
    def into_new_files(call):
        for path in fresh:
            path.unlink(missing_ok=True)
        return best_time(call, repeat=1)

    times = [(into_new_files(fn), into_new_files(floor)) for _ in range(3)]
    return tuple(min(column) for column in zip(*times))


#: float64 values converted to float32 and written at a time by :func:`write_converted`.
CONVERTED_BLOCK = 1 << 20


def write_converted(sources: np.ndarray, path: Path) -> None:
    """Write `sources` (float64) as float32 to `path`, converted a block at a time into one
    buffer (what a writer whose values are float64 must do before its bytes exist), then
    remove the file."""
    block = np.empty(CONVERTED_BLOCK, np.float32)
    with open(path, "wb") as fh:
        for first in range(0, len(sources), CONVERTED_BLOCK):
            part = sources[first:first + CONVERTED_BLOCK]
            stored = block[:len(part)]
            np.copyto(stored, part, casting="same_kind")
            fh.write(stored)
    path.unlink()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=35_000)
    args = parser.parse_args()
    face = trimesh.load(shared_data() / "ict-face" / "generic_neutral_mesh.obj", process=False)
    neutral = Mesh(np.asarray(face.vertices), np.asarray(face.faces), units="cm")
    rng = np.random.default_rng(0)
    displacements = rng.normal(0.0, 0.1, (N_SHAPES, neutral.n_vertices, 3))   # cm
    weights = rng.normal(0.3, 0.5, (args.frames, N_SHAPES))
    names = [f"shape_{i:02d}" for i in range(N_SHAPES)]
    # the head's motion, which `mocap2mesh run` stores with each sequence (float64)
    head = dict(rotation=Rotation.from_rotvec(rng.normal(0.0, 0.1, (args.frames, 3))).as_matrix(),
                translation=rng.normal(0.0, 2.0, (args.frames, 3)))
    out = scratch_directory("bench_exports_")
    print(f"{args.frames} frames, {N_SHAPES} shapes, ICT face {neutral.n_vertices} vertices")

    exports = {
        "weights CSV": (out / "weights.csv", lambda path: write_weights_csv(
            path, weights, names, rate=RATE)),
        "mesh sequence npz (compact)": (out / "mesh.npz", lambda path: write_mesh_sequence(
            path, neutral, displacements, weights, names=names, rate=RATE)),
        "  with the head motion (run's)": (out / "mesh-head.npz", lambda path: (
            write_mesh_sequence(path, neutral, displacements, weights, names=names,
                                rate=RATE, **head))),
        "glb (morph targets + weights)": (out / "face.glb", lambda path: write_gltf(
            path, neutral, displacements, names, weights=weights, rate=RATE)),
    }
    print(f"\n{'export':<32}{'MB':>8}{'ours [s]':>10}{'tofile [s]':>12}{'ratio':>8}")
    for name, (path, write) in exports.items():
        write(path)
        data = np.fromfile(path, dtype=np.uint8)
        ours, floor = alternately(lambda: write(path),
                                  lambda: data.tofile(out / "same-bytes.bin"),
                                  fresh=(path, out / "same-bytes.bin"))
        print(f"{name:<32}{data.size / 1e6:>8.1f}{ours:>10.3f}{floor:>12.4f}"
              f"{ours / floor:>8.1f}", flush=True)
        if path.name == "mesh.npz":
            crc = best_time(lambda: npz_crc32(data), repeat=3)
            print(f"{'  its CRC-32 alone':<32}{'':>8}{'':>10}{crc:>12.4f}{ours / crc:>8.1f}"
                  f"   ({CRC_SOURCE}: the zip format's own pass)")
            if npz_crc32 is not zlib.crc32:
                stdlib = best_time(lambda: zlib.crc32(data), repeat=3)
                print(f"{'  the same by zlib':<32}{'':>8}{'':>10}{stdlib:>12.4f}"
                      f"{ours / stdlib:>8.1f}   (zlib {zlib.ZLIB_RUNTIME_VERSION}, "
                      "the writer's without the speed extra)")
            # its float32 members come from float64: converting and writing them, and the
            # CRC-32, shared perfectly by the cores
            sources = rng.standard_normal(data.size // 4)
            converted = best_time(lambda: write_converted(sources, out / "converted.bin"),
                                  repeat=3)
            cores = 2
            shared = (converted + crc) / cores
            print(f"{'  its work on two cores':<32}{'':>8}{'':>10}{shared:>12.4f}"
                  f"{ours / shared:>8.1f}   (its floats from float64 converted and written, "
                  f"and its CRC-32, over {cores} cores: {shared / floor:.1f}x tofile)")
        if path.suffix == ".glb":
            sources = rng.standard_normal(data.size // 4)
            converted = best_time(lambda: write_converted(sources, out / "converted.bin"),
                                  repeat=3)
            print(f"{'  its floats from float64':<32}{'':>8}{'':>10}{converted:>12.4f}"
                  f"{ours / converted:>8.1f}   (as many float32 converted by NumPy, "
                  f"{CONVERTED_BLOCK:,} at a time, and written)")

    cells = np.column_stack([np.arange(args.frames) / RATE, weights]).ravel()
    csv_path, write_csv = exports["weights CSV"]
    print(f"\nweights CSV against formatting its {cells.size:,} floats with repr alone:")
    for text in ("NumPy", "compiled"):
        if text == "compiled":
            if not available("numba"):
                print("  compiled text: numba is not installed (the speed extra)")
                break
            import numba  # noqa: F401  (loaded: the CSV text is compiled for any table)
        assert compiled_lines_ready() == (text == "compiled"), "numba loaded by an import"
        ours, floor = alternately(lambda: write_csv(csv_path),
                                  lambda: ",".join(map(repr, cells.tolist())))
        print(f"  {text} text: {ours:.3f} s vs {floor:.3f} s, ratio {ours / floor:.2f}")
    print("aim: npz and glb <= 2x tofile of the same bytes")

    write_glb, over = exports["glb (morph targets + weights)"][1], out / "over.glb"
    write_glb(over)
    data = np.fromfile(over, dtype=np.uint8)
    ours, floor = alternately(lambda: write_glb(over), lambda: data.tofile(over))
    print(f"\nover an existing file (the atomic rename frees the old file, tofile truncates "
          f"it): glb {ours:.3f} s vs tofile {floor:.4f} s, ratio {ours / floor:.1f}")


if __name__ == "__main__":
    main()
