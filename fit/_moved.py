"""Where the modules and names of ``fit`` that moved in 0.2 went (old paths work until 0.3)."""

from mocap.util.deprecation import alias_modules


def _bind_capture():
    """``fit.commands.bind.bind_capture``: :func:`mocap.bind.bind_take` under its old signature."""
    from mocap.bind import bind_take

    def bind_capture(take, markerset, mesh, mesh_landmarks, *, frame="auto", icp=True,
                     skin_offset=0.0, stabilized=False, max_distance_warn=3.0):
        bound = bind_take(take, markerset, mesh, mesh_landmarks, frame=frame,
                          head_frame=stabilized, icp=icp, skin_offset=skin_offset,
                          max_distance_warn=max_distance_warn)
        return bound.binding, bound.frame
    return bind_capture


_COMMANDS = ("basis", "bind", "demo", "gestures", "info", "ingest", "maskle", "retarget", "run",
             "synth")
_COMMAND_NAMES = {
    "bind": {"bind_capture": ("mocap.bind:bind_take", _bind_capture),
             "parse_frame": "fit.cli.arguments:parse_frame"},
    "basis": {"pca_of_retargeted": "basis.take_pca:pca_of_retargeted",
              "pca_of_captures": "basis.take_pca:pca_of_captures",
              "write_outputs": "basis.outputs:write_basis_outputs",
              "COVERAGE_MARKS": "basis.outputs:COVERAGE_MARKS"},
    "run": {"run_takes": "fit.pipeline.session:run_takes",
            "process_take": "fit.pipeline.session:process_take",
            "RunOutcome": "fit.pipeline.session:RunOutcome",
            "load_artist": "basis.basis_io:load_any_basis"},
    "demo": {"run_demo": "fit.demo:run_demo", "demo_config_toml": "fit.demo:demo_config_toml"},
}

alias_modules({
    "fit.ingest": "mocap.clean.ingest",
    "fit.retarget": ("mocap.retarget", "mocap.neutral"),
    "fit.temporal": "fit.solve.temporal",
    "fit.gcv": "fit.solve.gcv",
    "fit.sampling_estimator": "fit.solve.sampling_estimator",
    "fit.marker_centres": "fit.solve.marker_centres",
    "fit.run_config": ("fit.pipeline.config", "fit.pipeline.options"),
    "fit.manifest": "fit.pipeline.manifest",
    "fit.ingest_plots": "fit.report.ingest_plots",
    "fit.commands": "fit.cli.commands",
    **{f"fit.commands.{name}": (f"fit.cli.commands.{name}", _COMMAND_NAMES.get(name, {}))
       for name in _COMMANDS},
})

#: Names of :mod:`fit.pipeline` that moved elsewhere.
PIPELINE_NAMES = {"BindResult": "mocap.bind:BoundTake",
                  "marker_basis": "fit.solve.marker_basis:marker_basis",
                  "solve_mesh_space": "fit.solve.mesh_space:solve_mesh_space"}
#: Names of :mod:`fit.report.plots` that moved elsewhere.
PLOTS_NAMES = {"plot_coverage": "basis.coverage:plot_coverage",
               "distinct_colours": "mocap.viz.figures:distinct_colours"}
