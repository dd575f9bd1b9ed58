"""The mouth of a mesh, its lip gap, and the lip-seal check of meshes against lip markers."""

from __future__ import annotations

import re
import sys

import numpy as np
import pytest
from helpers import kernel_or_numpy, numba_cannot_cache, slit_grid
from scipy.spatial import Delaunay
from scipy.spatial.distance import cdist
from tolerances import EXACT_FLOAT64

import mocap.mesh.mouth as mouth_module
from mocap import InputError
from mocap.markerset import MarkerSet
from mocap.mesh.mesh import Mesh
from mocap.mesh.mouth import MouthOpening, find_mouth
from mocap.retarget.lip_seal import LipWitness, check_lip_seal, contradicts, lip_witness

# ---------------------------------------------------------------- the mouth of a mesh

def test_the_demo_mouth_splits_into_the_lip_chains_the_demo_drew(demo_face):
    mouth = find_mouth(demo_face.mesh, demo_face.landmarks)
    assert mouth.method == "loop"
    # the demo knows its lip chains (corners excluded); ours run corner to corner
    assert mouth.upper_edge[1:-1].tolist() in (demo_face.upper_lip.tolist(),
                                               demo_face.upper_lip[::-1].tolist())
    assert set(mouth.lower_edge[1:-1]) == set(demo_face.lower_lip)
    assert mouth.upper_edge[0] == mouth.lower_edge[0]
    assert mouth.upper_edge[-1] == mouth.lower_edge[-1]
    v = demo_face.mesh.vertices
    assert v[mouth.upper, 1].mean() > v[mouth.lower, 1].mean()
    assert set(mouth.upper).isdisjoint(mouth.lower)


def test_the_gap_is_the_smallest_distance_between_the_lips(demo_face):
    mouth = find_mouth(demo_face.mesh, demo_face.landmarks)
    v = demo_face.mesh.vertices
    brute = cdist(v[mouth.upper], v[mouth.lower]).min()
    assert mouth.gap(v[mouth.vertex_ids]) == pytest.approx(brute, abs=EXACT_FLOAT64)
    # the lower lip dropped by 10 mm: the lips part by about that much more
    moved = v[mouth.vertex_ids].copy()
    moved[len(mouth.upper):, 1] -= 10.0
    frames = np.stack([v[mouth.vertex_ids], moved])
    gaps = mouth.gap(frames)
    assert gaps.shape == (2,) and gaps[1] == pytest.approx(
        cdist(moved[:len(mouth.upper)], moved[len(mouth.upper):]).min(), abs=EXACT_FLOAT64)
    assert 9.0 < gaps[1] - gaps[0] <= 10.0
    # lips pushed through each other still have a gap of 0 where they cross
    crossed = v[mouth.vertex_ids].copy()
    crossed[len(mouth.upper):] = crossed[:1]
    assert mouth.gap(crossed) == 0.0


@pytest.fixture(params=["compiled", "numpy"])
def gap_by(request, monkeypatch):
    """The lip gap by numba's loop over the pairs (the `speed` extra, in .[test]) or by
    NumPy's expansion in products of blocks of frames."""
    return kernel_or_numpy(request.param, monkeypatch, mouth_module, "_compiled_gap",
                           "_PAIRS_WORTH_COMPILING")


def test_the_compiled_gap_is_the_least_of_the_pairs_direct_distances(demo_face, monkeypatch):
    """Bit for bit the least of NumPy's squared coordinate differences summed in order (the
    oracle), on lips that part, cross and sit far from the origin (where the expansion
    ‖u‖² + ‖l‖² − 2 u·l would lose digits)."""
    monkeypatch.setattr(mouth_module, "_PAIRS_WORTH_COMPILING", 0)
    mouth = find_mouth(demo_face.mesh, demo_face.landmarks)
    n_up = len(mouth.upper)
    rng = np.random.default_rng(3)
    lips = demo_face.mesh.vertices[mouth.vertex_ids]
    frames = lips + rng.normal(0.0, 2.0, (200,) + lips.shape)
    frames[100:] += rng.normal(0.0, 1e6, (100, 1, 3))        # mm: 1 km from the origin
    up, low = frames[:, :n_up], frames[:, n_up:]
    oracle = ((up[:, :, None] - low[:, None]) ** 2).sum(axis=-1).reshape(200, -1).min(axis=1)
    np.testing.assert_array_equal(mouth.gap(frames), np.sqrt(oracle))


def test_the_gap_of_many_frames_block_by_block_is_each_frames_own(demo_face, monkeypatch,
                                                                  gap_by):
    """Frames go through in blocks of pair distances, in batches of blocks: blocks of 3
    frames, batches of 2 blocks, the last batch and its last block short (NumPy's); the
    compiled loop takes them frame by frame."""
    mouth = find_mouth(demo_face.mesh, demo_face.landmarks)
    n_up, n_low = len(mouth.upper), len(mouth.lower)
    monkeypatch.setattr(mouth_module, "_CHUNK_BYTES", 3 * 8 * n_up * n_low)
    monkeypatch.setattr(mouth_module, "_BLOCKS_PER_BATCH", 2)
    rng = np.random.default_rng(7)
    lips = demo_face.mesh.vertices[mouth.vertex_ids]
    frames = lips + rng.normal(0.0, 2.0, (11,) + lips.shape)           # mm: lips part and cross
    brute = [cdist(f[:n_up], f[n_up:]).min() for f in frames]
    np.testing.assert_allclose(mouth.gap(frames), brute, rtol=0, atol=EXACT_FLOAT64)
    np.testing.assert_allclose(mouth.gap(frames.reshape(11, 1, -1, 3))[:, 0], brute, rtol=0,
                               atol=EXACT_FLOAT64)


def test_the_ict_lips_touch_at_rest_and_part_with_the_jaw(ict_basis, ict_landmarks):
    """The ICT mouth loop curls into the mouth (11 mm open at rest): the gap is the lips'."""
    mesh = ict_basis.neutral
    mouth = find_mouth(mesh, ict_landmarks)
    v = mesh.vertices
    rest = mouth.gap(v[mouth.vertex_ids])
    edges = np.linalg.norm(v[mouth.upper_edge[len(mouth.upper_edge) // 2]]
                           - v[mouth.lower_edge[len(mouth.lower_edge) // 2]])
    assert 10 * rest < 1.5 < 10 * edges                                  # mm: touch; loop open
    jaw = v + ict_basis.displacements[ict_basis.names.index("jawOpen")]
    assert 10 * mouth.gap(jaw[mouth.vertex_ids]) > 25.0
    assert 10 * mouth.gap((v + ict_basis.displacements[ict_basis.names.index(
        "mouthPress_L")])[mouth.vertex_ids]) < 1.5


def test_a_mesh_without_a_mouth_opening_measures_between_landmarks():
    v, f, _, _ = slit_grid(n=21, slit=0.0)
    ids = [int(np.argmin(np.linalg.norm(v[:, :2] - p, axis=1)))
           for p in ([0.6, 0.5], [0.4, 0.5], [0.5, 0.55], [0.5, 0.45])]
    landmarks = dict(zip(["mouth_corner_left", "mouth_corner_right", "upper_lip_bottom",
                          "lower_lip_top"], ids))
    mouth = find_mouth(Mesh(v, f), landmarks)
    assert mouth.method == "landmarks" and len(mouth.upper_edge) == 0
    assert mouth.gap(v[mouth.vertex_ids]) == pytest.approx(np.linalg.norm(v[ids[2]] - v[ids[3]]))
    del landmarks["upper_lip_bottom"]
    landmarks["upper_lip_top"] = ids[2]
    with pytest.raises(InputError, match="has no mouth opening .* and no landmarks "
                                         "upper_lip_bottom and lower_lip_top"):
        find_mouth(Mesh(v, f), landmarks)


def _hexagonal_hole():
    """A triangular lattice with its centre vertex's six triangles removed."""
    rows = [(i + 0.5 * (j % 2), j * np.sqrt(3) / 2) for j in range(-4, 5) for i in range(-4, 5)]
    points = np.array(rows)
    tri = Delaunay(points).simplices
    centre = int(np.argmin(np.linalg.norm(points, axis=1)))
    faces = tri[~np.any(tri == centre, axis=1)]
    v = np.c_[points, np.zeros(len(points))]
    ring = np.unique(tri[np.any(tri == centre, axis=1)])
    ring = ring[ring != centre]
    left, right = ring[np.argmax(v[ring, 0])], ring[np.argmin(v[ring, 0])]
    up, down = ring[np.argmax(v[ring, 1])], ring[np.argmin(v[ring, 1])]
    keep = np.unique(faces)
    remap = -np.ones(len(v), dtype=np.int64)
    remap[keep] = np.arange(len(keep))
    landmarks = {"mouth_corner_left": int(remap[left]), "mouth_corner_right": int(remap[right]),
                 "upper_lip_bottom": int(remap[up]), "lower_lip_top": int(remap[down])}
    return Mesh(v[keep], remap[faces]), landmarks


@pytest.mark.parametrize("change, match", [
    (dict(mouth_corner_left=None), "needs the mesh landmarks mouth_corner_left and "
                                   "mouth_corner_right"),
    (dict(upper_lip_bottom=None), "needs the mesh landmarks upper_lip_bottom or upper_lip_top"),
    (dict(lower_lip_top=None), "needs the mesh landmarks lower_lip_top or lower_lip_bottom"),
    (dict(lower_lip_top=10 ** 6), "landmark vertex 1000000 is not a vertex of the mesh"),
])
def test_landmark_errors(demo_face, change, match):
    landmarks = {k: v for k, v in demo_face.landmarks.items()
                 if k in ("mouth_corner_left", "mouth_corner_right", "upper_lip_bottom",
                          "lower_lip_top")}
    for key, value in change.items():
        if value is None:
            del landmarks[key]
        else:
            landmarks[key] = value
    with pytest.raises(InputError, match=match):
        find_mouth(demo_face.mesh, landmarks)


def test_mouth_errors(demo_face):
    mesh, landmarks = _hexagonal_hole()
    with pytest.raises(InputError, match=r"cannot tell the upper lip from the lower one .*"
                                         r"its opening \(6 vertices\) is too small"):
        find_mouth(mesh, landmarks)
    with pytest.raises(InputError, match="mesh must be a mocap.mesh.mesh.Mesh"):
        find_mouth(demo_face.mesh.vertices, demo_face.landmarks)
    with pytest.raises(InputError, match=r"middle must be two fractions 0 < a < b < 1"):
        find_mouth(demo_face.mesh, demo_face.landmarks, middle=(0.7, 0.3))
    with pytest.raises(InputError, match=r"middle must have shape \(2\), got \(\)"):
        find_mouth(demo_face.mesh, demo_face.landmarks, middle=0.5)
    mouth = find_mouth(demo_face.mesh, demo_face.landmarks)
    with pytest.raises(InputError, match=r"positions must have shape \(\.\.\., 104, 3\)"):
        mouth.gap(np.zeros((3, 5, 3)))
    with pytest.raises(InputError, match="positions contains NaN"):
        mouth.gap(np.full((104, 3), np.nan))
    lipless = MouthOpening([], [], upper=[0, 1], lower=[], method="loop")
    with pytest.raises(InputError, match="needs vertices on both lips .* 2 upper and 0 lower"):
        lipless.gap(np.zeros((2, 3)))


def test_a_non_finite_coordinate_anywhere_in_a_block_is_refused(demo_face, monkeypatch,
                                                                gap_by):
    """The gap checks its positions by their result: a NaN or ±inf in any frame of a block
    (not only its first), any vertex of either lip and any coordinate is named as numpy's
    isnan and isinf find it; finite lips pass."""
    mouth = find_mouth(demo_face.mesh, demo_face.landmarks)
    n_up, n_low = len(mouth.upper), len(mouth.lower)
    monkeypatch.setattr(mouth_module, "_CHUNK_BYTES", 4 * 8 * n_up * n_low)   # 4-frame blocks
    rng = np.random.default_rng(11)
    lips = demo_face.mesh.vertices[mouth.vertex_ids] + rng.normal(0.0, 1.0, (9, n_up + n_low, 3))
    assert np.isfinite(mouth.gap(lips)).all()
    assert mouth.gap(lips[:0]).shape == (0,) and mouth.gap(lips[None, :0]).shape == (1, 0)
    for _ in range(40):
        bad = lips.copy()
        where = (rng.integers(9), rng.integers(n_up + n_low), rng.integers(3))
        bad[where] = rng.choice([np.nan, np.inf, -np.inf])
        expected = "infinite values" if np.isinf(bad).any() else r"NaN \(first at index " \
            + re.escape(str(tuple(int(i) for i in np.argwhere(np.isnan(bad))[0]))) + r"\)"
        with pytest.raises(InputError, match=f"positions contains {expected}"):
            mouth.gap(bad)


def test_the_compiled_gap_is_loaded_for_frames_that_pay_for_it(demo_face, monkeypatch):
    """Loading numba costs about half a second: a process that has not loaded it measures a
    few frames by NumPy, many by the compiled loop."""
    mouth = find_mouth(demo_face.mesh, demo_face.landmarks)
    lips = demo_face.mesh.vertices[mouth.vertex_ids]
    frames = lips + np.random.default_rng(9).normal(0.0, 2.0, (6,) + lips.shape)
    used = []
    monkeypatch.setattr(mouth_module, "_compiled_gap",
                        lambda real=mouth_module._compiled_gap: used.append(1) or real())
    monkeypatch.delitem(sys.modules, "numba", raising=False)
    few = mouth.gap(frames)
    assert not used
    monkeypatch.setattr(mouth_module, "_PAIRS_WORTH_COMPILING",
                        len(frames) * len(mouth.upper) * len(mouth.lower))
    assert used == [] and np.allclose(mouth.gap(frames), few, rtol=0, atol=EXACT_FLOAT64)
    assert used == [1]


def _all_pairs_least(x: np.ndarray, n_up: int) -> np.ndarray:
    """Every pair's ``(dx·dx + dy·dy) + dz·dz`` and its least, per frame (the oracle)."""
    d = x[:, :n_up, None, :] - x[:, None, n_up:, :]
    with np.errstate(over="ignore"):                    # points 1e305 mm apart: inf
        pairs = (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]) + d[..., 2] * d[..., 2]
    return pairs.reshape(len(x), -1).min(axis=1, initial=np.inf)


@pytest.mark.parametrize("n_up", [0, 1, 3, 4, 5, 8, 11])
def test_the_compiled_gap_is_the_least_pair_distance_bit_for_bit(n_up):
    """The compiled loop (upper points four at a time, then the rest) against every pair's
    ``(dx·dx + dy·dy) + dz·dz`` in NumPy and its least: the same bits, for any number of
    upper points, and NaN in a frame with a coordinate that is not finite."""
    from mocap.mesh._mouth_kernel import least_squared_distances  # the speed extra
    rng = np.random.default_rng(n_up)
    x = rng.normal(0.0, 5.0, (40, n_up + 9, 3)) + [0.0, -50.0, 100.0]
    x[7, 0, 1] = np.nan
    x[11, -1, 2] = np.inf
    expected = _all_pairs_least(x, n_up)
    expected[~np.isfinite(x).all(axis=(1, 2))] = np.nan
    got = np.empty(len(x))
    least_squared_distances(x, n_up, got)
    np.testing.assert_array_equal(got, expected)


def test_the_compiled_gap_leaves_out_only_pairs_that_cannot_be_the_nearest(demo_face):
    """The compiled loop measures only the pairs its bound along the lips' axis cannot rule
    out, starting from the frame before's nearest pair: the least is still every pair's, to
    the bit, as the lips close, touch, cross and open again, slide sideways (the frame
    before's pair far from the nearest), sit 1 km from the origin, after a frame with NaN
    (no pair to start from), with both lips about one centroid (no axis), and with
    coordinates whose sums overflow (every pair measured)."""
    from mocap.mesh._mouth_kernel import least_squared_distances  # the speed extra
    mouth = find_mouth(demo_face.mesh, demo_face.landmarks)
    n_up = len(mouth.upper)
    lips = demo_face.mesh.vertices[mouth.vertex_ids]
    lower = np.arange(len(lips)) >= n_up
    t = np.linspace(0.0, 4.0 * np.pi, 240)
    frames = np.repeat(lips[None], len(t), axis=0)
    frames[:, lower, 1] -= (8.0 * np.sin(t) - 2.0)[:, None]          # open, touch, cross
    frames[:, lower, 0] += (15.0 * np.sin(3.0 * t))[:, None]         # and slide sideways
    frames += np.random.default_rng(1).normal(0.0, 0.3, frames.shape)
    frames[120:] += [1e6, -2e6, 5e5]                                  # mm: far from the origin
    frames[60, 3, 2] = np.nan
    rng = np.random.default_rng(2)
    up, low = rng.integers(-20, 20, (2, 5, 6, 3)).astype(float)       # both about 0 exactly
    centred = np.concatenate([up, -up, low, -low], axis=1)
    huge = frames[:5] * 1e305                       # sums overflow: every pair, inf not NaN
    for x, k in ((frames, n_up), (centred, 12), (huge, n_up)):
        got = np.empty(len(x))
        least_squared_distances(x, k, got)
        expected = _all_pairs_least(x, k)
        expected[~np.isfinite(x).all(axis=(1, 2))] = np.nan
        np.testing.assert_array_equal(got, expected)
    gap = np.sqrt(_all_pairs_least(frames[:120], n_up))
    assert (gap < 0.5).any() and (gap > 5.0).any()                    # it did close and open


def test_numba_without_a_cache_folder_measures_the_gap_with_numpy_and_a_warning(
        demo_face, monkeypatch):
    """numba raises RuntimeError when it can write its compiled code nowhere (a read-only
    install and home): NumPy's expansion measures the gap, with a warning saying so."""
    mouth = find_mouth(demo_face.mesh, demo_face.landmarks)
    lips = demo_face.mesh.vertices[mouth.vertex_ids]
    frames = lips + np.random.default_rng(5).normal(0.0, 2.0, (4,) + lips.shape)
    monkeypatch.setattr(mouth_module, "_PAIRS_WORTH_COMPILING", 0)
    numba_cannot_cache(monkeypatch, "mocap.mesh._mouth_kernel")
    mouth_module._compiled_gap.cache_clear()
    try:
        with pytest.warns(UserWarning, match="compiled lip gap is off .*no locator"):
            got = mouth.gap(frames)
        assert mouth_module._compiled_gap() is None
    finally:
        monkeypatch.undo()
        mouth_module._compiled_gap.cache_clear()
    expanded = mouth_module._expanded_least_squared_distances(frames, len(mouth.upper))
    np.testing.assert_array_equal(got, np.sqrt(np.maximum(expanded, 0.0)))
    np.testing.assert_allclose(got, mouth.gap(frames), rtol=0, atol=EXACT_FLOAT64)


# ---------------------------------------------------------------- lip markers

def _markerset(**landmarks):
    regions = {"upper_lip": ("u1", "u2"), "lower_lip": ("l1", "l2"), "left_brow": (),
               "right_brow": (), "left_eye": (), "right_eye": (), "other": ("c",)}
    return MarkerSet(name="lips", head=("h1", "h2", "h3"), regions=regions,
                     landmarks=landmarks)


def test_the_lip_witness_prefers_landmarks_then_regions():
    labels = ("u1", "u2", "l1", "l2", "c")
    regions = lip_witness(_markerset(), labels)
    assert (regions.upper, regions.lower, regions.source) == ((0, 1), (2, 3), "regions")
    marked = lip_witness(_markerset(upper_lip_top="u2", lower_lip_bottom="l1"), labels)
    assert (marked.upper, marked.lower, marked.source) == ((1,), (2,), "landmarks")
    x = np.zeros((2, 5, 3))
    x[1, 2:4, 1] = -7.0                       # the lower lip markers drop 7 mm
    np.testing.assert_allclose(regions.distance(x), [0.0, 7.0])
    assert "upper lip: u1, u2; lower lip: l1, l2" in regions.describe()
    with pytest.raises(InputError, match="has no lower lip marker to check the lips with"):
        lip_witness(_markerset(), ("u1", "u2", "c"))
    with pytest.raises(InputError, match=r"positions must have shape \(any, 5, 3\)"):
        regions.distance(np.zeros((2, 4, 3)))


def test_the_lip_witness_on_its_own_markers_measures_what_it_measures_on_all():
    labels = ("c", "l2", "u1", "x", "u2", "l1")
    x = np.random.default_rng(3).normal(0.0, 5.0, (7, len(labels), 3))
    for witness in (lip_witness(_markerset(), labels),
                    lip_witness(_markerset(upper_lip_top="u2", lower_lip_bottom="l1"), labels),
                    # one marker in both groups: gathered once
                    LipWitness((2, 4), (4, 5), labels, "regions")):
        own = witness.own_markers()
        assert len(set(own.labels)) == len(own.labels) < len(labels)
        columns = [labels.index(label) for label in own.labels]
        np.testing.assert_array_equal(own.distance(x[:, columns]), witness.distance(x))
        assert own.describe() == witness.describe()


# ---------------------------------------------------------------- the check

def test_the_check_names_the_frames_where_mesh_and_markers_disagree():
    n = 60
    markers = np.zeros(n)
    markers[10:21] = 20.0                     # the markers open the mouth in frames 10-20
    markers[40:43] = 2.0                      # and barely in 40-42
    shut = np.full(n, 1.0)                     # a mesh that never opens (rest gap 1 mm)
    follows = 1.0 + markers
    parted = follows.copy()
    parted[50:55] = 15.0                      # opens while the markers are at rest
    check = check_lip_seal(30.0 + markers, {"W·D": shut, "H": follows, "QE": parted},
                           rest_distance=30.0, rest_gap=1.0, first_frame=1001,
                           witness="test")
    assert check.runs("W·D") == [(1011, 1021)] and check.runs("H") == []
    assert check.runs("QE", "parted") == [(1051, 1055)] and check.runs("QE") == []
    messages = check.messages()
    assert len(messages) == 2
    assert "the W·D mesh keeps the mouth shut while the lip markers open it (by up to 20 mm) " \
           "in 11 frames: 1011-1021" in messages[0]
    assert "the QE mesh opens the mouth (by up to 14 mm) while the lip markers keep it shut " \
           "in 5 frames: 1051-1055" in messages[1]
    summary = check.summary()
    assert summary["meshes"]["W·D"]["shut_runs"] == [(1011, 1021)]
    assert summary["widest_marker_opening_mm"] == 20.0
    np.testing.assert_array_equal(contradicts(markers, shut - 1.0), check.shut("W·D"))


def test_many_runs_are_summarized():
    markers = np.tile([0.0, 10.0], 20)
    check = check_lip_seal(markers, {"H": np.zeros(40)}, rest_distance=0.0, rest_gap=0.0)
    assert check.messages()[0].endswith("in 20 frames: 1, 3, 5, 7, 9, 11 and 14 more")


@pytest.mark.parametrize("kwargs, match", [
    (dict(mesh_gap={"H": np.zeros(4)}), r"mesh_gap\['H'\] has 4 frames, the markers 5"),
    (dict(marker_distance=np.full(5, np.nan)), "marker_distance contains NaN"),
    (dict(open_mm=0.0), "open_mm must be positive and finite"),
    (dict(fraction=1.5), "fraction must be below 1"),
    (dict(fraction=0.0), "fraction must be positive and finite"),
    (dict(open_span=-0.5), "open_span must be >= 0"),
    (dict(rest_gap=np.nan), "rest_gap contains NaN"),
])
def test_check_errors(kwargs, match):
    args = dict(marker_distance=np.zeros(5), mesh_gap={"H": np.zeros(5)}, rest_distance=0.0,
                rest_gap=0.0) | kwargs
    with pytest.raises(InputError, match=match):
        check_lip_seal(args.pop("marker_distance"), args.pop("mesh_gap"), **args)
    check = check_lip_seal(np.zeros(5), {"H": np.zeros(5)}, rest_distance=0.0, rest_gap=0.0)
    with pytest.raises(InputError, match="kind must be 'shut' or 'parted'"):
        check.runs("H", "open")
