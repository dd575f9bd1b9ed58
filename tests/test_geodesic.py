"""Heat-method geodesic distances against exact geodesics and known geometry."""

from __future__ import annotations

import time

import igl
import numpy as np
import pytest
import trimesh
from helpers import slit_grid
from tolerances import EXACT_FLOAT64, GEODESIC_HEAT_MAX_REL, GEODESIC_HEAT_MEAN_REL, MESH_EXACT

import mocap.mesh.geodesic as geodesic
from mocap import InputError
from mocap.mesh._geodesic_cache import FieldCache
from mocap.mesh.geodesic import HeatGeodesics


def test_flat_grid_matches_euclidean_and_exact():
    v, f, _, _ = slit_grid(slit=0.0)
    geo = HeatGeodesics(v, f)
    sources = np.array([0, 12 * 25 + 12, 7 * 25 + 3])
    heat = geo.from_vertices(sources)
    euclid = np.linalg.norm(v[None, :, :] - v[sources, None, :], axis=2)
    exact = np.stack([igl.exact_geodesic(v, f, VS=np.array([s]), VT=np.arange(len(v)))
                      for s in sources])
    np.testing.assert_allclose(exact, euclid, atol=MESH_EXACT)
    far = euclid > 0.25                         # the heat method is O(h) near the source
    rel = np.abs(heat - euclid)[far] / euclid[far]
    assert rel.max() < GEODESIC_HEAT_MAX_REL
    assert rel.mean() < GEODESIC_HEAT_MEAN_REL
    assert np.all(heat[np.arange(3), sources] == 0.0)


def test_slit_forces_the_way_around():
    v, f, upper, lower = slit_grid()
    geo = HeatGeodesics(v, f)
    a, b = upper[3], lower[3]              # facing each other across the cut
    tip = v[upper[np.flatnonzero(upper == lower)[0]]]    # first vertex not cut
    around = np.linalg.norm(v[a] - tip) + np.linalg.norm(tip - v[b])
    heat = geo.from_vertices([a])[0, b]
    exact = igl.exact_geodesic(v, f, VS=np.array([a]), VT=np.array([b]))[0]
    assert np.linalg.norm(v[a] - v[b]) == 0.0
    np.testing.assert_allclose(exact, around, rtol=MESH_EXACT)
    np.testing.assert_allclose(heat, exact, rtol=GEODESIC_HEAT_MAX_REL)


def test_surface_points_blend_vertex_fields():
    v, f, _, _ = slit_grid(slit=0.0)
    geo = HeatGeodesics(v, f)
    corner = f[40, 1]
    at_vertex = geo.from_surface_points([40], [[0.0, 1.0, 0.0]])
    np.testing.assert_array_equal(at_vertex, geo.from_vertices([corner]))
    bary = np.array([[0.2, 0.5, 0.3]])
    blended = geo.from_surface_points([40], bary)
    np.testing.assert_allclose(blended[0], bary[0] @ geo.from_vertices(f[40]), rtol=EXACT_FLOAT64)


def test_symmetric_fields_agree_with_point_distances():
    v, f, _, _ = slit_grid()
    geo = HeatGeodesics(v, f)
    rng = np.random.default_rng(3)
    faces = rng.choice(len(f), 8, replace=False)
    bary = rng.dirichlet(np.ones(3), 8)
    raw = geo.at_surface_points(geo.from_surface_points(faces, bary), faces, bary)
    dist = geo.between_surface_points(faces, bary)
    fields = geo.from_surface_points(faces, bary, symmetric=True)
    np.testing.assert_allclose(dist, dist.T, atol=EXACT_FLOAT64)
    np.testing.assert_allclose(dist, (raw + raw.T) / 2 - np.diag(np.diag(raw)), atol=MESH_EXACT)
    np.testing.assert_allclose(geo.at_surface_points(fields, faces, bary), dist, atol=MESH_EXACT)


def test_locate_recovers_surface_points():
    v, f, _, _ = slit_grid(slit=0.0)
    v = v + np.c_[np.zeros((len(v), 2)), 0.1 * np.sin(3 * v[:, 0])]
    geo = HeatGeodesics(v, f)
    rng = np.random.default_rng(4)
    faces = rng.choice(len(f), 10, replace=False)
    bary = rng.dirichlet(np.ones(3) * 3, 10)
    points = np.einsum("pk,pkd->pd", bary, v[f[faces]])
    got_faces, got_bary = geo.locate(points)
    np.testing.assert_array_equal(got_faces, faces)
    np.testing.assert_allclose(got_bary, bary, atol=MESH_EXACT)


def test_ict_mouth_is_open(ict_neutral_path):
    mesh = trimesh.load(ict_neutral_path, process=False)
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)   # quads split by trimesh
    assert f.shape == (2 * 9230, 3)
    upper_inner, lower_inner = 5533, 5517       # Multi-PIE landmarks 62 and 66
    dist = HeatGeodesics(v, f).from_vertices([upper_inner])[0, lower_inner]
    assert dist > 20 * np.linalg.norm(v[upper_inner] - v[lower_inner])


@pytest.mark.parametrize("faces, match", [
    (np.array([[0, 1, 2, 3]]), r"shape \(n_faces, 3\)"),
    (np.array([[0, 1, 9]]), r"faces index vertices 0\.\.3"),
    (np.array([[0.0, 1, 2]]), "integer vertex ids"),
    (np.array([[0, 1, 2]]), "2 connected pieces"),
])
def test_mesh_errors(faces, match):
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 0]])
    with pytest.raises(InputError, match=match):
        HeatGeodesics(v, faces)


def test_point_errors():
    v, f, _, _ = slit_grid(n=5, slit=0.0)
    geo = HeatGeodesics(v, f)
    with pytest.raises(InputError, match="expected non-negative weights summing to 1"):
        geo.from_surface_points([0], [[0.5, 0.6, 0.0]])
    with pytest.raises(InputError, match=r"face_ids must be in 0\.\.31"):
        geo.from_surface_points([32], [[1.0, 0.0, 0.0]])
    with pytest.raises(InputError, match="sources must be vertex ids"):
        geo.from_vertices([25])


def _grid_sources(monkeypatch):
    """A mesh and sources whose solves here are slowed (20 ms a chunk), so that a helper is
    ready before this process is done; the chunks helpers answered are counted."""
    import mocap.mesh._geodesic_helpers as helpers

    v, f, _, _ = slit_grid()
    geo = HeatGeodesics(v, f)
    solve, answered = geo._solve, []
    monkeypatch.setattr(geodesic, "FIELDS", FieldCache(0))     # every call solves

    def slowly(sources):
        time.sleep(0.02)
        return solve(sources)
    monkeypatch.setattr(geo, "_solve", slowly)
    answer = helpers._Helper.answer
    monkeypatch.setattr(helpers._Helper, "answer",
                        lambda self: (answered.append(True), answer(self))[1])
    return geo, np.arange(0, len(v), 3), answered


@pytest.mark.parametrize("processes", [1, 2])
def test_fields_shared_with_helper_processes_are_the_same_bits(processes, monkeypatch):
    """Helper processes (fresh interpreters, each factorizing the mesh again) solve chunks
    of the sources: the fields are those solved here alone, bit for bit."""
    geo, sources, answered = _grid_sources(monkeypatch)
    alone = geo.from_vertices(sources, processes=0)
    np.testing.assert_array_equal(geo.from_vertices(sources, processes=processes), alone)
    assert answered                                     # the helpers took their share


@pytest.mark.parametrize("program", [
    "import sys; sys.exit(3)",                                     # dies at its start
    "import pickle, sys; pickle.load(sys.stdin.buffer); pickle.load(sys.stdin.buffer); "
    "out = sys.stdout.buffer; pickle.dump('ready', out); out.flush(); "
    "pickle.load(sys.stdin.buffer)",                               # dies on its first chunk
    "import pickle, sys; pickle.load(sys.stdin.buffer); pickle.load(sys.stdin.buffer); "
    "out = sys.stdout.buffer; pickle.dump('ready', out); out.flush(); "
    "[(pickle.load(sys.stdin.buffer), pickle.dump('solve failed', out), out.flush()) "
    "for _ in iter(int, 1)]",                                      # answers with an error
])
def test_what_a_helper_cannot_solve_is_solved_here(program, monkeypatch):
    import mocap.mesh._geodesic_helpers as helpers

    monkeypatch.setattr(helpers, "_BOOT", program)
    geo, sources, _ = _grid_sources(monkeypatch)
    np.testing.assert_array_equal(geo.from_vertices(sources, processes=1),
                                  geo.from_vertices(sources, processes=0))


def test_large_fields_are_shared_by_default_with_a_helper_per_spare_core(monkeypatch):
    shared = []
    monkeypatch.setattr(geodesic, "solve_shared",
                        lambda solve, mesh, sources, out, helpers: (
                            shared.append(helpers), out.__setitem__(slice(None),
                                                                    solve(sources))))
    monkeypatch.setattr(geodesic, "worker_threads", lambda: 3)
    geo, sources, _ = _grid_sources(monkeypatch)
    geo.from_vertices(sources)
    assert shared == []                                 # too few values to share
    monkeypatch.setattr(geodesic, "SHARED_FROM", sources.size * geo.n_vertices)
    geo.from_vertices(sources)
    assert shared == [2]
    monkeypatch.setattr(geodesic, "worker_threads", lambda: 16)
    geo.from_vertices(sources)
    assert shared == [2, geodesic.MAX_HELPERS]          # each helper factorizes the mesh
    with pytest.raises(InputError, match="processes"):
        geo.from_vertices(sources, processes=-1)


def _counted(monkeypatch):
    """A fresh cache of fields for the test, and the vertices libigl solves, in order."""
    monkeypatch.setattr(geodesic, "FIELDS", FieldCache(1 << 30))
    solved = []
    solve = igl.heat_geodesics_solve
    monkeypatch.setattr(igl, "heat_geodesics_solve",
                        lambda data, gamma: (solved.extend(gamma.tolist()), solve(data, gamma))[1])
    return solved


def test_the_next_geodesics_on_the_same_mesh_solve_only_new_sources(monkeypatch):
    """A session's next take: another object on a copy of the same mesh finds the fields
    solved before (the same bits as solved afresh) and solves only the sources it lacks,
    whatever their order and repeats."""
    v, f, _, _ = slit_grid()
    solved = _counted(monkeypatch)
    first = HeatGeodesics(v, f).from_vertices([3, 40, 7])
    assert solved == [3, 7, 40]
    solved.clear()
    again = HeatGeodesics(v.copy(), f.copy())
    fields = again.from_vertices([40, 5, 3, 40])
    assert solved == [5]
    geodesic.FIELDS.clear()
    fresh = HeatGeodesics(v, f).from_vertices([40, 5, 3, 40])       # the oracle: solved
    np.testing.assert_array_equal(fields, fresh)
    np.testing.assert_array_equal(fields[[0, 2, 3]], first[[1, 0, 1]])
    fields[0] = -1.0                             # the caller's copy: the kept field stays
    np.testing.assert_array_equal(again.from_vertices([40])[0], fresh[0])


@pytest.mark.parametrize("change", ["vertex", "faces", "time", "delaunay"])
def test_another_mesh_or_heat_method_solves_its_own(monkeypatch, change):
    v, f, _, _ = slit_grid()
    solved = _counted(monkeypatch)
    HeatGeodesics(v, f).from_vertices([3])
    options = {}
    if change == "vertex":
        v = v.copy()
        v[10, 2] += 1e-9
    elif change == "faces":                       # the same triangles, another corner first
        f = np.roll(f, 1, axis=1)
    elif change == "time":
        options = {"time_factor": 0.5}
    else:
        options = {"intrinsic_delaunay": True}
    solved.clear()
    HeatGeodesics(v, f, **options).from_vertices([3])
    assert solved == [3]


def test_the_kept_fields_stay_within_their_bound_the_least_recent_mesh_first():
    cache, rows = FieldCache(5 * 80), np.arange(3 * 10, dtype=float).reshape(3, 10)
    cache.keep(b"a", [1, 2, 3], rows)                    # fields of 80 bytes: 5 fit
    cache.keep(b"b", [1, 2], rows[:2])
    assert cache.nbytes == 400 and set(cache.take(b"a", [1])) == {1}     # "a" used last
    cache.keep(b"c", [7], rows[2:])                      # "b" is the least recent: 1 goes
    assert cache.nbytes == 400
    assert set(cache.take(b"b", [1, 2])) == {2} and set(cache.take(b"a", [1, 2, 3])) == {1, 2, 3}
    np.testing.assert_array_equal(cache.take(b"c", [7])[7], rows[2])
    cache.keep(b"d", [1, 2, 3, 4, 5], np.zeros((5, 10)))   # a whole bound's worth: the rest go
    assert cache.nbytes == 400 and not cache.take(b"a", [1, 2, 3]) and not cache.take(b"c", [7])
    none = FieldCache(0)
    none.keep(b"a", [1], rows[:1])
    assert none.take(b"a", [1]) == {} and none.nbytes == 0
    kept = cache.take(b"d", [4])[4]
    with pytest.raises(ValueError):                       # read-only: shared by the takes
        kept[0] = 1.0
    cache.clear()
    assert cache.nbytes == 0 and cache.take(b"d", [4]) == {}
