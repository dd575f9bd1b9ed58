"""Where the modules and names of ``mocap`` that moved in 0.2 went (old paths work until 0.3)."""

from mocap.util.deprecation import alias_modules

alias_modules({
    "mocap.c3d": "mocap.io.c3d",
    "mocap.vicon_csv": "mocap.io.vicon_csv",
    "mocap.trc": "mocap.io.trc",
    "mocap.take_npz": "mocap.io.take_npz",
    "mocap.mesh_landmarks": "mocap.mesh.landmarks",
    "mocap.layout": "mocap.mesh.layout",
    "mocap.regions": "mocap.mesh.regions",
    "mocap.geodesic": "mocap.mesh.geodesic",
    "mocap.rbf": "mocap.retarget.rbf",
    "mocap.render": "mocap.viz.render",
    "mocap.performance": "mocap.synth.performance",
})

#: Names of :mod:`mocap.bind` that moved to :mod:`mocap.neutral`.
BIND_NAMES = {name: f"mocap.neutral:{name}" for name in (
    "pick_neutral_frame", "resolve_neutral_frame", "hold_window", "NEUTRAL_METHODS",
    "PICKED_FRAMES", "HOLD_S")}
