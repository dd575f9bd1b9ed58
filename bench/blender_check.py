"""Open the project's .glb files in Blender (bpy) and compare the mesh Blender evaluates with ours.

Run with the Python of a venv that has ``bpy`` (``make blender-check`` builds
``.venv-blender``). It needs nothing of the project but numpy: it reads each
file's glTF JSON itself (the GLB header and its first chunk) and the mesh
sequence the project wrote beside it, which is the reference:

* ``face-B.glb`` of ``mocap2mesh run`` is checked against ``mesh-B.npz`` in
  its folder, ``gestures.glb`` against ``mesh.npz``; the reference mesh of
  key k is ``neutral + Σ_i w_ki e_i`` (float64 from the stored float32),
  placed by the recorded head motion ``R_k v + T_k``.

For every file: the vertex count; the shape keys (Blender's ``Basis``, then
the morph targets named as ``mesh.extras.targetNames``); the action's frames
(scene fps set to the file's rate before importing, so that key k lands on
frame ``time_k × fps``, which must be the capture's frame number ``first_frame
+ k`` that the mesh sequence records). Then, with a reference, the evaluated
mesh: at each checked frame ``scene.frame_set``, the depsgraph's evaluated
object (shape keys with their slider clamping, the action, the object's
animated transform), its vertices in world space taken back to glTF axes
(Blender is Z-up: glTF ``(x, y, z)`` is Blender ``(x, -z, y)``) and to mesh
units, against the reference: the largest vertex distance, mm, must be at
most ``--tolerance-mm`` (default 0.01 mm). All frames are checked unless
``--frames N`` asks for N evenly spaced ones.

Usage: ``python bench/blender_check.py [--frames N] [--tolerance-mm MM] FILE_OR_DIR...``
(directories: every ``*.glb`` under them). Prints one block per file; exits 1
if any check fails.
"""

from __future__ import annotations

import argparse
import json
import struct
import sys
import time
from pathlib import Path

import numpy as np

GLB_MAGIC = 0x46546C67          # b"glTF"
JSON_CHUNK = 0x4E4F534A         # b"JSON"
BIN_CHUNK = 0x004E4942          # b"BIN\0"
#: Millimetres per unit of the mesh sequences' ``units``.
MM_PER_UNIT = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "": 1000.0}
#: Blender world (Z-up) to glTF (Y-up) axes: glTF = Blender @ this.
BLENDER_TO_GLTF = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def read_glb(path: Path) -> tuple[dict, bytes]:
    """The glTF JSON document and the binary chunk of a .glb file."""
    data = path.read_bytes()
    magic, version, length = struct.unpack_from("<III", data, 0)
    if magic != GLB_MAGIC or version != 2 or length != len(data):
        raise SystemExit(f"{path}: not a glTF 2.0 binary file")
    size, kind = struct.unpack_from("<II", data, 12)
    if kind != JSON_CHUNK:
        raise SystemExit(f"{path}: first chunk is not JSON")
    doc = json.loads(data[20:20 + size])
    offset = 20 + size
    binary = b""
    if offset < len(data):
        bsize, bkind = struct.unpack_from("<II", data, offset)
        if bkind == BIN_CHUNK:
            binary = data[offset + 8:offset + 8 + bsize]
    return doc, binary


def accessor_floats(doc: dict, binary: bytes, index: int) -> np.ndarray:
    """A float32 SCALAR accessor's values (the animation's times and weights), tightly packed."""
    acc = doc["accessors"][index]
    view = doc["bufferViews"][acc["bufferView"]]
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    return np.frombuffer(binary, "<f4", acc["count"], start).astype(float)


def expected(doc: dict, binary: bytes) -> dict:
    """What the file says: vertices, target names, key times and weights."""
    (mesh,) = doc["meshes"]
    vertices = sum(doc["accessors"][p["attributes"]["POSITION"]]["count"]
                   for p in mesh["primitives"])
    names = list(mesh.get("extras", {}).get("targetNames", []))
    n_targets = len(mesh["primitives"][0].get("targets", []))
    times = weights = None
    for animation in doc.get("animations", []):
        # the weights' channel (a head motion adds rotation and translation channels)
        for channel in animation["channels"]:
            if channel["target"]["path"] == "weights":
                sampler = animation["samplers"][channel["sampler"]]
                times = accessor_floats(doc, binary, sampler["input"])
                weights = accessor_floats(doc, binary, sampler["output"]).reshape(len(times),
                                                                                   -1)
    return {"vertices": vertices, "names": names, "n_targets": n_targets, "times": times,
            "weights": weights}


def reference_for(path: Path) -> Path | None:
    """The mesh sequence the project wrote beside a .glb (``face-B.glb`` → ``mesh-B.npz``)."""
    stem = path.stem
    name = f"mesh-{stem[len('face-'):]}.npz" if stem.startswith("face-") else "mesh.npz"
    candidate = path.with_name(name)
    return candidate if candidate.is_file() else None


def reference_mesh(path: Path) -> dict:
    """Frames of a mesh sequence .npz evaluated in float64, placed by its head motion, mm."""
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    mm = MM_PER_UNIT[str(arrays["units"])]
    if "vertices" in arrays:
        frames = arrays["vertices"].astype(np.float64)
    else:
        weights = arrays["weights"].astype(np.float64)
        basis = arrays["displacements"].astype(np.float64)
        frames = np.tensordot(weights, basis, axes=1) + arrays["neutral"].astype(np.float64)
    if "rotation" in arrays:
        frames = (np.einsum("tij,tvj->tvi", arrays["rotation"], frames)
                  + arrays["translation"][:, None, :])
    return {"frames": frames * mm, "first_frame": int(arrays["first_frame"]),
            "moving": "rotation" in arrays}


def blender_view(path: Path, fps: int, frames=None) -> dict:
    """What Blender imports from `path` into an empty scene at `fps`, and the mesh it
    evaluates at each of `frames` (world space, glTF axes, metres)."""
    import bpy  # here, so that the file's side can be read without Blender

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps = fps
    scene.render.fps_base = 1.0
    bpy.ops.import_scene.gltf(filepath=str(path))
    meshes = [o for o in scene.objects if o.type == "MESH"]
    if len(meshes) != 1:
        raise SystemExit(f"{path}: Blender imported {len(meshes)} mesh objects, expected 1")
    obj = meshes[0]
    keys = obj.data.shape_keys
    blocks = [] if keys is None else [b.name for b in keys.key_blocks]
    action = None if keys is None or keys.animation_data is None \
        else keys.animation_data.action
    view = {"version": bpy.app.version_string, "object": obj.name,
            "vertices": len(obj.data.vertices), "shape_keys": blocks,
            "action": None if action is None else action.name,
            "slider_ranges": [] if keys is None else
            [(b.slider_min, b.slider_max) for b in keys.key_blocks[1:]]}
    if action is not None:
        view["frame_range"] = tuple(float(x) for x in action.frame_range)
        first = action.fcurves[0].keyframe_points
        points = np.empty(2 * len(first))
        first.foreach_get("co", points)
        view["key_frames"] = points[0::2]
    if frames is not None:
        evaluated, n = [], len(obj.data.vertices)
        co = np.empty(3 * n)
        for frame in frames:
            scene.frame_set(int(frame))
            depsgraph = bpy.context.evaluated_depsgraph_get()
            ob = obj.evaluated_get(depsgraph)
            mesh = ob.to_mesh()
            mesh.vertices.foreach_get("co", co)
            matrix = np.array(ob.matrix_world)
            ob.to_mesh_clear()
            world = co.reshape(-1, 3) @ matrix[:3, :3].T + matrix[:3, 3]
            evaluated.append(world @ BLENDER_TO_GLTF)
        view["evaluated"] = np.array(evaluated)
    return view


def check(path: Path, *, n_frames: int | None, tolerance_mm: float) -> bool:
    doc, binary = read_glb(path)
    want = expected(doc, binary)
    times = want["times"]
    extras = (doc.get("animations") or [{}])[0].get("extras", {})
    rate = extras.get("rate") or (None if times is None or len(times) < 2
                                  else 1.0 / (times[1] - times[0]))
    fps = 24 if rate is None else int(round(rate))
    ref_path = reference_for(path) if times is not None else None
    reference = reference_mesh(ref_path) if ref_path is not None else None
    frames = keys = None
    if reference is not None:
        keys = np.arange(len(times))
        if n_frames is not None and n_frames < len(keys):
            keys = np.unique(np.linspace(0, len(keys) - 1, n_frames).round().astype(int))
        frames = np.round(times[keys] * fps).astype(int)
    tic = time.perf_counter()
    got = blender_view(path, fps, frames)
    seconds = time.perf_counter() - tic
    results = [("vertices", want["vertices"], got["vertices"],
                got["vertices"] == want["vertices"]),
               ("shape keys", ["Basis"] + want["names"], got["shape_keys"],
                got["shape_keys"] == ["Basis"] + want["names"]
                and want["n_targets"] == len(want["names"]))]
    if times is not None:
        span = (float(times[0] * fps), float(times[-1] * fps))
        have = got.get("frame_range")
        results.append(("action frame range", span, have,
                        have is not None and np.allclose(have, span, atol=1e-3)))
        weights = want["weights"]
        results.append(("the file's weights inside the default slider range",
                        "[0, 1]", f"keys in [{weights.min():.4g}, {weights.max():.4g}]",
                        bool(weights.min() >= 0 and weights.max() <= 1)))
    if reference is not None:
        numbers = reference["first_frame"] + np.arange(len(times))
        have = got.get("key_frames", np.array([]))
        results.append(("keys on the capture's frame numbers",
                        f"{numbers[0]}..{numbers[-1]}",
                        f"{have[0]:g}..{have[-1]:g}" if len(have) else None,
                        len(have) == len(numbers) and np.allclose(have, numbers, atol=1e-3)))
        ours = reference["frames"][keys]
        if ours.shape != got["evaluated"].shape:
            results.append(("evaluated mesh", ours.shape, got["evaluated"].shape, False))
        else:
            mm = MM_PER_UNIT[""]                        # Blender's metres to mm
            gap = np.linalg.norm(got["evaluated"] * mm - ours, axis=2)
            per_frame = gap.max(axis=1)
            worst = int(np.argmax(per_frame))
            bad = int((per_frame > tolerance_mm).sum())
            results.append((
                f"evaluated mesh at {len(keys)} frames vs {ref_path.name}"
                f"{' (placed by its head motion)' if reference['moving'] else ''}: "
                f"max vertex distance (mm); {bad} frames over {tolerance_mm:g} mm, "
                f"median of the per-frame max {np.median(per_frame):.3g} mm, worst at frame "
                f"{frames[worst]}", f"<= {tolerance_mm:g}", float(per_frame.max()),
                bool(per_frame.max() <= tolerance_mm)))
    print(f"{path}: Blender {got['version']}, object {got['object']!r}, "
          f"action {got['action']!r}, scene fps {fps}, {seconds:.1f} s in Blender"
          + ("" if ref_path is not None or times is None else "; no mesh sequence beside it: "
             "evaluated mesh not checked"))
    ok = True
    for what, expect, have, good in results:
        shown = (lambda v: f"{len(v)} names: {v[:3]}...{v[-1:]}"
                 if isinstance(v, list) and len(v) > 5 else v)
        print(f"  {'ok  ' if good else 'FAIL'} {what}: expected {shown(expect)}; "
              f"Blender {shown(have)}")
        ok &= bool(good)
    return ok


def main(argv) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paths", nargs="+", type=Path)
    parser.add_argument("--frames", type=int, help="check N evenly spaced frames (default all)")
    parser.add_argument("--tolerance-mm", type=float, default=0.01)
    args = parser.parse_args(argv)
    files = []
    for p in args.paths:
        files += sorted(p.rglob("*.glb")) if p.is_dir() else [p]
    if not files:
        print("no .glb files given or found", file=sys.stderr)
        return 2
    results = [check(f, n_frames=args.frames, tolerance_mm=args.tolerance_mm) for f in files]
    print(f"{sum(results)} of {len(results)} files play back in Blender as computed")
    return 0 if all(results) else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
