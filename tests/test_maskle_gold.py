"""Gold weights of the Maskle bench: the mouth sides against independent criteria."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree
from tolerances import EXACT_FLOAT64, MOUTH_SIDE_AT_LANDMARK

from basis.artist import load_artist_basis
from basis.maskle.gold import DEMO_GOLD_SHAPES, GOLD_SHAPES, gold_weights, mouth_sides
from fit.demo.face import MOUTH, mouth_line
from fit.demo.muscles import muscle_basis
from mocap.errors import InputError
from mocap.mesh.mesh import boundary_loops


@pytest.fixture(scope="module")
def gold_basis(ict_mesh, ict_expressions_dir):
    """The ICT expressions the gold weights are made of, and jawOpen (cm)."""
    names = sorted({s for shapes in GOLD_SHAPES.values() for s in shapes} | {"jawOpen"})
    return load_artist_basis(ict_mesh, ict_expressions_dir, names=names)


def test_demo_face_sides_follow_its_lip_line(demo_face):
    face = demo_face
    side = mouth_sides(face.mesh, face.landmarks)
    x, y = face.mesh.vertices[:, 0], face.mesh.vertices[:, 1]
    above = y - mouth_line(x)                    # the generator's own lip contact line, mm
    near = np.abs(x) < MOUTH["half_width"] + 10.0
    far = near & (np.abs(above) > 2.0)
    np.testing.assert_array_equal(side[far] > 0.5, above[far] > 0)
    clear = near & (np.abs(above) > 5.0)
    assert np.all((side[clear] >= 0.9) | (side[clear] <= 0.1))
    assert side[face.upper_lip].min() >= 0.9 and side[face.lower_lip].max() <= 0.1


def test_demo_gold_from_its_own_muscles(demo_face):
    face = demo_face
    bones = tuple(DEMO_GOLD_SHAPES)
    gold = gold_weights(muscle_basis(face), face.landmarks, bones, shapes=DEMO_GOLD_SHAPES)
    y = face.mesh.vertices[:, 1]
    assert gold.shape == (face.mesh.n_vertices, len(bones))
    np.testing.assert_allclose(gold.max(axis=0), 1.0)
    assert np.all(gold[y > 8.0, bones.index("jaw")] == 0)        # the jaw's reach ends there
    brows = [bones.index("brow_left"), bones.index("brow_right")]
    assert np.all(gold[y < 30.0][:, brows] == 0)                 # frontalis: above the eyes
    with pytest.raises(InputError, match="no gold shapes for bone lower_lip_left"):
        gold_weights(muscle_basis(face), face.landmarks, ("lower_lip_left",),
                     shapes=DEMO_GOLD_SHAPES)


def test_ict_sides_agree_with_the_jaw(gold_basis, ict_landmarks):
    """Near the mouth, the clear lower side is what jawOpen drops, the upper side stays."""
    basis, marks = gold_basis, ict_landmarks
    mesh = basis.neutral
    side = mouth_sides(mesh, marks)
    v = mesh.vertices
    loop = min(boundary_loops(mesh),
               key=lambda lp: np.linalg.norm(v[lp] - v[marks["upper_lip_bottom"]], axis=1).min())
    half = np.linalg.norm(v[marks["mouth_corner_left"]] - v[marks["mouth_corner_right"]]) / 2
    lips = (cKDTree(v[loop]).query(v)[0] < 1.0) & (np.abs(v[:, 0]) < 0.9 * half)
    drop = -basis.displacements[basis.index("jawOpen")][:, 1]
    drop /= drop[lips].max()
    upper, lower = lips & (side > 0.9), lips & (side < 0.1)
    assert upper.sum() > 200 and lower.sum() > 200
    assert drop[upper].max() < 1 / 3 < drop[lower].min()
    for name, want in (("upper_lip_top", 1), ("upper_lip_bottom", 1), ("lower_lip_top", 0),
                       ("lower_lip_bottom", 0)):
        assert side[marks[name]] == pytest.approx(want, abs=MOUTH_SIDE_AT_LANDMARK), name


def test_gold_lip_bones_keep_to_their_side(gold_basis, ict_landmarks):
    basis, marks = gold_basis, ict_landmarks
    bones = ("jaw", "upper_lip_left", "lower_lip_left")
    raw = gold_weights(basis, marks, bones, lip_sides=False)
    mags = np.linalg.norm(basis.displacements[basis.index("mouthLowerDown_L")], axis=1)
    np.testing.assert_allclose(raw[:, 2], mags / mags.max(), rtol=EXACT_FLOAT64)
    side = mouth_sides(basis.neutral, marks)
    gold = gold_weights(basis, marks, bones)
    np.testing.assert_array_equal(gold[:, 0], raw[:, 0])         # the jaw is not a lip bone
    np.testing.assert_allclose(gold[:, 1], raw[:, 1] * side, rtol=EXACT_FLOAT64)
    np.testing.assert_allclose(gold[:, 2], raw[:, 2] * (1 - side), rtol=EXACT_FLOAT64)
    # the raw mouthLowerDown_L drags the upper side, the restricted gold does not
    assert raw[side > 0.9, 2].max() > 0.15 and gold[side > 0.9, 2].max() < 0.1


def test_gold_errors(gold_basis, ict_landmarks):
    basis, marks = gold_basis, ict_landmarks
    with pytest.raises(InputError, match="no gold shapes for bone nose"):
        gold_weights(basis, marks, ("nose",))
    partial = {k: i for k, i in marks.items() if k != "lower_lip_top"}
    with pytest.raises(InputError, match="face landmarks lack lower_lip_top"):
        mouth_sides(basis.neutral, partial)
