"""Fuzzing every reader and configuration loader: a valid result or our error, in bounded memory.

10,500 seeded cases (:data:`fuzzing.TEST_COUNTS`: C3D, Vicon CSV, TRC, OBJ, PLY,
take npz, marker set, mesh landmarks, marker layout, binding, run
configuration), each in a forked worker whose address space is limited with
``resource.setrlimit`` and with a timer per case (:mod:`fuzzing`). Any other
exception, a numpy RuntimeWarning, a hang, or a case whose peak memory exceeds
twice its file plus a fixed allowance fails, naming the reader and the case
to replay (``fuzzing.build_targets`` then the case's index).
"""

from __future__ import annotations

import warnings

import fuzzing
import numpy as np
import pytest

from mocap import Take
from mocap.io.c3d import read_c3d
from mocap.util.budget import SLACK_BYTES


@pytest.fixture(scope="module")
def summaries(shared_data, tmp_path_factory):
    if not fuzzing.environment_ok():
        pytest.fail("fuzzing needs Linux: /proc/self/clear_refs and RLIMIT_AS")
    targets = fuzzing.build_targets(shared_data, tmp_path_factory.mktemp("fuzz"),
                                    fuzzing.TEST_COUNTS)
    return fuzzing.run_targets(targets)


def test_at_least_ten_thousand_cases():
    assert sum(fuzzing.TEST_COUNTS.values()) >= 10_000


@pytest.mark.parametrize("name", list(fuzzing.TEST_COUNTS))
def test_every_case_gives_a_result_or_our_error(summaries, name):
    summary = summaries[name]
    assert summary.failures == [], "\n".join(f"case {c}: {o}: {m}"
                                             for c, o, m in summary.failures)
    assert summary.counts["other"] == summary.counts["hang"] == 0
    assert sum(summary.counts.values()) == fuzzing.TEST_COUNTS[name]
    assert summary.counts["valid"] > 0 and summary.counts["error"] > 0   # both paths reached


@pytest.mark.parametrize("name", list(fuzzing.TEST_COUNTS))
def test_no_case_takes_more_memory_than_its_file_justifies(summaries, name):
    peak, size, case = summaries[name].worst_peak
    assert peak <= 2 * size + SLACK_BYTES, f"case {case}: {peak} bytes for a {size}-byte file"


def test_damaged_samples_never_hide_the_layout(shared_data, tmp_path):
    """Bytes changed in the data section of a C3D file still give a Take of the same shape."""
    source = shared_data / "c3d-samples/sample_02/pc_int.c3d"
    buf = source.read_bytes()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        clean = read_c3d(source)
    path = tmp_path / "fuzz.c3d"
    for seed in range(40):
        rng = np.random.default_rng(seed)
        path.write_bytes(fuzzing.flip_bytes(buf, rng, clean.source.extra["data_offset"]))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            warnings.simplefilter("error", RuntimeWarning)
            take = read_c3d(path)
        assert isinstance(take, Take) and take.positions.shape == clean.positions.shape
