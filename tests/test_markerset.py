"""Marker-set files: the real one for facial-sing.c3d and every error path."""

import pytest
from helpers import TESTS_DIR

from mocap.errors import FileFormatError, MarkerError
from mocap.markerset import REQUIRED_REGIONS, load_markerset

GOOD = """
name = "t"
head = ["h1", "h2", "h3"]
[regions]
upper_lip = ["u1"]
lower_lip = ["l1"]
left_brow = []
right_brow = []
left_eye = []
right_eye = []
other = ["c"]
[landmarks]
mouth_corner_left = "u1"
"""


def write(tmp_path, text):
    path = tmp_path / "ms.toml"
    path.write_text(text)
    return path


def test_good_file(tmp_path):
    ms = load_markerset(write(tmp_path, GOOD))
    assert ms.head == ("h1", "h2", "h3")
    assert ms.face_markers == ("u1", "l1", "c")
    assert ms.region_of("l1") == "lower_lip" and ms.region_of("h2") == "head"
    assert ms.clusters["head"] == ms.head
    with pytest.raises(MarkerError, match="'zz': not in marker set"):
        ms.region_of("zz")
    with pytest.raises(MarkerError, match="absent: l1, c"):
        ms.check_labels(["h1", "h2", "h3", "u1"])


@pytest.mark.parametrize("old, new, message", [
    ('head = ["h1", "h2", "h3"]', 'head = ["h1", "h2"]', "needs at least 3"),
    ('other = ["c"]', 'other = ["c", "u1"]', "'u1' is in both 'upper_lip' and 'other'"),
    ("left_eye = []\n", "", "lacks left_eye"),
    ('mouth_corner_left = "u1"', 'mouth_corner = "u1"', "unknown anatomical point 'mouth_corner'"),
    ('mouth_corner_left = "u1"', 'mouth_corner_left = "x"', "names marker 'x'"),
    ('name = "t"', 'nmae = "t"', "unknown keys"),
    ('name = "t"', 'name = "t', "not valid TOML"),
    ("[landmarks]", '[clusters]\nn = ["u1", "l1"]\n[landmarks]', "cluster 'n' must name at least 3"),
])
def test_errors(tmp_path, old, new, message):
    assert old in GOOD
    with pytest.raises(FileFormatError, match=message):
        load_markerset(write(tmp_path, GOOD.replace(old, new)))


@pytest.mark.parametrize("name", ["facial_sing_markerset.toml"])
def test_shipped_markersets_are_valid(name):
    ms = load_markerset(TESTS_DIR / name)
    assert set(REQUIRED_REGIONS) <= set(ms.regions)
