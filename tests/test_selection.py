"""``kernel = "auto"``: the retargeting variant chosen by cross-validation, on the ICT truth."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.sparse as sp
from helpers import (
    ICT_LANDMARKS_TOML,
    jaw_open_peak_time,
    layout_binding,
    lip_regions,
    off_lip_layout,
    one_variant_at_a_time,
)
from scipy.spatial import cKDTree
from tolerances import AUTO_VS_TRUTH_BEST, BATCHED_VS_ONE_AT_A_TIME

from mocap import InputError
from mocap.mesh.landmarks import load_mesh_landmarks
from mocap.mesh.mouth import find_mouth
from mocap.retarget import selection
from mocap.retarget.cross_validation import MarkerGeometry, leave_one_out
from mocap.retarget.lip_seal import check_lip_seal, contradicts, lip_witness
from mocap.retarget.rbf import build_rbf_operator
from mocap.retarget.retargeting import (
    RetargetOptions,
    build_retarget_operator,
    marker_displacements,
    retarget,
)
from mocap.synth.capture import simulate_capture
from mocap.take import Take

MM_PER_CM = 10.0


def _simulate(basis, performance, layout, markerset, *, start, duration):
    """The noisy capture in the head frame (exact stabilization) and its truth."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                   # TongueOut: no ICT shape
        sim = simulate_capture(basis, performance, layout, markerset.head, rate=15.0,
                               start=start, duration=duration, noise_mm=0.2, seed=4)
    truth = sim.truth
    head = np.einsum("tji,tmj->tmi", truth.rotation,
                     sim.take.positions - truth.translation[:, None])
    take = Take(sim.take.labels, head, rate=sim.take.rate)
    neutral = int(np.argmin(np.abs(truth.weights).sum(axis=1)))
    return take, truth, neutral


def _truth_errors(candidates, geometry, displacements, basis, truth, neutral, vertices,
                  regions):
    """RMS vertex error (mm) of every scored candidate against the truth, on `vertices`."""
    shapes = basis.displacements[:, vertices].reshape(len(basis.names), -1)
    true = ((truth.weights - truth.weights[neutral]) @ shapes).reshape(
        len(displacements), len(vertices), 3)
    between, _, fields = geometry.distances("geodesic")
    errors = {}
    for i, c in enumerate(candidates):
        if not np.isfinite(c.score_mm):
            continue
        geodesic = c.distance == "geodesic"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            op = build_rbf_operator(geometry.centers, geometry.vertices[vertices],
                                    kernel=c.kernel, epsilon=c.epsilon, distance=c.distance,
                                    precomputed=(fields[:, vertices], between) if geodesic
                                    else None, regions=regions if c.use_regions else None,
                                    labels=geometry.labels)
        w = op.matrix.toarray() if sp.issparse(op.matrix) else op.matrix
        errors[i] = MM_PER_CM * float(np.sqrt(np.mean(np.sum(
            (np.matmul(w, displacements) - true) ** 2, axis=-1))))
    return errors


@pytest.fixture(scope="module")
def ict_auto(ict_basis, ict_layout, ict_markerset, arkit_performance):
    take, truth, neutral = _simulate(ict_basis, arkit_performance, ict_layout, ict_markerset,
                                     start=15.0, duration=20.0)
    labels = ict_markerset.face_markers
    binding = layout_binding(ict_layout, labels)
    mesh = ict_basis.neutral
    landmarks = load_mesh_landmarks(ICT_LANDMARKS_TOML, mesh)
    result = retarget(take, binding, mesh, ict_markerset, neutral_frame=neutral, align=False,
                      mouth=find_mouth(mesh, landmarks))
    regions = lip_regions(ict_markerset, labels)
    return dict(result=result, truth=truth, neutral=neutral, binding=binding, labels=labels,
                regions=regions)


def test_auto_is_within_10_percent_of_the_truth_best_variant(ict_auto, ict_basis):
    result, truth = ict_auto["result"], ict_auto["truth"]
    chosen = result.selection
    assert len(chosen.candidates) == 4 * sum(len(v) for v in selection.SHAPES.values())
    assert chosen.lips_checked
    geometry = MarkerGeometry.from_binding(ict_auto["binding"], ict_basis.neutral,
                                           ict_auto["labels"])
    near = cKDTree(geometry.centers).query(ict_basis.neutral.vertices)[0] * MM_PER_CM <= 15.0
    vertices = np.flatnonzero(near)[::3]                    # the face the markers cover
    errors = _truth_errors(chosen.candidates, geometry, result.displacements, ict_basis,
                           truth, ict_auto["neutral"], vertices, ict_auto["regions"])
    best = min(errors, key=errors.get)
    assert errors[chosen.chosen] <= AUTO_VS_TRUTH_BEST * errors[best], (
        f"auto chose {chosen.best.name} ({errors[chosen.chosen]:.3f} mm), the truth-best is "
        f"{chosen.candidates[best].name} ({errors[best]:.3f} mm)")
    # the operator built is the variant chosen, and it is what the retargeting records
    assert result.options.kernel == chosen.best.kernel
    assert result.options.distance == chosen.best.distance
    assert result.cross_validation.rms == pytest.approx(chosen.best.score_mm, rel=1e-9)


def test_the_selection_record_lists_every_variant_and_the_choice(ict_auto):
    record = ict_auto["result"].selection.to_dict()
    assert record["chosen"] == record["tried"][ict_auto["result"].selection.chosen]
    assert {t["kernel"] for t in record["tried"]} == set(selection.SHAPES)
    assert {(t["distance"], t["use_regions"]) for t in record["tried"]} == {
        ("euclidean", False), ("euclidean", True), ("geodesic", False), ("geodesic", True)}
    scored = [t["score_mm"] for t in record["tried"] if t["score_mm"] is not None]
    assert record["chosen"]["score_mm"] == min(
        t["score_mm"] for t in record["tried"]
        if t["score_mm"] is not None and t["lips_shut_frames"] == 0)
    assert len(scored) >= 80


@pytest.fixture(scope="module")
def off_lips(ict_basis, ict_layout, ict_markerset, ict_landmarks, arkit_performance):
    """The ICT face seen by markers that sit off the lips, through its jaw-open stretch."""
    layout, markerset = off_lip_layout(ict_layout, ict_basis.neutral, ict_markerset,
                                       ict_landmarks)
    start = max(0.0, jaw_open_peak_time(arkit_performance) - 10.0)
    take, truth, neutral = _simulate(ict_basis, arkit_performance, layout, markerset,
                                     start=start, duration=20.0)
    binding = layout_binding(layout, markerset.face_markers)
    return dict(take=take, truth=truth, neutral=neutral, binding=binding,
                markerset=markerset)


def test_off_the_lips_auto_opens_the_mouth_that_tps_keeps_shut(off_lips, ict_basis,
                                                               ict_landmarks):
    """Euclidean interpolation moves the touching lips together; the lip-seal check names
    the frames, and "auto" chooses a variant whose mouth opens there."""
    mesh = ict_basis.neutral
    kwargs = dict(neutral_frame=off_lips["neutral"], align=False,
                  mouth=find_mouth(mesh, ict_landmarks))
    tps = retarget(off_lips["take"], off_lips["binding"], mesh, off_lips["markerset"],
                   options=RetargetOptions(kernel="thin_plate_spline"), **kwargs)
    auto = retarget(off_lips["take"], off_lips["binding"], mesh, off_lips["markerset"],
                    **kwargs)
    assert tps.selection is None and auto.selection.best.lips_shut_frames == 0
    mouth, witness = auto.mouth, auto.lip_witness
    face = off_lips["take"].select(tps.labels)
    truth = off_lips["truth"]
    ids = mouth.vertex_ids
    true_lips = mesh.vertices[ids] + np.einsum(
        "tn,nvc->tvc", truth.weights, ict_basis.displacements[:, ids])
    gaps = {"truth": MM_PER_CM * mouth.gap(true_lips)}
    for name, r in (("TPS", tps), ("auto", auto)):
        w = r.operator.matrix
        w = (w.toarray() if sp.issparse(w) else w)[ids]
        gaps[name] = MM_PER_CM * mouth.gap(mesh.vertices[ids] + np.matmul(w, r.displacements))
    rest = face.positions[off_lips["neutral"]]
    check = check_lip_seal(witness.distance(face.positions), gaps,
                           rest_distance=float(witness.distance(rest[None])[0]),
                           rest_gap=MM_PER_CM * float(mouth.gap(mesh.vertices[ids])))
    shut = check.shut("TPS")
    truth_open = check.mesh_opening("truth") >= check.marker_open_mm
    assert check.marker_open_mm > check.open_mm          # markers 30 mm apart at rest
    assert truth_open.sum() > 20 and not check.shut("truth").any()
    assert shut[truth_open].mean() > 0.9               # flagged where the mouth really opens
    assert (check.mesh_opening("truth")[shut] > check.open_mm).all()   # and only there
    assert check.shut("auto").sum() < 0.1 * shut.sum()
    assert any("the TPS mesh keeps the mouth shut" in m for m in check.messages())


def test_variants_scored_together_as_each_alone(off_lips, ict_basis, ict_landmarks,
                                                monkeypatch):
    """The grid's variants of one kernel, distance and region map are solved as stacks:
    every score, lip reading, shift and note, and the choice, are those of the per-variant
    path (``leave_one_out`` one variant at a time)."""
    markerset, mesh = off_lips["markerset"], ict_basis.neutral
    labels = markerset.face_markers
    geometry = MarkerGeometry.from_binding(off_lips["binding"], mesh, labels)
    d = marker_displacements(off_lips["take"].select(labels), off_lips["binding"],
                             neutral_frame=off_lips["neutral"])
    mouth = find_mouth(mesh, ict_landmarks)
    kwargs = dict(regions=lip_regions(markerset, labels), mm_per_unit=MM_PER_CM, mouth=mouth,
                  witness=lip_witness(markerset, labels))
    batched = selection.select_variant(geometry, d, **kwargs)
    with monkeypatch.context() as patch:
        patch.setattr(selection, "leave_one_out_many", one_variant_at_a_time)
        alone = selection.select_variant(geometry, d, **kwargs)
    assert batched.lips_checked and batched.chosen == alone.chosen and batched.rule == alone.rule
    assert len(batched.candidates) == 88
    for got, expected in zip(batched.candidates, alone.candidates):
        assert got.options() == expected.options() and got.note == expected.note
        assert got.score_mm == pytest.approx(expected.score_mm, rel=BATCHED_VS_ONE_AT_A_TIME,
                                             nan_ok=True)
        assert got.shift == pytest.approx(expected.shift, rel=BATCHED_VS_ONE_AT_A_TIME, abs=0)
        assert got.lips_open == pytest.approx(expected.lips_open, rel=BATCHED_VS_ONE_AT_A_TIME)
        assert got.lips_shut_frames == expected.lips_shut_frames
    # what is compared is not trivial: shifted variants, variants that keep the mouth shut
    assert sum(c.shift > 0.0 for c in batched.candidates) >= 5
    assert {c.lips_shut_frames == 0 for c in batched.candidates} == {True, False}
    # the lips of a stack read as each variant's own, from its held-out rows alone
    neutral, rest, frames, marker_opening, open_mm = selection._lip_frames(
        geometry, d, mouth, kwargs["witness"], MM_PER_CM, selection.OPEN_MM)
    for c in batched.candidates:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")               # its shift, if it has one
            rows = leave_one_out(geometry, kernel=c.kernel, epsilon=c.epsilon,
                                 distance=c.distance, vertices=mouth.vertex_ids,
                                 regions=kwargs["regions"] if c.use_regions else None).rows
        opening = MM_PER_CM * (mouth.gap(neutral + np.matmul(rows, frames)) - rest)
        assert c.lips_open == pytest.approx(float(np.median(opening / marker_opening)),
                                            rel=BATCHED_VS_ONE_AT_A_TIME)
        assert c.lips_shut_frames == int(contradicts(marker_opening, opening,
                                                     open_mm=open_mm).sum())


def test_a_variant_that_cannot_be_solved_is_noted_as_alone(monkeypatch, ict_basis, ict_layout):
    """Four markers: degree 1 fits them, but not without one (every marker is singular);
    three: the TPS cannot be solved at all. Batched or not, the same notes."""
    monkeypatch.setattr(selection, "SHAPES", {"thin_plate_spline": (None,),
                                              "gaussian": (0.5, 1.0)})
    for n in (3, 4):
        labels = ict_layout.labels[6:6 + n]
        geometry = MarkerGeometry.from_binding(layout_binding(ict_layout, labels),
                                               ict_basis.neutral, labels)
        d = np.random.default_rng(n).normal(scale=0.1, size=(5, n, 3))
        kwargs = dict(regions=None, mm_per_unit=10.0, distances=("euclidean",))
        batched = selection.select_variant(geometry, d, **kwargs)
        with monkeypatch.context() as patch:
            patch.setattr(selection, "leave_one_out_many", one_variant_at_a_time)
            alone = selection.select_variant(geometry, d, **kwargs)
        tps = batched.candidates[0]
        assert np.isnan(tps.score_mm) and tps.note == alone.candidates[0].note
        assert tps.note.startswith("3 centers, but a degree-1" if n == 3 else
                                   f"marker {labels[0]!r} cannot be held out")
        assert [c.score_mm for c in batched.candidates[1:]] == pytest.approx(
            [c.score_mm for c in alone.candidates[1:]], rel=BATCHED_VS_ONE_AT_A_TIME)
        assert batched.chosen == alone.chosen == 1 + int(np.argmin(
            [c.score_mm for c in alone.candidates[1:]]))


def test_auto_limited_to_what_the_options_leave_open(off_lips, ict_basis):
    result = retarget(off_lips["take"], off_lips["binding"], ict_basis.neutral,
                      off_lips["markerset"], neutral_frame=off_lips["neutral"], align=False,
                      options=RetargetOptions(distance="euclidean", use_regions=False))
    chosen = result.selection
    assert {(c.distance, c.use_regions) for c in chosen.candidates} == {("euclidean", False)}
    assert not chosen.lips_checked and "(lips not read)" in chosen.rule
    assert result.options.distance == "euclidean" and result.options.use_regions is False


def test_no_variant_that_can_be_scored_is_an_error(monkeypatch, ict_basis, ict_layout):
    monkeypatch.setattr(selection, "SHAPES", {"thin_plate_spline": (None,)})
    labels = ict_layout.labels[6:9]
    geometry = MarkerGeometry.from_binding(layout_binding(ict_layout, labels),
                                           ict_basis.neutral, labels)
    with pytest.raises(InputError, match=r"kernel='auto': no retargeting variant could be "
                                         r"cross-validated \(3 centers, but a degree-1"):
        selection.select_variant(geometry, np.zeros((4, 3, 3)), regions=None, mm_per_unit=10.0,
                                 distances=("euclidean",))


@pytest.mark.parametrize("kwargs, match", [
    (dict(epsilon=0.5), "epsilon is chosen by kernel='auto': name a kernel to set it"),
    (dict(degree=1), "degree is chosen by kernel='auto'"),
    (dict(use_regions="yes"), "use_regions must be true, false or unset"),
    (dict(distance="manhattan"), "distance must be one of"),
    (dict(kernel="spline"), "kernel must be one of"),
])
def test_option_errors(kwargs, match):
    with pytest.raises(InputError, match=match):
        RetargetOptions(**kwargs)


def test_auto_cannot_be_built_without_a_take(off_lips, ict_basis):
    with pytest.raises(InputError, match="kernel='auto' is chosen from a take's displacements"):
        build_retarget_operator(off_lips["binding"], ict_basis.neutral, off_lips["markerset"],
                                options=RetargetOptions())
    with pytest.raises(InputError, match="options must be a RetargetOptions"):
        retarget(off_lips["take"], off_lips["binding"], ict_basis.neutral,
                 off_lips["markerset"], options={"kernel": "auto"})


def test_displacements_are_those_of_the_variant_used(off_lips, ict_basis):
    """The selection does not change the data: W·D of auto is W of the chosen variant."""
    result = retarget(off_lips["take"], off_lips["binding"], ict_basis.neutral,
                      off_lips["markerset"], neutral_frame=off_lips["neutral"], align=False,
                      options=RetargetOptions(distance="euclidean", use_regions=False))
    face = off_lips["take"].select(off_lips["markerset"].face_markers)
    expected = marker_displacements(face, off_lips["binding"],
                                    neutral_frame=off_lips["neutral"])
    np.testing.assert_array_equal(result.displacements, expected)
    op = build_retarget_operator(off_lips["binding"], ict_basis.neutral, off_lips["markerset"],
                                 options=result.options)
    w = op.matrix.toarray() if sp.issparse(op.matrix) else op.matrix
    got = result.operator.matrix
    np.testing.assert_array_equal(got.toarray() if sp.issparse(got) else got, w)


def test_retarget_errors_of_the_lips_and_regions(off_lips, ict_basis, demo_face):
    args = (off_lips["take"], off_lips["binding"], ict_basis.neutral, off_lips["markerset"])
    other = find_mouth(demo_face.mesh, demo_face.landmarks)
    other = type(other)(other.upper_edge, other.lower_edge, other.upper + 10 ** 5,
                        other.lower, other.method)
    with pytest.raises(InputError, match="mouth must be the MouthOpening of this mesh"):
        retarget(*args, neutral_frame=off_lips["neutral"], mouth=other)
    with pytest.raises(InputError, match="split_regions: marker set 'ict-layout-off-lips' has "
                                         "no region 'nose_tip'"):
        retarget(*args, neutral_frame=off_lips["neutral"],
                 options=RetargetOptions(use_regions=True, split_regions=("nose_tip",)))


def test_selection_and_operator_errors(off_lips, ict_basis, ict_layout, demo_face):
    labels = off_lips["markerset"].face_markers
    geometry = MarkerGeometry.from_binding(off_lips["binding"], ict_basis.neutral, labels)
    other = MarkerGeometry.from_binding(off_lips["binding"], ict_basis.neutral, labels[:5])
    witness = lip_witness(off_lips["markerset"], labels)
    mouth = find_mouth(demo_face.mesh, demo_face.landmarks)
    with pytest.raises(InputError, match="witness must refer to the geometry's markers"):
        selection.select_variant(other, np.zeros((3, 5, 3)), regions=None, mm_per_unit=10.0,
                                 mouth=mouth, witness=witness)
    with pytest.raises(InputError, match="geometry must be of the same markers on the same mesh"):
        build_retarget_operator(off_lips["binding"], ict_basis.neutral, off_lips["markerset"],
                                options=RetargetOptions(kernel="gaussian", epsilon=0.5,
                                                        distance="geodesic"), geometry=other)
    assert geometry.n_markers == len(labels)
