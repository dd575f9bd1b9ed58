"""The reconstruction errors' pass over the samples as one compiled loop (numba, the
``speed`` extra).

:func:`fit.metrics.reconstruction_errors` in NumPy forms, a block of frames at a time, the
differences of every sample to the reconstruction, to α's origin and to the rest pose,
squares them, sums each sample's three, masks the samples not counted and sums the rest
over frames and markers: about twenty passes over the block. This takes each sample once:
the same errors bit for bit (each sample's ``(dx·dx + dy·dy) + dz·dz``), and the same sums
but for the order they are added in (frame by frame and marker by marker here, NumPy's
pairwise sums there: they agree to rounding).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["squared_errors"]


@numba.njit(cache=True, nogil=True)
def squared_errors(captured, reconstructed, origin, neutral, errors, sums,
                   marker_sums):  # pragma: no cover - compiled; tested against NumPy
    """Errors (T, M) into `errors`, per-frame sums (3, T) into `sums` and per-marker sums
    (2, M) into `marker_sums` of captured and reconstructed positions (T, M, 3), α's
    `origin` (3,) and the rest pose `neutral` (M, 3), as :func:`fit.metrics._squared_errors`
    returns them.

    A sample counts when its squared error is a number (no coordinate of either position
    is NaN); its error is NaN otherwise and it adds to no sum.
    """
    marker_sums[:] = 0.0
    for t in range(captured.shape[0]):
        error_sum, position_sum, displacement_sum = 0.0, 0.0, 0.0
        for m in range(captured.shape[1]):
            cx, cy, cz = captured[t, m, 0], captured[t, m, 1], captured[t, m, 2]
            dx, dy, dz = (cx - reconstructed[t, m, 0], cy - reconstructed[t, m, 1],
                          cz - reconstructed[t, m, 2])
            squared = dx * dx + dy * dy + dz * dz
            errors[t, m] = np.sqrt(squared)
            if squared == squared:
                px, py, pz = cx - origin[0], cy - origin[1], cz - origin[2]
                qx, qy, qz = cx - neutral[m, 0], cy - neutral[m, 1], cz - neutral[m, 2]
                error_sum += squared
                position_sum += px * px + py * py + pz * pz
                displacement_sum += qx * qx + qy * qy + qz * qz
                marker_sums[0, m] += errors[t, m]
                marker_sums[1, m] += squared
        sums[0, t], sums[1, t], sums[2, t] = error_sum, position_sum, displacement_sum
