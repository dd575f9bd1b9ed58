"""glTF export (basis.gltf): written, then re-read with pygltflib, trimesh and basis.artist."""

from __future__ import annotations

import importlib.util
import json
import os
import struct
from pathlib import Path

import numpy as np
import pygltflib
import pytest
import threadpoolctl
import trimesh
from helpers import play_gltf, read_gltf_accessor
from scipy.spatial.transform import Rotation
from tolerances import FLOAT32_FACE_CM, FLOAT32_REL

import basis.gltf as gltf_module
from basis.artist import load_artist_basis
from basis.gltf import GLTF_FORMATS, morph_targets, write_gltf
from mocap.errors import InputError
from mocap.mesh.mesh import Mesh, load_mesh

#: Metres per unit: the oracle of the unit conversion.
_METRES = {"mm": 0.001, "cm": 0.01, "m": 1.0}


def _read(gltf: pygltflib.GLTF2, index: int) -> np.ndarray:
    """Decode an accessor (count, width) by hand, checking that it lies in its buffer."""
    return read_gltf_accessor(gltf, index, check_bounds=True)


def _check_accessors(gltf: pygltflib.GLTF2) -> None:
    """min/max equal numpy's on the stored values; views 4-byte aligned; strides set."""
    for i, acc in enumerate(gltf.accessors):
        values = _read(gltf, i)
        np.testing.assert_array_equal(acc.min, values.min(axis=0))
        np.testing.assert_array_equal(acc.max, values.max(axis=0))
    for view in gltf.bufferViews:
        assert view.byteOffset % 4 == 0 and view.byteLength % 4 == 0
        if view.target == pygltflib.ARRAY_BUFFER:
            assert view.byteStride == 12


def _grid(units: str | None, n: int = 5) -> Mesh:
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float))
    rng = np.random.default_rng(1)
    vertices = np.column_stack([x.ravel(), y.ravel(), rng.normal(scale=0.2, size=n * n)])
    i = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)).ravel()
    faces = np.concatenate([np.column_stack([i, i + 1, i + n + 1]),
                            np.column_stack([i, i + n + 1, i + n])])
    return Mesh(vertices, faces, units=units)


def _target_weights(targets, weights) -> np.ndarray:
    """The oracle of the stored target weights: NumPy's float64 quotients, clamped, rounded."""
    return np.maximum(weights[:, targets.shape] / targets.factor, 0.0).astype(np.float32)


@pytest.fixture(scope="module")
def ict_subset(ict_neutral_path, ict_expressions_dir):
    """The ArtistBasis of four ICT expressions (cm)."""
    return load_artist_basis(ict_neutral_path, ict_expressions_dir,
                             names=["jawOpen", "mouthSmile_L", "eyeBlink_R", "browInnerUp_L"],
                             units="cm")


def test_ict_face_as_animated_morph_targets(ict_subset, tmp_path):
    rng = np.random.default_rng(0)
    weights = rng.random((24, ict_subset.n_shapes))
    path = tmp_path / "face.glb"
    write_gltf(path, ict_subset.neutral, ict_subset.displacements, ict_subset.names,
               weights=weights, rate=60.0)

    gltf = pygltflib.GLTF2().load(str(path))
    _check_accessors(gltf)
    (mesh,), (prim,) = gltf.meshes, gltf.meshes[0].primitives
    assert mesh.extras["targetNames"] == list(ict_subset.names) and mesh.weights == [0.0] * 4
    assert gltf.accessors[prim.attributes.POSITION].count == ict_subset.neutral.n_vertices
    indices = _read(gltf, prim.indices).reshape(-1, 3)
    np.testing.assert_array_equal(indices, ict_subset.neutral.faces)
    np.testing.assert_allclose(_read(gltf, prim.attributes.POSITION) / _METRES["cm"],
                               ict_subset.neutral.vertices, rtol=0, atol=FLOAT32_FACE_CM)
    normals = _read(gltf, prim.attributes.NORMAL)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=FLOAT32_REL)
    # the face looks along +Z: normals at the nose tip point forward
    assert normals[np.argmax(ict_subset.neutral.vertices[:, 2]), 2] > 0.9
    assert len(prim.targets) == ict_subset.n_shapes
    for target, disp in zip(prim.targets, ict_subset.displacements):
        np.testing.assert_allclose(_read(gltf, target["POSITION"]) / _METRES["cm"], disp,
                                   rtol=0, atol=FLOAT32_FACE_CM)

    (anim,) = gltf.animations
    (sampler,), (channel,) = anim.samplers, anim.channels
    assert sampler.interpolation == "LINEAR"
    assert (channel.target.node, channel.target.path) == (0, "weights")
    assert gltf.nodes[channel.target.node].mesh == 0
    times = _read(gltf, sampler.input)[:, 0]
    np.testing.assert_allclose(times, np.arange(24) / 60.0, rtol=FLOAT32_REL)
    np.testing.assert_allclose(_read(gltf, sampler.output).reshape(24, ict_subset.n_shapes),
                               weights, rtol=0, atol=FLOAT32_REL)

    # an independent reader (another engineer's): the basis comes back in the
    # neutral's units, from metres in the file
    for neutral, per_cm in ((ict_subset.neutral, 1.0),
                            (Mesh(ict_subset.neutral.vertices * _METRES["cm"],
                                  ict_subset.neutral.faces, units="m"), _METRES["cm"])):
        back = load_artist_basis(neutral, path)
        assert back.names == ict_subset.names
        np.testing.assert_allclose(back.displacements / per_cm, ict_subset.displacements,
                                   rtol=0, atol=FLOAT32_FACE_CM)
    loaded = trimesh.load(path, process=False)
    geometry = loaded.to_geometry() if isinstance(loaded, trimesh.Scene) else loaded
    assert len(geometry.vertices) == ict_subset.neutral.n_vertices
    assert len(geometry.faces) == ict_subset.neutral.n_faces


def test_signed_weights_play_back_inside_the_slider_range(ict_subset, tmp_path, monkeypatch):
    """QE and PCA weights leave [0, 1] (here -40..60): a viewer that clamps every morph
    weight to [0, 1], as Blender's shape-key sliders do, still shows neutral + Σ w e at
    every key and between keys; the basis reads back unscaled. The target weights and
    displacements are made a small part at a time (here 1000 bytes: 83 vertices, parts
    that straddle two targets, and a few frames with a remainder), the same values as
    formed all at once, and every accessor's min/max (derived from the inputs' extremes
    for the targets and the weights) is numpy's on the values stored."""
    monkeypatch.setattr(gltf_module, "_PART_BYTES", 1000)
    rng = np.random.default_rng(3)
    weights = rng.normal(0.0, 20.0, (30, ict_subset.n_shapes))
    weights[:, 1] = rng.uniform(0.0, 0.7, 30)            # already inside: left as it is
    weights[:, 2] = -rng.uniform(0.0, 3.0, 30)           # only negative
    path = tmp_path / "signed.glb"
    write_gltf(path, ict_subset.neutral, ict_subset.displacements, ict_subset.names,
               weights=weights, rate=30.0, first_frame=7)
    _check_accessors(pygltflib.GLTF2().load(str(path)))
    stored = _target_weights(morph_targets(ict_subset.names, weights), weights)
    np.testing.assert_array_equal(play_gltf(path, clamp=None)["weights"], stored)
    played = play_gltf(path)
    assert played["weights"].min() >= 0 and played["weights"].max() <= 1
    np.testing.assert_array_equal(played["vertices"], play_gltf(path, clamp=None)["vertices"])
    want = ict_subset.neutral.vertices + np.tensordot(weights, ict_subset.displacements, 1)
    # float32 targets scaled up to 60x: the sum keeps a few 1e-5 cm
    np.testing.assert_allclose(played["vertices"] / _METRES["cm"], want, rtol=0,
                               atol=FLOAT32_FACE_CM * np.abs(weights).max())
    # halfway between two keys a viewer blends the target weights linearly
    half = 0.5 * (played["weights"][:-1] + played["weights"][1:])
    gltf = pygltflib.GLTF2().load(str(path))
    targets = np.array([_read(gltf, t["POSITION"]) for t in gltf.meshes[0].primitives[0].targets])
    between = _read(gltf, gltf.meshes[0].primitives[0].attributes.POSITION) \
        + np.tensordot(half, targets, 1)
    want_between = ict_subset.neutral.vertices + np.tensordot(
        0.5 * (weights[:-1] + weights[1:]), ict_subset.displacements, 1)
    np.testing.assert_allclose(between / _METRES["cm"], want_between, rtol=0,
                               atol=FLOAT32_FACE_CM * np.abs(weights).max())
    names = gltf.meshes[0].extras["targetNames"]
    assert names[:2] == [ict_subset.names[0], ict_subset.names[0] + ".neg"]
    assert ict_subset.names[1] + ".neg" not in names
    # keyed on frame numbers: key k at (7 + k) / 30 s
    np.testing.assert_allclose(played["times"], (7 + np.arange(30)) / 30.0, rtol=FLOAT32_REL)
    assert gltf.animations[0].extras == {"rate": 30.0, "first_frame": 7}
    back = load_artist_basis(ict_subset.neutral, path)
    assert back.names == ict_subset.names
    np.testing.assert_allclose(back.displacements, ict_subset.displacements, rtol=0,
                               atol=FLOAT32_FACE_CM)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_target_weights_are_numpys_quotients(dtype):
    """Every target weight is max(w / factor, 0) rounded once from the float64 quotient,
    a NaN kept and -0.0 made 0.0, bit for bit."""
    rng = np.random.default_rng(8)
    weights = rng.normal(0.0, 3.0, (50, 6))
    weights[3, :] = -0.0
    weights[4, :] = 0.0
    weights[5, 2] = np.nan
    weights[6, 1] = 1e-320                           # its quotients are subnormal or zero
    targets = morph_targets("abcdef", np.nan_to_num(weights))
    got = targets.weights(weights, dtype)
    want = np.maximum(weights[:, targets.shape] / targets.factor, 0.0).astype(dtype)
    assert got.dtype == dtype
    np.testing.assert_array_equal(got.view(f"u{got.itemsize}"), want.view(f"u{got.itemsize}"))
    assert not np.signbit(got[3:5]).any()


def test_the_same_bytes_on_any_threads(ict_subset, tmp_path, monkeypatch):
    """The file is the same, byte for byte, on one thread or two, with parts small enough
    to straddle targets or as large as the writer makes them, and where there is no
    ``os.pwrite`` (Windows)."""
    rng = np.random.default_rng(9)
    weights = rng.normal(0.2, 2.0, (300, ict_subset.n_shapes))

    def written(name, threads):
        with threadpoolctl.threadpool_limits(threads, user_api="blas"):
            write_gltf(tmp_path / name, ict_subset.neutral, ict_subset.displacements,
                       ict_subset.names, weights=weights, rate=30.0)
        return (tmp_path / name).read_bytes()

    first = written("one.glb", 1)
    assert written("two.glb", 2) == first
    monkeypatch.setattr(gltf_module, "_PART_BYTES", 4096)
    assert written("small-one.glb", 1) == first
    assert written("small-two.glb", 2) == first
    monkeypatch.delattr(os, "pwrite")
    assert written("no-pwrite.glb", 2) == first


def test_morph_targets_refuse_a_negative_name_that_is_taken():
    with pytest.raises(InputError, match="negative target's name 'a.neg' is another shape's"):
        morph_targets(["a", "a.neg"], [[-2.0, 0.5]])


@pytest.mark.parametrize("suffix", GLTF_FORMATS)
@pytest.mark.parametrize("units", sorted(_METRES))
def test_units_become_metres(tmp_path, suffix, units):
    neutral = _grid(units)
    disp = np.random.default_rng(2).normal(size=(3, neutral.n_vertices, 3))
    path = tmp_path / f"grid{suffix}"
    write_gltf(path, neutral, disp, ["a", "b", "c"])
    gltf = pygltflib.GLTF2().load(str(path))
    _check_accessors(gltf)
    assert gltf.animations == []
    prim = gltf.meshes[0].primitives[0]
    scale = _METRES[units]
    for target, d in zip(prim.targets, disp):
        decoded = _read(gltf, target["POSITION"])
        np.testing.assert_allclose(decoded, d * scale, rtol=0,
                                   atol=FLOAT32_REL * np.abs(d * scale).max())
    np.testing.assert_allclose(_read(gltf, prim.attributes.POSITION), neutral.vertices * scale,
                               rtol=0, atol=FLOAT32_REL * neutral.vertices.max() * scale)
    metres = Mesh(neutral.vertices * scale, neutral.faces, units="m")
    back = load_artist_basis(metres, path)
    np.testing.assert_allclose(back.displacements, disp * scale, rtol=0,
                               atol=FLOAT32_REL * np.abs(disp * scale).max())


def test_glb_chunks_are_aligned(tmp_path):
    neutral = _grid("cm", n=3)
    path = tmp_path / "a.glb"
    write_gltf(path, neutral, np.ones((1, 9, 3)), ["only"], weights=np.ones((5, 1)),
               rate=30)
    raw = path.read_bytes()
    magic, version, length = struct.unpack("<4sII", raw[:12])
    assert (magic, version, length) == (b"glTF", 2, len(raw))
    offset = 12
    while offset < len(raw):
        chunk_length, _ = struct.unpack("<II", raw[offset:offset + 8])
        assert chunk_length % 4 == 0
        offset += 8 + chunk_length
    assert offset == len(raw)


def _glb_chunks(raw: bytes) -> tuple[dict, bytes]:
    """The JSON document and the BIN chunk of a .glb, its framing checked."""
    (json_length,) = struct.unpack("<I", raw[12:16])
    (bin_length,) = struct.unpack("<I", raw[20 + json_length:24 + json_length])
    assert len(raw) == 28 + json_length + bin_length
    return json.loads(raw[20:20 + json_length]), raw[28 + json_length:]


def test_glb_and_gltf_are_pygltflib_own(tmp_path, monkeypatch):
    """The .glb and the .gltf hold the document and buffer pygltflib's ``save_binary`` and
    ``save_json`` write of the same glTF read into pygltflib's own objects (JSON values and
    buffer bytes equal), and the .glb's BIN chunk is the buffer the .gltf embeds."""
    neutral = _grid("cm", n=4)
    rng = np.random.default_rng(3)
    args = (neutral, rng.normal(size=(3, 16, 3)), ["a", "b", "\u00e9"])
    motion = dict(weights=rng.normal(0, 2.0, (7, 3)), rotation=np.tile(np.eye(3), (7, 1, 1)),
                  translation=rng.normal(size=(7, 3)), rate=30, first_frame=4)
    for kwargs in (motion, {}):
        write_gltf(tmp_path / "a.glb", *args, **kwargs)
        write_gltf(tmp_path / "a.gltf", *args, **kwargs)
        theirs = pygltflib.GLTF2().load(str(tmp_path / "a.glb"))
        theirs.save_binary(str(tmp_path / "b.glb"))
        ours, blob = _glb_chunks((tmp_path / "a.glb").read_bytes())
        assert (ours, blob) == _glb_chunks((tmp_path / "b.glb").read_bytes())
        embedded = pygltflib.GLTF2().load(str(tmp_path / "a.gltf"))
        assert embedded.decode_data_uri(embedded.buffers[0].uri) == blob
        embedded.save_json(str(tmp_path / "b.gltf"))
        assert (json.loads((tmp_path / "a.gltf").read_text())
                == json.loads((tmp_path / "b.gltf").read_text()))


def test_one_frame_animation_and_unitless_mesh(tmp_path):
    neutral = _grid(None, n=3)
    path = tmp_path / "a.gltf"
    with pytest.warns(UserWarning, match="no units: positions are written unscaled"):
        write_gltf(path, neutral, np.zeros((2, 9, 3)), ["a", "b"],
                   weights=[[0.25, 0.5]], rate=24)
    gltf = pygltflib.GLTF2().load(str(path))
    _check_accessors(gltf)
    sampler = gltf.animations[0].samplers[0]
    assert _read(gltf, sampler.input).tolist() == [[0.0]]
    assert _read(gltf, sampler.output).ravel().tolist() == [0.25, 0.5]
    np.testing.assert_allclose(_read(gltf, gltf.meshes[0].primitives[0].attributes.POSITION),
                               neutral.vertices, atol=FLOAT32_REL)


def _quat_apply(q, v):
    """v rotated by unit quaternions q (T, 4) stored x, y, z, w (hand-written oracle)."""
    u, w = q[:, None, :3], q[:, None, 3:]
    cross = np.cross(u, v)
    return v + 2 * w * cross + 2 * np.cross(u, cross)


def test_rigid_motion_animates_the_node_in_metres(tmp_path):
    """Vertex v of frame t lands on R_t v + T_t (mesh units): glTF rotates, then translates."""
    neutral = _grid("cm", n=3)
    n = 40
    angle = np.linspace(0.0, 1.8 * np.pi, n)                # crosses pi: quaternion signs flip
    axis = np.array([0.3, 1.0, -0.2]) / np.linalg.norm([0.3, 1.0, -0.2])
    rotation = np.array([np.cos(a) * np.eye(3) + np.sin(a) * np.cross(np.eye(3), axis)
                         + (1 - np.cos(a)) * np.outer(axis, axis) for a in angle])  # Rodrigues
    translation = np.random.default_rng(1).normal(0, 5.0, (n, 3))
    path = tmp_path / "moving.glb"
    write_gltf(path, neutral, np.zeros((2, 9, 3)), ["a", "b"], weights=np.zeros((n, 2)),
               rotation=rotation, translation=translation, rate=30)
    gltf = pygltflib.GLTF2().load(str(path))
    _check_accessors(gltf)
    (anim,) = gltf.animations
    paths = {c.target.path: anim.samplers[c.sampler] for c in anim.channels}
    assert set(paths) == {"weights", "rotation", "translation"}
    assert all(c.target.node == 0 and gltf.nodes[0].mesh == 0 for c in anim.channels)
    quat = _read(gltf, paths["rotation"].output)
    move = _read(gltf, paths["translation"].output)
    np.testing.assert_allclose(_read(gltf, paths["rotation"].input)[:, 0], np.arange(n) / 30,
                               rtol=FLOAT32_REL)
    np.testing.assert_allclose(np.linalg.norm(quat, axis=1), 1.0, atol=FLOAT32_REL)
    assert np.all(np.einsum("ij,ij->i", quat[1:], quat[:-1]) > 0)   # the slerp's short way
    metres = _read(gltf, gltf.meshes[0].primitives[0].attributes.POSITION)
    played = _quat_apply(quat.astype(float), metres[None].astype(float)) + move[:, None]
    want = np.einsum("tij,vj->tvi", rotation, neutral.vertices) + translation[:, None]
    np.testing.assert_allclose(played / _METRES["cm"], want, atol=FLOAT32_FACE_CM * 10)
    # the same motion as a scipy Rotation (converted once for several files): the same file
    again = tmp_path / "again.glb"
    write_gltf(again, neutral, np.zeros((2, 9, 3)), ["a", "b"], weights=np.zeros((n, 2)),
               rotation=Rotation.from_matrix(rotation), translation=translation, rate=30)
    assert again.read_bytes() == path.read_bytes()



def test_blender_check_reads_the_weights_beside_a_head_motion(tmp_path):
    """``make blender-check`` finds the weights' channel among the node's three (no Blender needed
    for the file's side), as gestures.glb with a head motion has them."""
    spec = importlib.util.spec_from_file_location(
        "blender_check", Path(__file__).resolve().parents[1] / "bench" / "blender_check.py")
    blender_check = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(blender_check)
    n = 6
    weights = np.random.default_rng(2).uniform(0.0, 1.0, (n, 2))
    path = tmp_path / "moving.glb"
    write_gltf(path, _grid("cm", n=3), np.zeros((2, 9, 3)), ["a", "b"], weights=weights,
               rotation=np.tile(np.eye(3), (n, 1, 1)), translation=np.ones((n, 3)), rate=30)
    want = blender_check.expected(*blender_check.read_glb(path))
    assert (want["vertices"], want["names"], want["n_targets"]) == (9, ["a", "b"], 2)
    np.testing.assert_allclose(want["times"], np.arange(n) / 30, rtol=FLOAT32_REL)
    np.testing.assert_allclose(want["weights"], weights, rtol=FLOAT32_REL)

def test_output_never_replaces_the_neutral(tmp_path):
    neutral = _grid("cm", n=3)
    src = tmp_path / "neutral.glb"
    write_gltf(src, neutral, np.zeros((1, 9, 3)), ["a"])
    loaded = load_mesh(src, units="m")
    with pytest.raises(InputError, match="refusing to overwrite an input file"):
        write_gltf(src, loaded, np.zeros((1, 9, 3)), ["a"])


def _one(shape: tuple, index: tuple, value: float) -> np.ndarray:
    """Zeros of `shape` but `value` at `index`."""
    arr = np.zeros(shape)
    arr[index] = value
    return arr


@pytest.mark.parametrize("kwargs, message", [
    (dict(names=["a"]), "names has 1 entries but displacements has 2 shapes"),
    (dict(names=["a", "a"]), "names must be unique: 'a' appears twice"),
    (dict(names="ab"), "names must be a sequence of strings"),
    (dict(names=["a", ""]), "names must be non-empty strings"),
    (dict(names=[], displacements=np.zeros((0, 9, 3))), "displacements has no shapes"),
    (dict(displacements=np.zeros((2, 8, 3))), r"displacements must have shape \(any, 9, 3\)"),
    (dict(displacements=np.full((2, 9, 3), np.nan)), "displacements contains NaN"),
    (dict(weights=np.array([[0.0, np.nan]]), rate=30), r"weights contains NaN"),
    (dict(displacements=_one((2, 9, 3), (0, 8, 2), np.nan)),
     r"displacements contains NaN \(first at index \(0, 8, 2\)\)"),
    (dict(displacements=_one((2, 9, 3), (1, 4, 0), -np.inf)),
     "displacements contains infinite values"),
    (dict(weights=np.array([[0.0, 0.5], [0.3, np.nan], [0.1, 0.2]]), rate=30),
     r"weights contains NaN \(first at index \(1, 1\)\)"),
    (dict(weights=np.array([[0.0, 0.5], [np.inf, 0.2]]), rate=30),
     "weights contains infinite values"),
    (dict(weights=np.zeros((4, 3)), rate=30), r"weights must have shape \(any, 2\)"),
    (dict(weights=np.zeros((0, 2)), rate=30), "the animation has no frames"),
    (dict(weights=np.zeros((4, 2))), "an animation needs the take's rate"),
    (dict(rate=30), "rate is only used with an animation"),
    (dict(weights=np.zeros((4, 2)), rate=-1), "rate must be positive"),
    (dict(weights=np.zeros((4, 2)), rate=30, first_frame=-1), "first_frame must be at least 0"),
    (dict(rotation=np.tile(np.eye(3), (4, 1, 1)), rate=30), "rotation and translation go"),
    (dict(rotation=np.tile(2 * np.eye(3), (4, 1, 1)), translation=np.zeros((4, 3)), rate=30),
     "rotation must hold rotation matrices"),
    (dict(rotation=Rotation.identity(), translation=np.zeros((1, 3)), rate=30),
     "rotation must hold one rotation a frame, got a single Rotation"),
    (dict(rotation=Rotation.identity(4), translation=np.zeros((5, 3)), rate=30),
     r"translation must have shape \(4, 3\)"),
    (dict(rotation=np.tile(np.eye(3), (4, 1, 1)), translation=np.zeros((4, 3)), rate=30,
          weights=np.zeros((5, 2))), "weights have 5 frames but the motion 4"),
    (dict(path="face.fbx"), "unknown glTF extension '.fbx'"),
    (dict(neutral=np.zeros((9, 3))), "neutral must be a Mesh"),
])
def test_invalid_input_is_refused(tmp_path, kwargs, message):
    args = dict(path="face.glb", neutral=_grid("cm", n=3), displacements=np.zeros((2, 9, 3)),
                names=["a", "b"])
    args.update(kwargs)
    path = tmp_path / args.pop("path")
    with pytest.raises(InputError, match=message):
        write_gltf(path, args.pop("neutral"), args.pop("displacements"), args.pop("names"),
                   **args)
    assert not path.exists()


def test_unwritable_directory_names_the_file(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    with pytest.raises(InputError, match=r"a_file/face\.glb: cannot write"):
        write_gltf(blocker / "face.glb", _grid("cm", n=3), np.zeros((1, 9, 3)), ["a"])
    with pytest.raises(InputError, match="directory .*missing_dir does not exist"):
        write_gltf(tmp_path / "missing_dir" / "face.glb", _grid("cm", n=3),
                   np.zeros((1, 9, 3)), ["a"])
    assert Path(blocker).read_text() == ""
