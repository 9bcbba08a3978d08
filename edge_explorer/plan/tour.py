"""The shortest open tour through a handful of stops, exactly: the global layer's tour over target clusters
(:func:`edge_explorer.plan.route.tour_first`).

The global layer tours at most :data:`MAX_TOUR_STOPS` stops, so the Held–Karp dynamic programme (O(2^n n²), well under
a millisecond of arithmetic for ten stops) finds the optimum without a solver: the daemon flies it, and OR-Tools, which
the FUEL-style planner and the bench oracle use for tours of tens to hundreds of stops, is an optional dependency that
would add its import and memory to the vehicle's process for a problem this small.
"""

from __future__ import annotations

import numpy as np

MAX_TOUR_STOPS = 10  # stops beyond the start: 2^10 subsets


def open_tour(cost_m: np.ndarray) -> list[int]:
    """The order of all nodes that starts at node 0, ends anywhere and minimises the summed ``cost_m[i, j]``
    (an (n, n) array, n − 1 ≤ :data:`MAX_TOUR_STOPS`; ``inf`` where there is no way: such legs are taken last)."""
    n = len(cost_m)
    if n - 1 > MAX_TOUR_STOPS:
        raise ValueError(f"open_tour takes at most {MAX_TOUR_STOPS} stops besides the start, got {n - 1}")
    if n <= 2:
        return list(range(n))
    cost = np.where(np.isfinite(cost_m), cost_m, 1e3 * float(np.nanmax(np.where(np.isfinite(cost_m), cost_m, 0)) + 1))
    stops = n - 1
    legs = cost[1:, 1:]
    best = np.full((1 << stops, stops), np.inf)  # best[S, j]: shortest path from 0 through the stops in S, ending at j
    came = np.full((1 << stops, stops), -1, dtype=np.int64)
    for j in range(stops):
        best[1 << j, j] = cost[0, j + 1]
    for subset in range(1, 1 << stops):
        for j in range(stops):
            before = subset & ~(1 << j)
            if before == subset or before == 0:
                continue
            through = best[before] + legs[:, j]
            i = int(np.argmin(through))
            best[subset, j], came[subset, j] = through[i], i
    subset, j = (1 << stops) - 1, int(np.argmin(best[-1]))
    order = []
    while j >= 0:
        order.append(j + 1)
        subset, j = subset & ~(1 << j), int(came[subset, j])
    return [0, *order[::-1]]
