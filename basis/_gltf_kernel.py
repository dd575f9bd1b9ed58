"""The glTF writer's float32 values in one compiled pass each (numba, the ``speed`` extra).

:func:`basis.gltf.write_gltf` in NumPy forms its morph targets' weights by a gather, a
division, a clamp and a conversion, one whole-block pass each, and its targets'
displacements by one scaling per target; these do a whole part of the file in one call,
value by value, without the GIL (so that the writer's threads share the work): half the
time for the weights (most of it the divisions).
"""

from __future__ import annotations

import numba

__all__ = ["target_weights", "scaled_targets"]


@numba.njit(cache=True, nogil=True)
def target_weights(weights, shape, factor, out):  # pragma: no cover - compiled
    """``max(weights[t, shape[k]] / factor[k], 0)`` into ``out[t, k]`` (T, K), in `out`'s
    type (rounded once from the float64 quotient); NaN stays NaN, and -0.0 becomes 0.0
    as with NumPy's ``maximum``.

    Parameters
    ----------
    weights : ndarray of float64, shape (T, n)
    shape : ndarray of int, shape (K,)
    factor : ndarray of float64, shape (K,)
    out : ndarray of float32 or float64, shape (T, K)
    """
    for t in range(out.shape[0]):
        for k in range(out.shape[1]):
            quotient = weights[t, shape[k]] / factor[k]
            out[t, k] = quotient if quotient > 0.0 or quotient != quotient else 0.0


@numba.njit(cache=True, nogil=True)
def scaled_targets(values, shape, factor, first, out):  # pragma: no cover - compiled
    """Values ``first`` to ``first + len(out)`` of the targets laid one after another,
    target k being ``values[shape[k]] * factor[k]``, into `out` in its type (rounded once
    from the float64 product).

    Parameters
    ----------
    values : ndarray of float64, shape (n, m)
        Each shape's values (a displacement field, flattened).
    shape : ndarray of int, shape (K,)
    factor : ndarray of float64, shape (K,)
    first : int
    out : ndarray of float32, shape (count,)
    """
    per_target = values.shape[1]
    done = 0
    while done < out.shape[0]:
        k, start = divmod(first + done, per_target)
        count = min(per_target - start, out.shape[0] - done)
        source, scale = values[shape[k]], factor[k]
        for i in range(count):
            out[done + i] = source[start + i] * scale
        done += count
