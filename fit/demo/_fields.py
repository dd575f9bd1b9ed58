"""Smooth, compactly supported building blocks of the demo's displacement fields.

Every profile is exactly 0 outside its support (so a shape moves nothing
beyond its muscle) and twice continuously differentiable (quintic
"smootherstep" ramps).
"""

from __future__ import annotations

import numpy as np

from fit.demo.face import MOUTH, mouth_line
from mocap.mesh.mesh import vertex_normals


def ramp(t) -> np.ndarray:
    """0 for t <= 0, 1 for t >= 1, the quintic smootherstep between."""
    t = np.clip(t, 0.0, 1.0)
    return t * t * t * (t * (6 * t - 15) + 10)


def window(t, a, b, c, d) -> np.ndarray:
    """0 outside (a, d), 1 on [b, c], smooth ramps between (a < b <= c < d)."""
    return ramp((t - a) / (b - a)) * (1.0 - ramp((t - c) / (d - c)))


def radial(x, y, center, radii, flat=0.2) -> np.ndarray:
    """1 within `flat` of an ellipse's normalized radius, 0 beyond its rim.

    Parameters
    ----------
    x, y : ndarray, mm
    center : (float, float), mm
    radii : (float, float), mm
        Semi-axes of the support.
    flat : float in [0, 1)
        Normalized radius of the plateau.
    """
    r = np.hypot((x - center[0]) / radii[0], (y - center[1]) / radii[1])
    return 1.0 - ramp((r - flat) / (1.0 - flat))


def slit_side(x, y, line, half_width, cx=0.0, *, sharpness=0.5, start=0.9,
              growth=0.5) -> np.ndarray:
    """Weight of being on the upper side of a slit: exactly 1 above, 0 below.

    Within `start` times the slit's half-width of its centre the step spans
    ``±sharpness`` mm about ``line(x)``, so the two lips move independently;
    farther out it widens by `growth` mm per mm, so the skin round a corner
    blends both sides.
    """
    beyond = np.clip(np.abs(x - cx) - start * half_width, 0.0, None)
    return ramp(0.5 + 0.5 * (y - line(x)) / (sharpness + growth * beyond))


def above_mouth(x, y, **options) -> np.ndarray:
    """:func:`slit_side` of the mouth: 1 on the upper lip, 0 on the lower lip."""
    return slit_side(x, y, mouth_line, MOUTH["half_width"], MOUTH["center"][0], **options)
class Sculptor:
    """Displacement fields on one neutral: tangential slides plus normal bulges.

    Parameters
    ----------
    vertices : ndarray of shape (N, 3), mm
    faces : ndarray of shape (F, 3), int
    """

    def __init__(self, vertices, faces):
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.x, self.y = self.vertices[:, 0], self.vertices[:, 1]
        self.normals = vertex_normals(self.vertices, faces)

    def slide(self, weight, direction) -> np.ndarray:
        """``weight * direction`` projected on the tangent plane, (N, 3) mm.

        `direction` is (3,) or (N, 3), mm at weight 1.
        """
        d = weight[:, None] * np.broadcast_to(np.asarray(direction, float),
                                              self.vertices.shape)
        return d - np.sum(d * self.normals, axis=1, keepdims=True) * self.normals

    def bulge(self, weight, mm) -> np.ndarray:
        """``mm * weight`` along the vertex normals, (N, 3) mm."""
        return (mm * weight)[:, None] * self.normals

    def rotation_parts(self, weight, pivot, axis) -> tuple[np.ndarray, np.ndarray]:
        """The two fields of a blended rotation, each (N, 3) mm per radian.

        A rotation by angle a about unit `axis` through `pivot`, blended by
        `weight`, moves a vertex by ``weight * (sin(a) K r + (1 - cos(a)) K K r)``
        with ``r = v - pivot`` and ``K r = axis x r`` (Rodrigues); returns
        ``(weight * K r, weight * K K r)``.
        """
        axis = np.asarray(axis, float) / np.linalg.norm(axis)
        k_r = np.cross(axis, self.vertices - np.asarray(pivot, float))
        return weight[:, None] * k_r, weight[:, None] * np.cross(axis, k_r)
