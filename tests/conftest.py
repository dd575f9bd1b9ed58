"""Shared fixtures: where the real data made by others lives."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


def shared_data_dir() -> Path | None:
    """``$MOCAP2MESH_SHARED_DATA`` or ``../shared/data`` beside the repository."""
    env = os.environ.get("MOCAP2MESH_SHARED_DATA")
    path = Path(env) if env else REPO.parent / "shared" / "data"
    return path if path.is_dir() else None


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Root of the real data in ../shared/data; skip when absent, fail under CI."""
    path = shared_data_dir()
    if path is None:
        reason = ("real data not found: set MOCAP2MESH_SHARED_DATA or put the shared "
                  "data at ../shared/data")
        if os.environ.get("CI"):
            pytest.fail(reason + " (CI is set, so this is an error)")
        pytest.skip(reason)  # only when the shared data is absent (never under CI)
    return path
