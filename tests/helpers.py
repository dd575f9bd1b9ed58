"""Helpers shared by several test files (not fixtures: those are in conftest.py)."""

from __future__ import annotations

import base64
import os
import sys
import time
from html.parser import HTMLParser
from pathlib import Path

import igl
import numpy as np
import pygltflib
import pytest
from scipy.spatial.distance import cdist

from mocap.bind import Binding
from mocap.errors import InputError
from mocap.markerset import MarkerSet
from mocap.mesh.layout import make_layout
from mocap.mesh.mouth import find_mouth
from mocap.retarget.cross_validation import leave_one_out
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


# ---------------------------------------------------------------- reports

class ReportPage(HTMLParser):
    """A report page read back: images, external references, table cells by table id
    (a cell's data-value, else its text), section headings and warning paragraphs."""

    def __init__(self):
        super().__init__()
        self.images, self.links, self.tables = [], [], {}
        self.headings, self.warnings = [], []
        self._table = self._row = self._text = None

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "h2" or (tag == "p" and attrs.get("class") == "warning"):
            self._text = self.headings if tag == "h2" else self.warnings
            self._text.append("")
        if tag == "img":
            self.images.append(attrs["src"])
        if tag in ("link", "script", "iframe") or "href" in attrs:
            self.links.append((tag, attrs))
        if tag == "table":
            self._table = self.tables.setdefault(attrs["id"], [])
        elif tag == "tr" and self._table is not None:
            self._row = []
            self._table.append(self._row)
        elif tag in ("td", "th") and self._row is not None:
            self._row.append(attrs.get("data-value", ""))

    def handle_data(self, data):
        if self._row and self._row[-1] == "":
            self._row[-1] = data
        if self._text is not None:
            self._text[-1] += data

    def handle_endtag(self, tag):
        if tag == "table":
            self._table = self._row = None
        if tag in ("h2", "p"):
            self._text = None

    @classmethod
    def read(cls, path) -> "ReportPage":
        """The page of an HTML file (UTF-8)."""
        page = cls()
        page.feed(Path(path).read_text(encoding="utf-8"))
        page.close()
        return page


# ---------------------------------------------------------------- marker layouts

def layout_binding(layout, labels, *, mm_per_unit: float = 10.0) -> Binding:
    """The exact binding of a simulated capture: its layout's surface points, capture mm to
    mesh units (default cm), no rotation."""
    idx = [layout.index(x) for x in labels]
    return Binding(labels=tuple(labels), scale=1 / mm_per_unit, rotation=np.eye(3),
                   translation=np.zeros(3), face_ids=layout.face_ids[idx],
                   vertex_ids=layout.vertex_ids[idx], barycentric=layout.weights[idx],
                   distances=np.zeros(len(idx)), rms=0.0, skin_offset=0.0, n_landmarks=0,
                   n_iterations=0, converged=True, message="layout (truth)")


def lip_regions(markerset, labels) -> dict:
    """The region map of the retargeting's region variants on `labels`: the marker set's
    upper and lower lip, then ``"other"`` (every other marker of `labels`)."""
    lips = [x for r in ("upper_lip", "lower_lip") for x in markerset.regions[r]]
    return {"upper_lip": list(markerset.regions["upper_lip"]),
            "lower_lip": list(markerset.regions["lower_lip"]),
            "other": [x for x in labels if x not in lips]}


def one_variant_at_a_time(geometry, *, epsilons, **options) -> list:
    """:func:`mocap.retarget.cross_validation.leave_one_out_many` by the per-variant path:
    ``leave_one_out`` called for each shape parameter alone, an InputError in the place of a
    variant it raises for. The oracle of the batched path (and its time in the benchmark)."""
    out = []
    for epsilon in epsilons:
        try:
            out.append(leave_one_out(geometry, epsilon=epsilon, **options))
        except InputError as exc:
            out.append(exc)
    return out


#: The ICT layout's lip markers moved off the lips as on a real take from another lab:
#: marker -> (direction on the ICT mesh (y up, +x the subject's left), distance (cm) from
#: the lip line, or from a mesh landmark): upper lip 10-12 mm above the line, lower lip
#: 16-18 mm below (a lower-lip marker 18 mm below the lip), the corner markers 10 mm out
#: from the mouth corners (~71 mm apart against the ICT corners' 51 mm).
OFF_LIP_MOVES = {"lip-upper1": ((0, 1, 0), 1.0, None), "lip-upper3": ((0, 1, 0), 1.2, None),
                 "lip-upper5": ((0, 1, 0), 1.0, None), "lip-lower1": ((0, -1, 0), 1.6, None),
                 "lip-lower3": ((0, -1, 0), 1.8, None), "lip-lower5": ((0, -1, 0), 1.6, None),
                 "mouth-corner-L": ((1, 0, 0), 1.0, "mouth_corner_left"),
                 "mouth-corner-R": ((-1, 0, 0), 1.0, "mouth_corner_right")}
#: ... and the mouth made sparse: three markers per lip, no philtrum or mentolabial markers.
OFF_LIP_DROPPED = ("lip-upper2", "lip-upper4", "lip-lower2", "lip-lower4", "philtrum-L",
                   "philtrum-R", "mentolabial-L", "mentolabial-R")


def lip_line(mesh, landmarks) -> np.ndarray:
    """Points (P, 3) where the lips meet at rest, from 20 % to 80 % of the mouth's width:
    each lip's vertices within 0.5 mm (ICT cm) of its closest approach to the other lip."""
    mouth = find_mouth(mesh, landmarks, middle=(0.2, 0.8))
    v = mesh.vertices
    d = cdist(v[mouth.upper], v[mouth.lower])
    return np.r_[v[mouth.upper[d.min(axis=1) < d.min(axis=1).min() + 0.05]],
                 v[mouth.lower[d.min(axis=0) < d.min(axis=0).min() + 0.05]]]


def off_lip_layout(layout, mesh, markerset, landmarks):
    """The ICT layout with its lip markers moved off the lips and the mouth made sparse.

    Each moved marker slides over the surface along its direction (the closest surface
    point of its straight path) until it is its distance from the lip line or its
    landmark (:data:`OFF_LIP_MOVES`); the markers of :data:`OFF_LIP_DROPPED` go. Returns
    the new layout and the marker set without the dropped markers.
    """
    v, f = mesh.vertices, mesh.faces
    line = lip_line(mesh, landmarks)
    steps = np.linspace(0.0, 3.0, 601)                                    # cm, 0.05 mm apart
    moved = [label for label in layout.labels if label in OFF_LIP_MOVES]
    start = layout.positions(v, offset=False)[[layout.index(x) for x in moved]]
    paths = np.concatenate([p + steps[:, None] * np.asarray(OFF_LIP_MOVES[x][0], float)
                            for x, p in zip(moved, start)])
    _, faces, closest = igl.point_mesh_squared_distance(paths, v, f)
    far = np.stack([cdist(closest[k * len(steps):(k + 1) * len(steps)],
                          line if OFF_LIP_MOVES[x][2] is None
                          else v[[landmarks[OFF_LIP_MOVES[x][2]]]]).min(axis=1)
                    for k, x in enumerate(moved)])
    specs = {}
    for i, label in enumerate(layout.labels):
        if label in OFF_LIP_DROPPED:
            continue
        if label in OFF_LIP_MOVES:
            k = moved.index(label)
            j = k * len(steps) + int(np.argmax(far[k] >= OFF_LIP_MOVES[label][1]))
            tri = v[f[faces[j:j + 1]]]
            bary = np.asarray(igl.barycentric_coordinates(
                closest[j:j + 1], *(np.ascontiguousarray(tri[:, c]) for c in range(3))))[0]
            bary = np.clip(bary, 0.0, None)
            specs[label] = {"face": int(faces[j]), "bary": (bary / bary.sum()).tolist()}
        elif layout.face_ids[i] < 0:
            specs[label] = {"vertex": int(layout.vertex_ids[i, 0])}
        else:
            specs[label] = {"face": int(layout.face_ids[i]), "bary": layout.weights[i].tolist()}
        specs[label]["offset"] = float(layout.offsets[i])
    regions = {r: tuple(x for x in members if x not in OFF_LIP_DROPPED)
               for r, members in markerset.regions.items()}
    kept = {k: x for k, x in markerset.landmarks.items() if x not in OFF_LIP_DROPPED}
    return (make_layout(mesh, specs, name=f"{layout.name}-off-lips"),
            MarkerSet(name=f"{markerset.name}-off-lips", head=markerset.head, regions=regions,
                      clusters=markerset.clusters, landmarks=kept))


def stub_take(calls, bases=None, helpers=None):
    """A stand-in for one take of ``run_takes`` (``fit.pipeline.session._guarded``) that
    commits one small file through the completion API; appends each capture's name to
    `calls` (the session basis it was given to `bases`, its figure helpers to `helpers`)."""
    from fit.pipeline.completion import begin_take, commit_take

    def fake(capture, config, name, provenance, session_basis=None, figure_helpers=None,
             kept=None, built=None):
        calls.append(capture.name)
        if bases is not None:
            bases.append(session_basis)
        if helpers is not None:
            helpers.append(figure_helpers)
        stage = begin_take(config.output, name)
        (stage / "out.txt").write_text(f"{capture.name} {provenance.key}")
        record = commit_take(stage, config.output, name, provenance,
                             summary={"status": "ok", "skipped": False, "error": None})
        return {**record.summary, "files": [f"{name}/{f}" for f in record.files]}
    return fake


def wait_for_file(path, seconds: float = 60.0) -> None:
    """Until `path` exists: a figure helper has drawn a figure submitted before `run`."""
    deadline = time.monotonic() + seconds
    while not os.path.exists(path):
        if time.monotonic() > deadline:
            pytest.fail(f"no helper drew {path} within {seconds} s")
        time.sleep(0.05)


def kernel_or_numpy(param: str, monkeypatch, module, loader: str, threshold: str) -> str:
    """Make `module` do its work by its compiled kernel (numba: the speed extra, in .[test])
    for any size of work, or by NumPy, as `param` says ("compiled" or "numpy"): `loader`
    names its cached kernel loader, `threshold` the work from which it loads numba."""
    if param == "compiled":
        assert getattr(module, loader)() is not None
        monkeypatch.setattr(module, threshold, 0)
    else:
        monkeypatch.setattr(module, loader, lambda: None)
    return param


def numba_cannot_cache(monkeypatch, module: str) -> None:
    """Make importing the numba kernel `module` raise what numba raises when it can write
    its compiled code nowhere (a read-only install and home): RuntimeError, not
    ImportError. Undone with `monkeypatch`."""
    class NoCacheFolder:
        @staticmethod
        def find_spec(fullname, path=None, target=None):
            if fullname == module:
                raise RuntimeError(f"cannot cache function: no locator available for file "
                                   f"'{module.rsplit('.', 1)[-1]}.py'")
            return None
    monkeypatch.delitem(sys.modules, module, raising=False)
    monkeypatch.setattr(sys, "meta_path", [NoCacheFolder, *sys.meta_path])
