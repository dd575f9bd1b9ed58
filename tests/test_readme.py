"""The README's Python script runs as written, on the demo session, and does what it says."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
from tolerances import FLOAT32_REL, MESH_EXACT

from basis.artist import load_artist_basis
from fit.demo import make_demo_session
from fit.exports import read_weights_csv
from fit.pipeline.config import INPUT_KEYS, OUTPUT_KEYS, RUN_KEYS, STAGE_TABLES
from fit.pipeline.template import option_rows

README = Path(__file__).resolve().parent.parent / "README.md"


def _python_section_script() -> str:
    text = README.read_text(encoding="utf-8")
    section = text[text.index("## Python API"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_readme_script_runs_and_its_outputs_agree(tmp_path, monkeypatch, capsys):
    make_demo_session(tmp_path / "session", seconds=3.0)
    monkeypatch.chdir(tmp_path)
    namespace = {}
    exec(compile(_python_section_script(), str(README), "exec"), namespace)
    result, weights = namespace["result"], namespace["weights"]
    take = namespace["take"]
    # the DataFrame is indexed by the capture's own frame numbers
    assert weights.index[0] == result.take.first_frame >= take.first_frame
    assert list(weights.columns) == ["time", *result.bases.bases["H"].names]
    # the lazily evaluated mesh is the basis evaluated at those weights
    H = result.bases.bases["H"]
    t = 100
    expected = namespace["recon"].mesh.vertices + np.tensordot(
        result.fitted.weights["H"][t], H.displacements, axes=1)
    np.testing.assert_allclose(namespace["mesh_at_100"], expected, atol=MESH_EXACT)
    # the glTF holds the basis as morph targets (read back by the glTF reader of the
    # artist bases); save wrote the per-take files
    morphs = load_artist_basis(namespace["recon"].mesh, tmp_path / "face-H.glb")
    assert morphs.names == H.names
    np.testing.assert_allclose(morphs.displacements, H.displacements,
                               atol=FLOAT32_REL * np.abs(H.displacements).max())
    saved = read_weights_csv(tmp_path / "out" / "capture" / "weights-H.csv")
    np.testing.assert_allclose(saved[list(H.names)].to_numpy(), weights[list(H.names)],
                               rtol=0, atol=0)
    assert "jaw_open" in capsys.readouterr().out


def test_the_readme_names_every_key_of_the_run_configuration():
    """'Your own capture' lists every key (init writes them all into run.toml)."""
    text = README.read_text(encoding="utf-8")
    section = text[text.index("## Your own capture"):text.index("## Python API")]
    keys = [f"inputs.{k}" for k in INPUT_KEYS] + [f"output.{k}" for k in OUTPUT_KEYS]
    keys += [f"run.{k}" for k in RUN_KEYS]
    keys += [f"{table}.{f.name}" for table, cls in STAGE_TABLES.items()
             for f in dataclasses.fields(cls)]
    missing = [k for k in keys if f"`{k}`" not in section]
    assert not missing, f"add these keys to the README's run-configuration table: {missing}"
    # and each stage option's row says what the code says (default and comment)
    stale = [row for row in option_rows() if row not in section.splitlines()]
    assert not stale, ("the README's run-configuration table differs from the options' "
                       "docstrings (fit.pipeline.template.option_rows): " + "; ".join(stale))

