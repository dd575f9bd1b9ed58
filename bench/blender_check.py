"""Open the project's .glb files in Blender (bpy) and check what Blender sees against the files.

Run with the Python of a venv that has ``bpy`` (``make blender-check`` builds
``.venv-blender``); it needs nothing of the project, so it reads each file's
glTF JSON itself (the GLB header and its first chunk) for what to expect:

* vertex count: the POSITION accessor's count of every mesh primitive;
* shape keys: Blender's ``Basis`` followed by the morph targets, named as
  ``mesh.extras.targetNames``;
* the weight animation: Blender's glTF importer keys the shape-key values at
  ``time × scene fps``; the scene's fps is set to the file's frame rate
  (``1 / (t₁ − t₀)``, the exporter writes one key per captured frame) before
  importing, so the action must span frames ``t_first × fps`` to
  ``t_last × fps``, with one key per frame on every shape key, whose values
  are the file's weights (float32: to 1e-6).

Usage: ``python bench/blender_check.py FILE_OR_DIR...`` (directories: every
``*.glb`` under them). Prints one block per file; exits 1 if any check fails.
"""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path

import numpy as np

GLB_MAGIC = 0x46546C67          # b"glTF"
JSON_CHUNK = 0x4E4F534A         # b"JSON"
BIN_CHUNK = 0x004E4942          # b"BIN\0"


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
    """What the file says: vertices, shape names, key times."""
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


def blender_view(path: Path, fps: int) -> dict:
    """What Blender imports from `path` into an empty scene at `fps`."""
    import bpy  # here, so that the file's side can be read without Blender

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.context.scene.render.fps = fps
    bpy.context.scene.render.fps_base = 1.0
    bpy.ops.import_scene.gltf(filepath=str(path))
    meshes = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    if len(meshes) != 1:
        raise SystemExit(f"{path}: Blender imported {len(meshes)} mesh objects, expected 1")
    obj = meshes[0]
    keys = obj.data.shape_keys
    blocks = [] if keys is None else [b.name for b in keys.key_blocks]
    action = None if keys is None or keys.animation_data is None \
        else keys.animation_data.action
    view = {"version": bpy.app.version_string, "object": obj.name,
            "vertices": len(obj.data.vertices), "shape_keys": blocks,
            "action": None if action is None else action.name}
    if action is not None:
        view["frame_range"] = tuple(float(x) for x in action.frame_range)
        counts = {len(c.keyframe_points) for c in action.fcurves}
        view["fcurves"] = len(action.fcurves)
        view["keys_per_curve"] = sorted(counts)
        values = {}
        for curve in action.fcurves:            # data_path 'key_blocks["name"].value'
            name = curve.data_path.split('"')[1]
            points = np.empty(2 * len(curve.keyframe_points))
            curve.keyframe_points.foreach_get("co", points)
            values[name] = points[1::2]
        view["values"] = values
    return view


def check(path: Path) -> bool:
    doc, binary = read_glb(path)
    want = expected(doc, binary)
    times = want["times"]
    fps = 24 if times is None or len(times) < 2 else int(round(1.0 / (times[1] - times[0])))
    got = blender_view(path, fps)
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
        results.append(("keys per shape curve", len(times), got.get("keys_per_curve"),
                        got.get("keys_per_curve") == [len(times)]
                        and got.get("fcurves") == len(want["names"])))
        values = got.get("values", {})
        worst = max((np.abs(values[name] - want["weights"][:, i]).max()
                     for i, name in enumerate(want["names"]) if name in values),
                    default=np.inf)
        results.append(("key values (max |Blender - file|)", 0.0, float(worst),
                        len(values) == len(want["names"]) and worst <= 1e-6))
    print(f"{path}: Blender {got['version']}, object {got['object']!r}, "
          f"action {got['action']!r}, scene fps {fps}")
    ok = True
    for what, expect, have, good in results:
        shown = (lambda v: f"{len(v)} names: {v[:3]}...{v[-1:]}"
                 if isinstance(v, list) and len(v) > 5 else v)
        print(f"  {'ok  ' if good else 'FAIL'} {what}: file {shown(expect)}; "
              f"Blender {shown(have)}")
        ok &= bool(good)
    return ok


def main(argv) -> int:
    files = []
    for arg in argv:
        p = Path(arg)
        files += sorted(p.rglob("*.glb")) if p.is_dir() else [p]
    if not files:
        print("no .glb files given or found", file=sys.stderr)
        return 2
    results = [check(f) for f in files]
    print(f"{sum(results)} of {len(results)} files open in Blender as written")
    return 0 if all(results) else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
