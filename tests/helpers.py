"""Helpers shared by several test files (not fixtures: those are in conftest.py)."""

from __future__ import annotations

from pathlib import Path

TESTS_DIR = Path(__file__).resolve().parent
#: The files kept beside the tests: the ICT face's marker layout, marker set and mesh
#: landmarks, and the marker set of facial-sing.c3d.
ICT_LAYOUT_TOML = TESTS_DIR / "ict_marker_layout.toml"
ICT_MARKERSET_TOML = TESTS_DIR / "ict_markerset.toml"
ICT_LANDMARKS_TOML = TESTS_DIR / "ict_landmarks.toml"
FACIAL_SING_MARKERSET_TOML = TESTS_DIR / "facial_sing_markerset.toml"
