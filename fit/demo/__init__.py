"""The project's own demo session, generated from nothing.

A procedural face mesh with eye and mouth openings (:mod:`fit.demo.face`),
an 18-shape muscle basis (:mod:`fit.demo.muscles`), a performance that the
basis does not span exactly (:mod:`fit.demo.performance`), a marker layout
and marker set (:mod:`fit.demo.markers`) and a simulated capture, all
written by :func:`make_demo_session` (:mod:`fit.demo.session`);
:func:`run_demo` (:mod:`fit.demo.run`) runs the whole chain on it.
"""

from fit.demo.run import DEMO_MAX_GAP, demo_config_toml, run_demo
from fit.demo.session import SESSION_FILES, DemoSession, make_demo_session

__all__ = ["DemoSession", "make_demo_session", "SESSION_FILES", "run_demo", "demo_config_toml",
           "DEMO_MAX_GAP"]
