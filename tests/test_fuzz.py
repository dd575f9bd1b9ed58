"""Fuzzing the C3D reader: mutated and truncated corpus files give a Take or our error.

2,000 seeded cases: 5 source files x 5 kinds of damage x 80 seeds. Each case
must end in a valid Take or a ``Mocap2MeshError``; any other exception (and any
RuntimeWarning from numpy) fails, naming the file, kind and seed to replay.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from mocap import Take
from mocap.errors import Mocap2MeshError
from mocap.io.c3d import read_c3d, write_c3d
from mocap.take import Analog

CORPUS = ["c3d-samples/sample_16/basketball.c3d", "c3d-samples/sample_02/pc_int.c3d",
          "c3d-samples/sample_02/dec_real.c3d", "c3d-samples/sample_02/sgi_int.c3d"]
SOURCES = CORPUS + ["written-by-us"]
KINDS = ("header", "parameters", "data", "truncate", "anywhere")
N_SEEDS = 80


def _source_bytes(shared_data, tmp_path, name) -> bytes:
    if name != "written-by-us":
        return (shared_data / name).read_bytes()
    rng = np.random.default_rng(0)
    positions = rng.uniform(-500, 500, size=(40, 4, 3))
    positions[5:9, 2] = np.nan
    analog = Analog(rng.normal(size=(80, 3)), 200.0, ("a", "b", "c"), ("V", "V", "V"))
    path = tmp_path / "source.c3d"
    write_c3d(Take(("m1", "m2", "m3", "m4"), positions, 100.0, analog=analog), path)
    return path.read_bytes()


def _mutate(buf: bytes, kind: str, data_offset: int, rng) -> bytes:
    if kind == "truncate":
        return buf[:int(rng.integers(0, len(buf)))]
    param_start = (buf[0] - 1) * 512
    lo, hi = {"header": (0, 512), "parameters": (param_start, data_offset),
              "data": (data_offset, len(buf)), "anywhere": (0, len(buf))}[kind]
    out = np.frombuffer(buf, dtype=np.uint8).copy()
    n = int(rng.integers(1, 9))
    out[rng.integers(lo, hi, size=n)] = rng.integers(0, 256, size=n)
    return out.tobytes()


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("name", SOURCES)
def test_mutated_files_give_a_take_or_our_error(shared_data, tmp_path, name, kind):
    buf = _source_bytes(shared_data, tmp_path, name)
    path = tmp_path / "fuzz.c3d"
    path.write_bytes(buf)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        data_offset = read_c3d(path).source.extra["data_offset"]
    outcomes = {"take": 0, "error": 0}
    for seed in range(N_SEEDS):
        rng = np.random.default_rng([seed, KINDS.index(kind), SOURCES.index(name)])
        path.write_bytes(_mutate(buf, kind, data_offset, rng))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            warnings.simplefilter("error", RuntimeWarning)
            try:
                take = read_c3d(path)
            except Mocap2MeshError:
                outcomes["error"] += 1
                continue
            except Exception as exc:  # noqa: BLE001 - the point of the test
                pytest.fail(f"{name} {kind} seed {seed}: {type(exc).__name__}: {exc}")
        assert isinstance(take, Take)
        assert take.positions.shape == (take.n_frames, len(take.labels), 3)
        outcomes["take"] += 1
    assert sum(outcomes.values()) == N_SEEDS
    if kind == "data":                       # damaged samples never hide the layout
        assert outcomes["take"] == N_SEEDS
