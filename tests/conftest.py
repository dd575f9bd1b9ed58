"""Shared fixtures: where the real data made by others lives, and what several test files
load from it (read once per session; every object here is read-only or treated so)."""

from __future__ import annotations

import os
from pathlib import Path

import ezc3d
import pytest
from helpers import (
    FACIAL_SING_MARKERSET_TOML,
    ICT_LANDMARKS_TOML,
    ICT_LAYOUT_TOML,
    ICT_MARKERSET_TOML,
)

import mocap
from basis.artist import load_artist_basis
from fit.demo.face import make_face
from mocap.markerset import load_markerset
from mocap.mesh.landmarks import load_mesh_landmarks
from mocap.mesh.layout import load_marker_layout
from mocap.mesh.mesh import load_mesh
from mocap.synth.performance import read_performance

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


# ---------------------------------------------------------------- the ICT face (cm)

@pytest.fixture(scope="session")
def ict_dir(shared_data) -> Path:
    """The ICT-FaceKit folder: the neutral mesh, 53 expressions, vertex_indices.json."""
    return shared_data / "ict-face"


@pytest.fixture(scope="session")
def ict_neutral_path(ict_dir) -> Path:
    """The ICT neutral mesh file (OBJ of quads, cm)."""
    return ict_dir / "generic_neutral_mesh.obj"


@pytest.fixture(scope="session")
def ict_expressions_dir(ict_dir) -> Path:
    """The folder of the 53 ICT expression OBJ files."""
    return ict_dir / "expressions"


@pytest.fixture(scope="session")
def ict_mesh(ict_neutral_path):
    """The ICT neutral face as a ``Mesh`` in cm (9409 vertices)."""
    return load_mesh(ict_neutral_path, units="cm")


@pytest.fixture(scope="session")
def ict_basis(ict_neutral_path, ict_expressions_dir):
    """The ``ArtistBasis`` of the 53 ICT expressions, in cm."""
    return load_artist_basis(ict_neutral_path, ict_expressions_dir, units="cm")


@pytest.fixture(scope="session")
def ict_landmarks(ict_mesh) -> dict[str, int]:
    """The ICT mesh landmarks (anatomical point -> vertex id) of tests/ict_landmarks.toml."""
    return load_mesh_landmarks(ICT_LANDMARKS_TOML, ict_mesh)


@pytest.fixture(scope="session")
def ict_layout(ict_mesh):
    """The 66-marker ``MarkerLayout`` of tests/ict_marker_layout.toml on the ICT mesh."""
    return load_marker_layout(ICT_LAYOUT_TOML, ict_mesh)


@pytest.fixture(scope="session")
def ict_markerset():
    """The ``MarkerSet`` of the ICT layout (tests/ict_markerset.toml)."""
    return load_markerset(ICT_MARKERSET_TOML)


# ---------------------------------------------------------------- real captures

@pytest.fixture(scope="session")
def facial_sing_path(shared_data) -> Path:
    """The facial-sing.c3d capture (38 markers, 3000 frames at 100 Hz)."""
    return shared_data / "captures" / "facial-sing.c3d"


@pytest.fixture(scope="session")
def facial_sing_take(facial_sing_path):
    """facial-sing.c3d read as a ``Take`` (``mocap.read``)."""
    return mocap.read(facial_sing_path)


@pytest.fixture(scope="session")
def facial_sing_markerset():
    """The ``MarkerSet`` of facial-sing.c3d (tests/facial_sing_markerset.toml)."""
    return load_markerset(FACIAL_SING_MARKERSET_TOML)


@pytest.fixture(scope="session")
def vicon_nexus_dir(shared_data) -> Path:
    """The Vicon Nexus session: markers.c3d, markers.csv (the same trial) and markers.trc."""
    return shared_data / "vicon-nexus"


@pytest.fixture(scope="session")
def vicon_nexus_ezc3d(vicon_nexus_dir):
    """vicon-nexus/markers.c3d as ezc3d reads it (an ``ezc3d.c3d``): the oracle of our readers."""
    return ezc3d.c3d(str(vicon_nexus_dir / "markers.c3d"))


@pytest.fixture(scope="session")
def vicon_nexus_take(vicon_nexus_dir):
    """vicon-nexus/markers.c3d read as a ``Take`` (``mocap.read``)."""
    return mocap.read(vicon_nexus_dir / "markers.c3d")


@pytest.fixture(scope="session")
def arkit_performance_path(shared_data) -> Path:
    """A Live Link Face (ARKit) performance CSV, alex_rom_3.csv (52 weights, 30 Hz)."""
    return shared_data / "arkit-performances" / "alex_rom_3.csv"


@pytest.fixture(scope="session")
def arkit_performance(arkit_performance_path):
    """alex_rom_3.csv read as a ``Performance``."""
    return read_performance(arkit_performance_path)


# ---------------------------------------------------------------- generated data

@pytest.fixture(scope="session")
def demo_face():
    """The demo face (``fit.demo.face.make_face()``: mesh in mm, landmarks, lip chains)."""
    return make_face()
