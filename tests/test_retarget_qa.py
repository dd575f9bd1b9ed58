"""The retargeting QA of a whole take: lip-seal warnings, report sections, manifest, run."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from helpers import ReportPage

from fit.cli.main import main
from fit.demo import DEMO_MAX_GAP, demo_config_toml, make_demo_session
from fit.pipeline import Reconstruction
from fit.pipeline.manifest import write_manifest
from mocap.errors import InputError
from mocap.markerset import load_markerset


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """The demo session's take reconstructed with the TPS operator and with "auto"."""
    root = tmp_path_factory.mktemp("qa")
    session = make_demo_session(root / "session", seconds=6.0)
    paths = session.paths
    out = {}
    for kernel in ("thin_plate_spline", "auto"):
        recon = Reconstruction(markerset=paths["markerset"], mesh=paths["neutral"],
                               mesh_units="mm", landmarks=paths["landmarks"],
                               basis=paths["shapes"], ingest={"max_gap": DEMO_MAX_GAP},
                               bind={"skin_offset": 2.0}, retarget={"kernel": kernel})
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = recon.process(paths["capture"])
        out[kernel] = (result, [str(w.message) for w in caught])
    return root, paths, out


def _lip_markers_opening(result, paths):
    """The lip landmarks' distance from rest, straight from the take (mm)."""
    markerset = load_markerset(paths["markerset"])
    face = result.face
    upper = face.labels.index(markerset.landmarks["upper_lip_top"])
    lower = face.labels.index(markerset.landmarks["lower_lip_bottom"])
    rest = result.bound.neutral_pose(face.positions)
    return (np.linalg.norm(face.positions[:, upper] - face.positions[:, lower], axis=1)
            - np.linalg.norm(rest[upper] - rest[lower]))


def test_tps_keeps_the_demo_mouth_shut_and_the_warning_names_the_frames(demo):
    _, paths, out = demo
    result, messages = out["thin_plate_spline"]
    check = result.lip_seal
    mouth = result.retargeted.mouth
    # oracles: the mesh sequences and the take, evaluated their own ways
    vertices = result.retargeted.vertex_displacements(dtype=np.float64) \
        + result.reconstruction.mesh.vertices
    mm = 1.0 / result.binding.scale
    np.testing.assert_allclose(check.mesh_gap["W·D"],
                               mm * mouth.gap(vertices[:, mouth.vertex_ids]), rtol=1e-9)
    frames = [0, result.take.n_frames // 2]
    h = np.stack([result.meshes("H").vertices(f) for f in frames])
    np.testing.assert_allclose(check.mesh_gap["H"][frames],
                               mm * mouth.gap(h[:, mouth.vertex_ids]), rtol=1e-9)
    np.testing.assert_allclose(check.marker_opening, _lip_markers_opening(result, paths),
                               atol=1e-9)
    shut = [m for m in messages if "the W·D mesh keeps the mouth shut" in m]
    assert len(shut) == 1 and shut[0].startswith(str(paths["capture"]))
    runs = check.runs("W·D")
    named = ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in runs[:6])
    assert f"in {int(check.shut('W·D').sum())} frames: {named}" in shut[0]
    first, last = runs[0]                          # capture frame numbers
    index = np.arange(first, last + 1) - result.take.first_frame
    opening = _lip_markers_opening(result, paths)[index]
    assert (opening >= check.marker_open_mm).all()
    assert (check.mesh_opening("W·D")[index] < 0.25 * opening).all()
    assert check.mesh_opening("H").max() > 2 * check.mesh_opening("W·D").max()  # H opens


def test_auto_opens_the_demo_mouth(demo):
    _, _, out = demo
    result, messages = out["auto"]
    assert not any(f"the {name} mesh" in m for m in messages for name in ("W·D", "QE", "PCA"))
    check = result.lip_seal
    widest = check.marker_opening.max()
    for name in ("W·D", "QE", "PCA"):
        assert not check.shut(name).any()
        assert check.mesh_opening(name).max() > 0.75 * widest
    assert result.retargeted.selection.best.distance == "geodesic"


def test_report_sections_carry_the_numbers(demo):
    root, _, out = demo
    for kernel, (result, _) in out.items():
        files = result.report(root / f"report-{kernel}")
        page = ReportPage.read([f for f in files if str(f).endswith(".html")][0])
        assert {"Retargeting: leave-one-marker-out cross-validation",
                "Lip seal and contact"} <= set(page.headings)
        cv = result.retargeted.cross_validation
        rows = page.tables["cv-markers"][1:]
        assert [r[0] for r in rows] == list(cv.labels)
        np.testing.assert_array_equal([float(r[2]) for r in rows], cv.marker_rms)
        np.testing.assert_array_equal([float(r[3]) for r in rows], cv.motion_rms)
        regions = {r[0]: float(r[2]) for r in page.tables["cv-regions"][1:]}
        assert regions == {r["region"]: r["rms_mm"]
                           for r in cv.by_region(result.reconstruction.markerset.regions)}
        lips = {r[0]: (float(r[1]), int(r[2])) for r in page.tables["lip-seal"][1:]}
        check = result.lip_seal
        assert lips == {n: (float(check.mesh_opening(n).max()), int(check.shut(n).sum()))
                        for n in check.mesh_gap}
        assert page.warnings == check.messages()
        selection = result.retargeted.selection
        if kernel == "auto":
            chosen = [r for r in page.tables["cv-selection"][1:] if r[5] == "yes"]
            assert [r[1] for r in chosen] == [selection.best.name]
            assert float(chosen[0][2]) == selection.best.score_mm
        else:
            assert selection is None and "cv-selection" not in page.tables
        assert len(page.images) == sum(f.suffix == ".png" for f in files)


def test_the_manifest_record_has_the_variant_scores_and_lips(demo, tmp_path):
    _, _, out = demo
    result, _ = out["auto"]
    summary = result.summary()
    retarget = summary["retarget"]
    selection = result.retargeted.selection
    assert retarget["kernel"] == selection.best.kernel
    assert retarget["selection"]["chosen"]["name"] == selection.best.name
    assert len(retarget["selection"]["tried"]) == len(selection.candidates)
    assert retarget["cross_validation"]["rms_mm"] == pytest.approx(selection.best.score_mm)
    assert summary["lip_seal"]["meshes"]["W·D"]["shut_frames"] == 0
    doc = write_manifest(tmp_path / "m.json", config="x", versions={}, parameters={},
                         inputs={}, takes={"t": summary})
    assert json.loads((tmp_path / "m.json").read_text())["takes"]["t"]["retarget"] \
        == json.loads(json.dumps(doc["takes"]["t"]["retarget"]))


def test_run_prints_the_warnings_of_a_take_on_stderr(demo, capsys):
    """The configuration of the fixture's TPS reconstruction, through `mocap2mesh run`."""
    root, _, _ = demo
    head = demo_config_toml().split("[ingest]")[0]                 # inputs and output
    config = root / "run.toml"
    config.write_text(head + f'[ingest]\nmax_gap = {DEMO_MAX_GAP}\n\n[bind]\nskin_offset = 2.0\n\n'
                      '[retarget]\nkernel = '
                      '"thin_plate_spline"\n\n[report]\nvideo = false\n', encoding="utf-8")
    assert main(["run", str(config)]) == 0
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if "lip seal" in x]
    assert lines and all(x.startswith("mocap2mesh: warning: take capture: ") for x in lines)
    manifest = json.loads((root / "results" / "manifest.json").read_text())
    record = manifest["takes"]["capture"]
    assert record["retarget"]["selection"] is None
    assert record["lip_seal"]["meshes"]["W·D"]["shut_frames"] > 0
    assert any("lip seal" in w for w in record["warnings"])


def test_mesh_landmarks_without_the_mouth_skip_the_lips_with_a_warning(demo):
    _, paths, out = demo
    full = out["thin_plate_spline"][0].reconstruction
    landmarks = {k: v for k, v in full.landmarks.items() if not k.startswith("mouth_corner")}
    recon = Reconstruction(markerset=full.markerset, mesh=full.mesh, landmarks=landmarks,
                           basis=full.basis, ingest={"max_gap": DEMO_MAX_GAP},
                           bind={"skin_offset": 2.0}, retarget={"kernel": "thin_plate_spline"})
    with pytest.warns(UserWarning, match="the lips are not checked: the mouth needs the mesh "
                                         "landmarks mouth_corner_left and mouth_corner_right"):
        result = recon.process(paths["capture"])
    assert result.lip_seal is None and result.summary()["lip_seal"] is None


def test_lip_gap_errors(demo):
    from fit.report.retarget_qa import mesh_lip_gaps

    _, _, out = demo
    result = out["auto"][0]
    mouth, mesh = result.retargeted.mouth, result.reconstruction.mesh
    with pytest.raises(InputError, match=r"displacements must have shape \(T, 60, 3\)"):
        mesh_lip_gaps(mouth, mesh.vertices, mm_per_unit=1.0,
                      operator=result.retargeted.operator.matrix, displacements=np.zeros((3, 5)))
    with pytest.raises(InputError, match=r"basis 'H': shapes \(n, 6291, 3\) and weights "
                                         r"\(T, n\) expected"):
        mesh_lip_gaps(mouth, mesh.vertices, mm_per_unit=1.0,
                      bases={"H": (np.zeros((2, 10, 3)), np.zeros((4, 2)))})
