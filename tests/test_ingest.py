"""Ingestion of real takes (mocap.clean.ingest): what it fills, what it must leave alone.

facial-sing.c3d holds ``Unlabeled1`` (seen in 35 of 3000 frames, outside its
marker set) and face-marker gaps of up to 192 frames: it must come out with
Unlabeled1 untouched, long gaps open unless asked for, and warnings saying so.
Oracles: the raw file itself (carried samples), the same take with the extra
marker removed beforehand (filling must not read it), runs of NaN counted here.
"""

import re
import warnings

import numpy as np
import pytest
from helpers import FACIAL_SING_MARKERSET_TOML
from tolerances import EXACT_MM

import mocap
from fit.cli.main import main
from fit.pipeline.config import load_run_config
from mocap.clean.ingest import IngestOptions, ingest
from mocap.errors import InputError, MarkerError
from mocap.markerset import load_markerset


def _longest_run(missing):
    """Longest run of True in a 1-D mask, as (length, first index)."""
    best, start = (0, -1), None
    for i, gone in enumerate(list(missing) + [False]):
        if gone and start is None:
            start = i
        elif not gone and start is not None:
            best, start = max(best, (i - start, start)), None
    return best


def test_a_marker_outside_the_set_is_carried_unfilled(facial_sing_take, facial_sing_markerset):
    take, markerset = facial_sing_take, facial_sing_markerset
    j = take.index("Unlabeled1")
    with pytest.warns(UserWarning) as caught:
        result = ingest(take, markerset=markerset)
    np.testing.assert_array_equal(result.cleaned.positions[:, j], take.positions[:, j])
    assert (result.cleaned.filled[:, j] == 0).all()
    assert result.extra_markers == ("Unlabeled1",)
    seen = int((~np.isnan(take.positions[:, j, 0])).sum())
    assert seen == 35
    messages = [str(w.message) for w in caught]
    assert any("carried unfilled" in m and f"Unlabeled1 (visible in {seen} of 3000 frames)" in m
               for m in messages)
    # nothing of it reached the fills of the set's markers (to rounding: another column order)
    alone = ingest(take.select(markerset.markers), markerset=markerset)
    np.testing.assert_allclose(result.cleaned.select(markerset.markers).positions,
                               alone.cleaned.positions, rtol=0, atol=EXACT_MM)
    np.testing.assert_array_equal(result.cleaned.select(markerset.markers).missing,
                                  alone.cleaned.missing)


def test_a_marker_outside_the_set_can_be_dropped(facial_sing_take, facial_sing_markerset):
    with pytest.warns(UserWarning, match=r"1 marker\(s\) outside marker set 'facial-sing' "
                                         r"dropped \(ingest extra_markers = 'drop'\)"):
        result = ingest(facial_sing_take, markerset=facial_sing_markerset,
                        options=IngestOptions(extra_markers="drop"))
    assert result.cleaned.labels == tuple(label for label in facial_sing_take.labels
                                          if label != "Unlabeled1")


def test_long_gaps_stay_open_unless_asked_for(facial_sing_take, facial_sing_markerset):
    take = facial_sing_take
    runs = {label: _longest_run(np.isnan(take.positions[:, take.index(label), 0]))
            for label in facial_sing_markerset.face_markers}
    label, (length, start) = max(runs.items(), key=lambda kv: kv[1])
    assert length == 192                                    # the data README's longest gap
    first = take.first_frame + start
    with pytest.warns(UserWarning) as caught:
        result = ingest(take, markerset=facial_sing_markerset)
    col = result.cleaned.index(label)
    assert np.isnan(result.cleaned.positions[start:start + length, col]).all()
    expected = (f"longer than max_gap = 10 frames (0.10 s) left unfilled, the longest "
                f"{label}, frames {first}-{first + length - 1} (1.92 s); set max_gap to at "
                f"least {length} frames")
    assert any(expected in str(w.message) for w in caught)
    with pytest.warns(UserWarning, match=r"filled \d+ samples"):
        asked = ingest(take, markerset=facial_sing_markerset,
                       options=IngestOptions(max_gap=length))
    assert not np.isnan(asked.cleaned.positions[start:start + length, col]).any()


@pytest.mark.parametrize("fill", ["spline", "rigid", "pca", "auto"])
def test_three_head_markers_fill_with_every_method(facial_sing_take, tmp_path, fill):
    """A marker set with exactly 3 head markers: its head cluster no longer breaks filling."""
    text = FACIAL_SING_MARKERSET_TOML.read_text(encoding="utf-8")
    text = re.sub(r'(?m)^head = \[.*\]$', 'head = ["root-1", "root-2", "root-3"]', text)
    text = text.replace('other = []', 'other = ["root-4", "root-5", "root-6"]')
    path = tmp_path / "three-head.toml"
    path.write_text(text, encoding="utf-8")
    markerset = load_markerset(path)
    assert len(markerset.clusters["head"]) == 3
    with pytest.warns(UserWarning):
        result = ingest(facial_sing_take, markerset=markerset,
                        options=IngestOptions(fill=fill, max_gap=200))
    head = result.fill.gaps[result.fill.gaps["marker"].isin(markerset.head)]
    if fill == "rigid":
        assert head["reason"].str.startswith("its cluster 'head' has 3 markers").all()
    else:
        assert (head["method"] != "rigid").all()


@pytest.mark.parametrize("options, match", [
    ({"min_visible": 2}, r"min_visible must be in \[0, 1\], got 2.0"),
    ({"extra_markers": "keep"}, r"extra_markers must be one of \['carry', 'drop'\], got 'keep'"),
    ({"max_gap": 0}, r"max_gap must be at least 1, got 0"),
])
def test_ingest_option_errors(options, match):
    with pytest.raises(InputError, match=match):
        IngestOptions(**options)


def test_run_config_names_the_ingest_key(tmp_path):
    for name in ("capture.c3d", "markerset.toml", "neutral.obj", "landmarks.toml"):
        (tmp_path / name).write_text("")
    (tmp_path / "shapes").mkdir()
    path = tmp_path / "run.toml"
    path.write_text('[inputs]\ncaptures = ["capture.c3d"]\nmarkerset = "markerset.toml"\n'
                    'mesh = "neutral.obj"\nlandmarks = "landmarks.toml"\nbasis = "shapes"\n'
                    '[ingest]\nextra_markers = "fill"\n', encoding="utf-8")
    with pytest.raises(InputError, match=r"run\.toml: ingest\.extra_markers: extra_markers "
                                         r"must be one of"):
        load_run_config(path)


@pytest.mark.parametrize("extra, match", [
    (["--max-gap", "0"], r"max_gap must be at least 1, got 0"),
    (["--min-visible", "1.5"], r"min_visible must be in \[0, 1\], got 1.5"),
])
def test_ingest_cli_error_is_one_line(facial_sing_path, tmp_path, capsys, extra, match):
    code = main(["ingest", str(facial_sing_path), "-o", str(tmp_path / "out.c3d"), *extra])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1
    assert re.fullmatch(r"mocap2mesh ingest: error: " + match, err[0])


def test_ingest_cli_drops_or_carries_the_markers_outside_the_set(facial_sing_path, tmp_path):
    args = ["ingest", str(facial_sing_path), "--markerset", str(FACIAL_SING_MARKERSET_TOML)]
    with pytest.warns(UserWarning, match="dropped"):
        assert main(args + ["-o", str(tmp_path / "d.c3d"), "--extra-markers", "drop"]) == 0
    with pytest.warns(UserWarning, match="carried unfilled"):
        assert main(args + ["-o", str(tmp_path / "c.c3d")]) == 0
    assert "Unlabeled1" not in mocap.read(tmp_path / "d.c3d").labels
    carried = mocap.read(tmp_path / "c.c3d")
    assert (~carried.missing[:, carried.index("Unlabeled1")]).sum() == 35


@pytest.mark.parametrize("options, remedy", [
    ({"max_gap": 5}, r"after gap filling \(longer than max_gap=5\); 1 face marker\(s\) have gaps left, .*: set "
                     r"\[ingest\] max_gap = 40 or more to fill it"),
    ({"max_gap": 50, "min_visible": 0.95},
     r"after gap filling \(visible in 360 of 400 frames \(90\.0 %\), under min_visible = 0\.95\); .*: lower "
     r"\[ingest\] min_visible to fill it anyway"),
    ({"fill": "none"}, r"after gap filling; .*: fill it \(\[ingest\] fill, max_gap, "
                       r"min_visible\)"),
])
def test_the_chain_names_a_face_marker_left_with_gaps(options, remedy):
    """require_complete: the marker, its frames (numbers) and the option that would fill it."""
    from fit.pipeline.gaps import require_complete
    from mocap import Take
    from mocap.markerset import MarkerSet

    t = np.arange(400) / 100.0
    pos = np.stack([np.stack([np.sin(t + k), np.cos(t + k), t], axis=1) * 10 + 50 * k
                    for k in range(6)], axis=1)
    pos[100:140, 2] = np.nan
    take = Take(tuple(f"m{k}" for k in range(6)), pos, rate=100.0, first_frame=7)
    markerset = MarkerSet("toy", head=("m0", "m1", "m5"), regions={"other": ("m2", "m3", "m4")})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = ingest(take, markerset=markerset, options=IngestOptions(**options)) \
            if options.get("fill") != "none" else None
    cleaned = take if result is None else result.cleaned
    with pytest.raises(MarkerError, match=r"marker 'm2': the take: missing in frames 107-146 "
                                          r"\(0\.40 s\) " + remedy), \
            warnings.catch_warnings():
        warnings.simplefilter("ignore")
        require_complete(cleaned, markerset.face_markers, None if result is None else result.fill)
