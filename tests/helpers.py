"""Helpers shared by several test files (not fixtures: those are in conftest.py)."""

from __future__ import annotations

import base64
from pathlib import Path

import numpy as np
import pygltflib

from mocap.rigid import fit_rigid

TESTS_DIR = Path(__file__).resolve().parent
#: The files kept beside the tests: the ICT face's marker layout, marker set and mesh
#: landmarks, and the marker set of facial-sing.c3d.
ICT_LAYOUT_TOML = TESTS_DIR / "ict_marker_layout.toml"
ICT_MARKERSET_TOML = TESTS_DIR / "ict_markerset.toml"
ICT_LANDMARKS_TOML = TESTS_DIR / "ict_landmarks.toml"
FACIAL_SING_MARKERSET_TOML = TESTS_DIR / "facial_sing_markerset.toml"


# ---------------------------------------------------------------- oracles

def moving_average_oracle(x, window):
    """Centred mean over the frames inside the take (explicit loop)."""
    k = window // 2
    return np.array([x[max(0, t - k):t + k + 1].mean(axis=0) for t in range(len(x))])


def rigid_shape_rms(points, exact) -> float:
    """RMS distance (mm) of `points` to `exact` after the best rigid alignment of the two."""
    fit = fit_rigid(points, exact)
    return float(np.sqrt(np.mean(np.sum((fit.apply(points) - exact) ** 2, axis=1))))


def jaw_open_peak_time(performance) -> float:
    """Time (s) of a performance's widest jaw opening (its largest JawOpen weight)."""
    return performance.times[np.argmax(performance.weights[:, performance.names.index("JawOpen")])]


# ---------------------------------------------------------------- files

def write_utf8(tmp_path, text: str, name: str) -> Path:
    """`text` written to tmp_path / name as UTF-8 bytes, its newlines as they are."""
    path = tmp_path / name
    path.write_bytes(text.encode("utf-8"))
    return path


# ---------------------------------------------------------------- meshes

def slit_grid(n: int = 25, slit: float = 0.6):
    """Unit-square grid (criss-cross triangles) cut along y = 0.5 for x < `slit`.

    Returns vertices (V, 3), triangles (F, 3), and the ids of the vertex rows
    just above and just below the cut (sharing x), as (upper, lower).
    """
    xs = np.linspace(0.0, 1.0, n)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    vertices = np.c_[gx.ravel(), gy.ravel(), np.zeros(n * n)]
    ids = np.arange(n * n).reshape(n, n)
    mid, tip = (n - 1) // 2, int(round(slit * (n - 1)))
    faces = []
    lower_ids = ids.copy()
    if slit > 0:
        # Duplicate the cut vertices (x < tip) for the cells below the cut.
        dup = np.arange(n * n, n * n + tip)
        vertices = np.r_[vertices, vertices[ids[:tip, mid]]]
        lower_ids[:tip, mid] = dup
    for i in range(n - 1):
        for j in range(n - 1):
            grid = lower_ids if j < mid else ids
            a, b, c, d = grid[i, j], grid[i + 1, j], grid[i + 1, j + 1], grid[i, j + 1]
            faces += [[a, b, c], [a, c, d]] if (i + j) % 2 else [[a, b, d], [b, c, d]]
    return vertices, np.array(faces), ids[:, mid], lower_ids[:, mid]


# ---------------------------------------------------------------- glTF

_GLTF_DTYPES = {pygltflib.FLOAT: "<f4", pygltflib.UNSIGNED_INT: "<u4",
                pygltflib.UNSIGNED_SHORT: "<u2"}
_GLTF_WIDTH = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}


def gltf_buffer(gltf: pygltflib.GLTF2) -> bytes:
    """The bytes of buffer 0: the GLB's binary chunk, or the .gltf's base64 data URI."""
    uri = gltf.buffers[0].uri
    if uri is None:
        return gltf.binary_blob()
    assert uri.startswith("data:application/octet-stream;base64,")
    return base64.b64decode(uri.split(",", 1)[1])


def read_gltf_accessor(gltf: pygltflib.GLTF2, index: int, *,
                       check_bounds: bool = False) -> np.ndarray:
    """Decode an accessor (count, width) by hand from its view and buffer; with
    `check_bounds`, assert that it lies inside its view and the view inside the buffer."""
    acc = gltf.accessors[index]
    view = gltf.bufferViews[acc.bufferView]
    dtype = np.dtype(_GLTF_DTYPES[acc.componentType])
    width = _GLTF_WIDTH[acc.type]
    stride = view.byteStride or dtype.itemsize * width
    data = gltf_buffer(gltf)
    start = view.byteOffset + (acc.byteOffset or 0)
    if check_bounds:
        assert start + stride * (acc.count - 1) + dtype.itemsize * width <= view.byteOffset \
            + view.byteLength <= len(data)
    return np.ndarray((acc.count, width), dtype=dtype, buffer=data, offset=start,
                      strides=(stride, dtype.itemsize))


def play_gltf(path, *, clamp=(0.0, 1.0)) -> dict:
    """Play a one-mesh glTF written by basis.gltf as a viewer would, in numpy.

    Each key's morph weights are clamped to `clamp` (Blender's default slider
    range; None: no clamping), the targets added to the base positions, and the
    node's rotation (quaternion x, y, z, w) and translation applied when animated.

    Returns
    -------
    dict
        ``times`` (K,) s, ``vertices`` (K, N, 3) metres, placed; ``weights`` (K, n_targets).
    """
    gltf = pygltflib.GLTF2().load(str(path))
    prim = gltf.meshes[0].primitives[0]
    base = read_gltf_accessor(gltf, prim.attributes.POSITION).astype(float)
    targets = np.array([read_gltf_accessor(gltf, t["POSITION"]) for t in prim.targets], float)
    (anim,) = gltf.animations
    samplers = {c.target.path: anim.samplers[c.sampler] for c in anim.channels}
    times = read_gltf_accessor(gltf, samplers["weights"].input)[:, 0].astype(float)
    weights = read_gltf_accessor(gltf, samplers["weights"].output).astype(float)
    weights = weights.reshape(len(times), len(targets))
    shown = weights if clamp is None else np.clip(weights, *clamp)
    vertices = base + np.tensordot(shown, targets, axes=1)
    if "rotation" in samplers:
        quat = read_gltf_accessor(gltf, samplers["rotation"].output).astype(float)
        move = read_gltf_accessor(gltf, samplers["translation"].output).astype(float)
        u, w = quat[:, None, :3], quat[:, None, 3:]
        cross = np.cross(u, vertices)
        vertices = vertices + 2 * w * cross + 2 * np.cross(u, cross) + move[:, None]
    return {"times": times, "vertices": vertices, "weights": weights}


# ---------------------------------------------------------------- command lines

def synth_argv(mesh, shapes, performance, output, *extra, layout=ICT_LAYOUT_TOML,
               markerset=ICT_MARKERSET_TOML) -> list[str]:
    """``mocap2mesh synth`` of a performance on a face with the ICT layout and marker set."""
    return ["synth", "--mesh", str(mesh), "--shapes", str(shapes), "--performance",
            str(performance), "--layout", str(layout), "--markerset", str(markerset),
            "-o", str(output), *extra]


def bind_argv(capture, mesh, output, *extra, markerset=ICT_MARKERSET_TOML,
              landmarks=ICT_LANDMARKS_TOML) -> list[str]:
    """``mocap2mesh bind`` of a capture to a mesh with the ICT marker set and landmarks."""
    return ["bind", str(capture), "--markerset", str(markerset), "--mesh", str(mesh),
            "--landmarks", str(landmarks), "-o", str(output), *extra]


def stub_take(calls, bases=None):
    """A stand-in for one take of ``run_takes`` (``fit.pipeline.session._guarded``) that
    commits one small file through the completion API; appends each capture's name to
    `calls` (and the session basis it was given to `bases`)."""
    from fit.pipeline.completion import begin_take, commit_take

    def fake(capture, config, name, provenance, session_basis=None):
        calls.append(capture.name)
        if bases is not None:
            bases.append(session_basis)
        stage = begin_take(config.output, name)
        (stage / "out.txt").write_text(f"{capture.name} {provenance.key}")
        record = commit_take(stage, config.output, name, provenance,
                             summary={"status": "ok", "skipped": False, "error": None})
        return {**record.summary, "files": [f"{name}/{f}" for f in record.files]}
    return fake
