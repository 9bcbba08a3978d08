"""Lines of sight on a 2-D grid: the kernel of the planners' view gain (:func:`edge_explorer.plan.predictive.
visible_unknown`).

A view's gain tests the line of sight from a viewpoint to every unknown cell within sensor range: on a whole floor
the learned planner measures a few dozen views a decision, each hundreds to thousands of lines. Sampled as one
(lines × samples × 2) numpy array that cost ~1 ms a view and was the largest item of a slow decision (session 46).
This numba kernel samples the same points with the same floating-point operations, so it answers exactly what the
array did, and stops a line at its first blocked sample.

Only numpy and numba are imported here: the daemon loads this kernel before it releases LLVM's pages
(:func:`edge_explorer.runtime.kernels.warm_kernels`).
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def _clear(origin_x, origin_y, delta, t, blocking, x0, y0, resolution):  # pragma: no cover - compiled
    rows, cols = blocking.shape
    out = np.ones(delta.shape[0], dtype=np.bool_)
    for k in range(delta.shape[0]):
        dx, dy = delta[k, 0], delta[k, 1]
        for s in range(t.shape[0]):
            col = int(math.floor((origin_x + t[s] * dx - x0) / resolution))
            row = int(math.floor((origin_y + t[s] * dy - y0) / resolution))
            row = min(max(row, 0), rows - 1)
            col = min(max(col, 0), cols - 1)
            if blocking[row, col]:
                out[k] = False
                break
    return out


def clear_lines(
    origin_xy_m: np.ndarray,
    delta_xy_m: np.ndarray,
    t: np.ndarray,
    blocking: np.ndarray,
    grid_origin_xy_m: tuple[float, float],
    resolution_m: float,
) -> np.ndarray:
    """bool (K,): whether the line from ``origin_xy_m`` to ``origin_xy_m + delta_xy_m[k]``, sampled at the fractions
    ``t`` (S,), crosses no ``blocking`` cell (bool, rows × cols of the grid with origin ``grid_origin_xy_m`` and cells
    ``resolution_m``). A sample off the grid reads the nearest edge cell."""
    return _clear(
        float(origin_xy_m[0]),
        float(origin_xy_m[1]),
        np.ascontiguousarray(delta_xy_m, dtype=np.float64).reshape(-1, 2),
        np.ascontiguousarray(t, dtype=np.float64),
        np.ascontiguousarray(blocking, dtype=np.bool_),
        float(grid_origin_xy_m[0]),
        float(grid_origin_xy_m[1]),
        float(resolution_m),
    )
