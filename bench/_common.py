"""Helpers shared by the benchmark scripts: data location, timing, peak memory."""

from __future__ import annotations

import os
import sys
import time
import tracemalloc
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
#: The longest gap the benchmarks fill in facial-sing.c3d, frames: its longest face-marker
#: gap is 192 frames (1.92 s), far beyond the default maximum gap, and they fill it.
FACIAL_SING_MAX_GAP = 200


def shared_data() -> Path:
    """``$MOCAP2MESH_SHARED_DATA`` or ``../shared/data``; exit with a message if absent."""
    env = os.environ.get("MOCAP2MESH_SHARED_DATA")
    path = Path(env) if env else REPO.parent / "shared" / "data"
    if not path.is_dir():
        sys.exit(f"benchmark needs the real data: {path} not found "
                 "(set MOCAP2MESH_SHARED_DATA)")
    return path


def best_time(fn, *, repeat: int = 3) -> float:
    """Best wall-clock time of `repeat` calls of ``fn()``, seconds."""
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def peak_memory_mb(fn) -> float:
    """Peak memory allocated through Python/NumPy during ``fn()``, MB (tracemalloc)."""
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()
