"""The command line: exit codes, info, ingest, demo, and never losing an input."""

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import FACIAL_SING_MARKERSET_TOML
from tolerances import INGEST_STABILIZED_MM, REPAIRED_STEP_MM

import mocap
from fit.cli.main import main
from fit.demo import make_demo_session


@pytest.fixture(scope="module")
def session_files(tmp_path_factory):
    """The demo capture as .npz and .c3d, with its marker set."""
    root = tmp_path_factory.mktemp("session")
    session = make_demo_session(root, seconds=6.0)
    mocap.write(session.capture.take, root / "take.npz")
    mocap.write(session.capture.take, root / "take.c3d")
    return root, session


def test_help_and_usage_errors(capsys):
    assert main(["--help"]) == 0
    assert main([]) == 2
    assert main(["ingest", "x.c3d"]) == 2                 # -o is required
    assert main(["ingest", "x.c3d", "-o", "y.npz", "--fill", "magic"]) == 2


def test_missing_and_unsupported_files_exit_1(tmp_path, capsys):
    assert main(["info", str(tmp_path / "nope.c3d")]) == 1
    assert "nope.c3d: cannot read C3D file: no such file" in capsys.readouterr().err
    (tmp_path / "a.xyz").write_text("1 2 3")
    assert main(["info", str(tmp_path / "a.xyz")]) == 1
    assert "unsupported extension '.xyz'" in capsys.readouterr().err


def test_info_json_counts_missing_samples(session_files, capsys):
    root, session = session_files
    assert main(["info", str(root / "take.npz"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    take = session.capture.take
    assert info["labels"] == list(take.labels)
    assert info["frames"] == take.n_frames and info["rate"] == take.rate
    assert info["units"] == "mm"
    assert info["missing"] == {k: int(v) for k, v in zip(take.labels, take.missing.sum(0))}


def test_info_table(session_files, capsys):
    root, _ = session_files
    assert main(["info", str(root / "take.c3d")]) == 0
    out = capsys.readouterr().out
    assert "720 from frame 1, 120 Hz" in out and session_files[1].head_markers[0] in out


def test_ingest_refuses_to_overwrite_its_input(session_files, capsys):
    root, _ = session_files
    before = (root / "take.npz").read_bytes()
    assert main(["ingest", str(root / "take.npz"), "-o", str(root / "take.npz")]) == 1
    assert "refusing to overwrite an input" in capsys.readouterr().err
    assert (root / "take.npz").read_bytes() == before


def test_ingest_stabilize_needs_markerset(session_files, tmp_path, capsys):
    root, _ = session_files
    assert main(["ingest", str(root / "take.npz"), "-o", str(tmp_path / "o.npz"),
                 "--stabilize"]) == 1
    assert "needs a marker set" in capsys.readouterr().err
    assert not (tmp_path / "o.npz").exists()


def test_ingest_stabilized_matches_truth(session_files, tmp_path):
    """The stabilized output is the generator's head-frame truth, up to one rigid motion."""
    root, session = session_files
    out = tmp_path / "clean.npz"
    code = main(["ingest", str(root / "take.c3d"), "-o", str(out), "--markerset",
                 str(root / "markerset.toml"), "--stabilize", "--qa", str(tmp_path / "qa")])
    assert code == 0
    assert (tmp_path / "qa" / "gaps.png").stat().st_size > 10_000
    assert (tmp_path / "qa" / "head_residuals.png").stat().st_size > 10_000
    take = mocap.read(out)
    head = np.load(tmp_path / "clean.head.npz")
    assert head["rotation"].shape == (take.n_frames, 3, 3)
    truth = session.capture.truth.markers_head
    ok = ~np.isnan(take.positions[..., 0])
    assert take.filled.any() and ok.mean() > 0.97
    # our reference head frame differs from the generator's by one fixed rigid motion
    a, b = truth[ok], take.positions[ok]
    a0, b0 = a - a.mean(0), b - b.mean(0)
    u, _, vt = np.linalg.svd(b0.T @ a0)
    r = u @ np.diag([1, 1, np.linalg.det(u @ vt)]) @ vt
    err = np.linalg.norm(b0 - a0 @ r.T, axis=1)
    assert np.median(err) < INGEST_STABILIZED_MM      # mm, with 0.2 mm noise and fills


def test_demo_runs_the_whole_chain(tmp_path, capsys):
    assert main(["demo", "-o", str(tmp_path / "demo"), "--seconds", "3"]) == 0
    report = capsys.readouterr().out.split("report:")[1].split()[0]
    assert report.endswith(".html") and (tmp_path / "demo") in Path(report).parents
    assert Path(report).stat().st_size > 100_000          # pictures embedded
    assert list((tmp_path / "demo").rglob("manifest.json"))


def test_ingest_fix_swaps_undoes_an_injected_label_swap(session_files, tmp_path):
    root, session = session_files
    take = session.capture.take
    rest = np.nanmedian(take.positions, axis=0)
    seen = ~take.missing[190:270].any(axis=0)          # a pair visible around the swap
    face = [i for i, label in enumerate(take.labels)
            if label not in session.head_markers and seen[i]]
    a = face[0]
    b = min((i for i in face if i != a), key=lambda i: np.linalg.norm(rest[i] - rest[a]))
    swapped = take.positions.copy()
    swapped[200:260, [a, b]] = swapped[200:260, [b, a]]
    mocap.write(take.replace(positions=swapped), tmp_path / "swapped.npz")
    out = tmp_path / "fixed.npz"
    assert main(["ingest", str(tmp_path / "swapped.npz"), "-o", str(out), "--fix-swaps",
                 "--fill", "none"]) == 0
    np.testing.assert_array_equal(mocap.read(out).positions, take.positions)


def test_ingest_reject_implausible_refills_the_facial_sing_mislabel(facial_sing_path, tmp_path):
    """The section3-1 label leaves its marker for ~70 mm in frames 819-863; with
    --reject-implausible the written take moves smoothly there, and no captured
    sample elsewhere changes (gap fills may: they learn from the repaired markers)."""
    src = facial_sing_path
    markerset = FACIAL_SING_MARKERSET_TOML
    plain, clean = tmp_path / "plain.npz", tmp_path / "clean.npz"
    common = ["--markerset", str(markerset), "--fill", "auto"]
    assert main(["ingest", str(src), "-o", str(plain), *common]) == 0
    assert main(["ingest", str(src), "-o", str(clean), "--reject-implausible", *common]) == 0
    before, after = mocap.read(plain), mocap.read(clean)
    i = after.index("section3-1")
    def largest_step(take):
        return np.nanmax(np.linalg.norm(np.diff(take.positions[815:870, i], axis=0), axis=1))
    assert largest_step(before) > 60 and largest_step(after) < REPAIRED_STEP_MM
    captured = ~mocap.read(src).missing
    captured[819:864] = False
    np.testing.assert_array_equal(after.positions[captured], before.positions[captured])
