"""The package layout: imports point one way, nothing private is reached across packages,
and the old import paths of moved modules still work (with a warning) until they go."""

from __future__ import annotations

import ast
import contextlib
import importlib
import io
import sys
import warnings
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent

#: Top-level packages, lowest first: each may import only those before it.
PACKAGES = ("mocap", "basis", "fit")
#: Sub-packages and modules of a package by layer, lowest first: a unit may import
#: units of its own layer or below. Units not listed (the package root, ``_moved``,
#: ``basis``'s modules) are not layered.
LAYERS = {
    "mocap": (("errors",), ("util",), ("units", "anatomy", "take"), ("gaps", "rigid", "markerset"),
              ("io", "stabilize", "stable_markers", "head_frame", "mesh", "neutral"),
              ("clean", "bind"), ("retarget", "viz", "synth"), ("infer",)),
    "fit": (("solve", "metrics"), ("exports", "report", "gestures"), ("pipeline",), ("demo",),
            ("cli",)),
}


def _modules():
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            parts = path.relative_to(REPO).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            yield name, path, path.name == "__init__.py"


def _is_module(dotted: str) -> bool:
    path = REPO.joinpath(*dotted.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def _imports(path: Path):
    """(line, imported module, imported name or None) of every absolute import of the project."""
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name, None
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, f"{path}:{node.lineno}: relative import"
            for alias in node.names:
                yield node.lineno, node.module, alias.name


def _layer(module: str):
    parts = module.split(".")
    for rank, units in enumerate(LAYERS.get(parts[0], ())):
        if len(parts) > 1 and parts[1] in units:
            return rank
    return None


def test_imports_point_down_and_reach_nothing_private_of_another_package():
    problems = []
    for module, path, is_package in _modules():
        package = module if is_package else module.rpartition(".")[0]
        for line, target, name in _imports(path):
            top = target.split(".")[0]
            if top not in PACKAGES:
                continue
            where = f"{path.relative_to(REPO)}:{line}"
            if name is not None and name.startswith("_"):
                if not _is_module(f"{target}.{name}"):
                    problems.append(f"{where}: private name {name} of {target}")
                    continue
                target = f"{target}.{name}"
            if PACKAGES.index(top) > PACKAGES.index(module.split(".")[0]):
                problems.append(f"{where}: {module} imports {target}, a package above it")
            own, theirs = _layer(module), _layer(target)
            if top == module.split(".")[0] and None not in (own, theirs) and theirs > own:
                problems.append(f"{where}: {module} imports {target}, a layer above it")
            parts = target.split(".")
            private = next((i for i, p in enumerate(parts) if p.startswith("_")), None)
            if private is not None:
                home = ".".join(parts[:private])
                if not (package == home or package.startswith(home + ".")):
                    problems.append(f"{where}: {module} reaches the private {target}")
    assert not problems, "\n".join(problems)


def test_the_walk_finds_what_it_looks_for(tmp_path):
    """The checks above fire on a made-up upward and private import (they could be false)."""
    assert _layer("fit.cli.main") > _layer("fit.solve.weights")
    assert _layer("mocap.retarget.rbf") > _layer("mocap.mesh.mesh")
    bad = tmp_path / "bad.py"
    bad.write_text("from fit.cli import main\nfrom mocap.clean.swaps import _helper\n")
    found = list(_imports(bad))
    assert found == [(1, "fit.cli", "main"), (2, "mocap.clean.swaps", "_helper")]
    assert not _is_module("mocap.clean.swaps._helper") and _is_module("mocap.viz._raster")


#: Old import path -> a name it must still give, and where that name lives now.
MOVED = [
    ("mocap.c3d", "read_c3d", "mocap.io.c3d"),
    ("mocap.vicon_csv", "read_vicon_csv", "mocap.io.vicon_csv"),
    ("mocap.trc", "write_trc", "mocap.io.trc"),
    ("mocap.take_npz", "read_take_npz", "mocap.io.take_npz"),
    ("mocap.mesh_landmarks", "load_mesh_landmarks", "mocap.mesh.landmarks"),
    ("mocap.layout", "MarkerLayout", "mocap.mesh.layout"),
    ("mocap.regions", "region_weights", "mocap.mesh.regions"),
    ("mocap.geodesic", "HeatGeodesics", "mocap.mesh.geodesic"),
    ("mocap.rbf", "build_rbf_operator", "mocap.retarget.rbf"),
    ("mocap.render", "render_mesh", "mocap.viz.render"),
    ("mocap.performance", "read_performance", "mocap.synth.performance"),
    ("mocap.bind", "hold_window", "mocap.neutral"),
    ("fit.ingest", "IngestOptions", "mocap.clean.ingest"),
    ("fit.retarget", "retarget", "mocap.retarget.retargeting"),
    ("fit.retarget", "save_npz", "mocap.retarget.archive"),
    ("fit.retarget", "neutral_pose", "mocap.neutral"),
    ("fit.temporal", "moving_average", "fit.solve.temporal"),
    ("fit.gcv", "gcv_score", "fit.solve.gcv"),
    ("fit.sampling_estimator", "estimate_weights_by_sampling", "fit.solve.sampling_estimator"),
    ("fit.marker_centres", "solve_at_marker_centres", "fit.solve.marker_centres"),
    ("fit.run_config", "load_run_config", "fit.pipeline.config"),
    ("fit.run_config", "ReportOptions", "fit.pipeline.options"),
    ("fit.manifest", "sha256_path", "fit.pipeline.manifest"),
    ("fit.ingest_plots", "plot_gaps", "fit.report.ingest_plots"),
    ("fit.commands.run", "run_takes", "fit.pipeline.session"),
    ("fit.commands.basis", "pca_of_captures", "basis.take_pca"),
    ("fit.commands.demo", "run_demo", "fit.demo.run"),
    ("fit.pipeline", "BindResult", "mocap.bind"),
    ("fit.pipeline", "marker_basis", "fit.solve.marker_basis"),
    ("fit.report.plots", "plot_coverage", "basis.coverage"),
]


@pytest.mark.parametrize("old, name, new", MOVED, ids=[f"{o}.{n}" for o, n, _ in MOVED])
def test_an_old_path_still_gives_the_same_object_with_a_future_warning(old, name, new,
                                                                      monkeypatch):
    renamed = {"BindResult": "BoundTake"}
    if not hasattr(sys.modules.get(old), "__file__"):          # an alias warns when imported
        monkeypatch.delitem(sys.modules, old, raising=False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = getattr(importlib.import_module(old), name)
    assert got is getattr(importlib.import_module(new), renamed.get(name, name))
    assert any(w.category is FutureWarning and "removed in mocap2mesh 0.3" in str(w.message)
               for w in caught)


def test_old_bind_capture_keeps_its_signature_and_result(tmp_path):
    """``fit.commands.bind.bind_capture`` (the README's old entry) = bind_take's binding and frame."""
    from fit.demo import make_demo_session
    from mocap.bind import bind_take
    from mocap.markerset import load_markerset
    from mocap.mesh import load_mesh
    from mocap.mesh.landmarks import load_mesh_landmarks

    session = make_demo_session(tmp_path, seconds=2.0)
    take = session.capture.take
    markerset = load_markerset(session.paths["markerset"])
    mesh = load_mesh(session.paths["neutral"], units="mm")
    landmarks = load_mesh_landmarks(session.paths["landmarks"], mesh)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        from fit.commands.bind import bind_capture
    assert any("bind_capture moved to mocap.bind.bind_take" in str(w.message) for w in caught)
    binding, frame = bind_capture(take, markerset, mesh, landmarks, stabilized=True)
    bound = bind_take(take, markerset, mesh, landmarks, head_frame=True)
    assert frame == bound.frame and binding.labels == bound.binding.labels
    assert binding.rms == bound.binding.rms


def test_an_unknown_name_of_an_old_path_is_an_attribute_error(monkeypatch):
    monkeypatch.delitem(sys.modules, "fit.gcv", raising=False)
    with pytest.warns(FutureWarning):
        old = importlib.import_module("fit.gcv")
    with pytest.raises(AttributeError, match="has no attribute 'nope'"):
        old.nope


# ------------------------------------------------------------ what a command imports

def _fresh_modules(code: str) -> set:
    """The modules a fresh interpreter holds after running `code`."""
    import subprocess

    done = subprocess.run([sys.executable, "-c", code + "\nimport sys\nprint(*sys.modules)"],
                          capture_output=True, text=True, timeout=120, cwd=REPO)
    assert done.returncode == 0, done.stderr
    return set(done.stdout.split())


def test_the_run_command_loads_without_the_speech_analysis_and_the_other_commands():
    """``mocap2mesh run`` needs one function of fit.gestures: the package's other modules
    (scipy.signal with them) and the other commands' modules stay unimported, also through
    the command line's parser; the whole package still gives every name it lists."""
    loaded = _fresh_modules("from fit.cli.main import build_parser\n"
                            "build_parser(['run', 'x.toml'])\n"
                            "import fit.pipeline.session")
    assert "fit.gestures.transfer" in loaded
    assert not {"scipy.signal", "fit.gestures.phones", "fit.gestures.mrf"} & loaded
    assert not {m for m in loaded if m.startswith("fit.cli.commands.")} - {"fit.cli.commands.run"}
    everything = _fresh_modules("from fit.cli.main import full_parser\nfull_parser()")
    assert {f"fit.cli.commands.{name}" for name in ("demo", "gestures", "run")} <= everything


_USAGES = (["--help"], ["-h"], [], ["bogus"], ["-h", "run"], ["--", "run", "x.toml"], ["-x"],
           ["--version"])


def _parsed(parser, argv) -> tuple:
    """What `parser` prints and exits with on `argv` (the exit code None when it parses)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            parser.parse_args(argv)
            code = None
        except SystemExit as exc:
            code = exc.code
    return out.getvalue(), err.getvalue(), code


@pytest.mark.parametrize("argv", _USAGES, ids=" ".join)
def test_the_listing_of_the_commands_is_the_full_parsers(argv):
    """Without a command name first, the parser lists every command from its module's HELP
    line without importing it: the help, the listing and the usage errors are those of the
    parser with every command registered."""
    from fit.cli.main import build_parser, full_parser

    assert _parsed(build_parser(argv), argv) == _parsed(full_parser(), argv)


def test_the_help_of_the_command_line_imports_no_command():
    loaded = _fresh_modules("from fit.cli.main import main\nmain(['--help'])")
    assert not {m for m in loaded if m.startswith("fit.cli.commands.")}
    assert not {"scipy", "pandas", "matplotlib"} & loaded


def test_a_command_the_listing_parser_picks_is_parsed_again_with_its_own(monkeypatch, tmp_path,
                                                                         capsys):
    """Should argparse ever pick a listed command (its name not the first word), the
    command line parses the words again with that command registered, and runs it."""
    cli = importlib.import_module("fit.cli.main")   # (fit.cli.main is also the function)
    listing = cli.build_parser([])
    picked = listing.parse_args(["info", "--json", "-h"])
    assert (picked.command, picked.words) == ("info", ["--json", "-h"])
    monkeypatch.setattr(cli, "build_parser", lambda argv: listing)
    assert cli.main(["info", str(tmp_path / "missing.c3d")]) == cli.EXIT_BAD_INPUT
    assert "mocap2mesh info: error:" in capsys.readouterr().err


def test_a_lazy_package_gives_its_modules_objects_and_keeps_its_moved_names():
    import fit.gestures
    from fit.gestures import phones, speech

    assert fit.gestures.read_wav is speech.read_wav
    assert fit.gestures.PhoneSegments is phones.PhoneSegments
    assert set(fit.gestures.__all__) <= set(dir(fit.gestures))
    with pytest.raises(AttributeError, match="has no attribute 'nope'"):
        fit.gestures.nope
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fit.gestures.marker_basis
    assert [Path(w.filename).name for w in caught] == [Path(__file__).name]
    assert "moved to fit.solve.marker_basis" in str(caught[0].message)
