"""The oracle: the path a perfect-knowledge explorer needs to reach the coverage goal — the benchmark's yardstick
(issue #55, item 6).

An explorer that knows the floor plan still has to fly to places from which its sensor sees the building. The
oracle plans that flight with the plan in hand:

1. **Candidate viewpoints**: the planning cells (0.10 m, :func:`~edge_explorer.world.flight_space.planning_cells`)
   of the reachable flight space on a lattice of :data:`~edge_explorer.world.flight_space.VIEW_SPACING_M` (0.5 m),
   the lattice N_M itself is defined on (:func:`viewpoint_candidates`).
2. **What each one sees** (:func:`visible_cells`): the simulator's own planar sensor
   (:func:`~edge_explorer.vehicle.sensor.scan`, exact cell traversal on the true 0.05 m occupancy, 4.5 m range, no
   noise) turned a full circle: the vehicle can turn in place, and turning costs no path (the flown vehicle has an
   87° field of view; the bench's path length counts only translation). A seen 0.05 m cell makes its 0.20 m cell
   known — the rule of the observed low-res map — so the sets are of N_M cells (``raster.coarsened(0.20).interior``,
   what the simulator's coverage divides by).
3. **Greedy set cover** (:func:`greedy_cover`): the start's own view is free; then the viewpoint that adds the most
   unseen N_M cells, until ``goal`` of N_M is covered (lazy greedy; ties go by candidate index: deterministic).
   Viewpoints made redundant by later choices are then dropped, last chosen first, while coverage stays ≥ goal.
4. **Flyable distances** (:func:`path_lengths`): Dijkstra on the reachable planning cells with 16-connectivity
   (the 8 neighbours plus knight moves whose two crossed cells are reachable too), so a grid path is at most ~3 %
   longer than the straight flight (8-connectivity: up to 8 %).
5. **Open tour** (:func:`open_tour`): from the start through every chosen viewpoint, ending anywhere — an open
   TSP with a dummy end node every node reaches for free. No LKH binding is installed, so OR-Tools' routing solver
   runs instead: cheapest-arc start, then guided local search stopped after a fixed number of solutions (not a time
   limit, so the result does not depend on the machine's speed); a wall-clock cap only guards against runaway
   searches and is reported when it ends the search (then the tour may differ between runs).

The tour's length is the oracle's path (``path_m``). The bench measures a method by the path at which coverage
*first* reaches the goal, and a vehicle sees on its way; so the oracle also flies its tour cell by cell with the
real 87° sensor facing the direction of travel (full turns only at the start and the viewpoints) and reports where
coverage first reaches the goal (``path_at_goal_m`` ≤ ``path_m``, :func:`flown_path_at_goal`) — the figure the
ratios use. Neither is a strict bound: the cover ignores en-route views when it chooses viewpoints and is greedy;
the full turns are free; the vehicle flies smoothed paths, not grid steps; the simulator's sensor noise marks a
few extra cells. The ``+pred`` methods count predicted cells as covered, so their ratio can fall below 1.
"""

from __future__ import annotations

import heapq
import math
import time
from dataclasses import dataclass

import numpy as np
from ortools.constraint_solver import pywrapcp, routing_enums_pb2
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from edge_explorer.vehicle.sensor import SensorConfig, scan
from edge_explorer.world.flight_space import FLIGHT_CLEARANCE, VIEW_RANGE_M, VIEW_SPACING_M, reachable_cells
from edge_explorer.world.grid import LOW_RES_M, UNKNOWN, GridSpec, resolution_factor
from edge_explorer.world.raster import PlanRaster

FULL_TURN_RAD = 2.0 * math.pi - 1e-6  # the sensor model wants fov < 2π; one scan this wide is a full turn
_UNREACHABLE_CM = 10**9
# the 16-neighbourhood, each undirected edge once: (d_row, d_col) and the cells a knight move crosses
_MOVES: tuple[tuple[int, int, tuple[tuple[int, int], ...]], ...] = (
    (0, 1, ()),
    (1, 0, ()),
    (1, 1, ()),
    (1, -1, ()),
    (1, 2, ((0, 1), (1, 1))),
    (1, -2, ((0, -1), (1, -1))),
    (2, 1, ((1, 0), (1, 1))),
    (2, -1, ((1, 0), (1, -1))),
)


@dataclass(frozen=True)
class OracleConfig:
    """How the oracle samples viewpoints and how long its tour search runs."""

    spacing_m: float = VIEW_SPACING_M  # candidate lattice
    range_m: float = VIEW_RANGE_M  # the sensor's range
    prune: bool = True  # drop viewpoints made redundant by later choices
    solution_limit: int = 2000  # guided local search stops after this many solutions (deterministic)
    time_limit_s: float = 60.0  # safety cap of the tour search (reported when it ends the search)

    def __post_init__(self) -> None:
        if self.spacing_m <= 0 or self.range_m <= 0 or self.solution_limit < 1 or self.time_limit_s <= 0:
            raise ValueError("spacing_m, range_m, solution_limit and time_limit_s must be positive")


@dataclass(frozen=True)
class OracleResult:
    """The oracle's flight on one building: where it looks from, in which order, and how far it flies."""

    plan: str
    goal: float
    start_xy_m: tuple[float, float]
    viewpoints_xy_m: np.ndarray  # (k, 2) float: the chosen viewpoints (x, y) in metres, in the order chosen
    tour: tuple[int, ...]  # indices into viewpoints_xy_m, in the order flown
    path_m: float  # start → tour[0] → … → tour[-1] along flyable grid paths
    leg_m: tuple[float, ...]  # the tour's legs, in the order flown
    path_at_goal_m: float | None  # along the tour, where coverage with en-route 87° scans first reaches the goal
    coverage: float  # N_M share the start and the chosen viewpoints see
    n_m: int  # N_M cells (0.20 m)
    candidates: int  # candidate viewpoints on the lattice
    tour_capped: bool  # the wall-clock cap, not the solution limit, ended the tour search
    timings_s: dict[str, float]  # visibility, cover, paths, tour, total

    @property
    def solve_s(self) -> float:
        return self.timings_s["total"]

    def as_dict(self) -> dict[str, object]:
        """JSON-ready figures (the viewpoints in flown order)."""
        return {
            "plan": self.plan,
            "goal": self.goal,
            "path_m": round(self.path_m, 3),
            "path_at_goal_m": None if self.path_at_goal_m is None else round(self.path_at_goal_m, 3),
            "viewpoints": len(self.tour),
            "coverage": round(self.coverage, 5),
            "n_m": self.n_m,
            "candidates": self.candidates,
            "tour_capped": self.tour_capped,
            "start_xy_m": [round(v, 3) for v in self.start_xy_m],
            "tour_xy_m": np.round(self.viewpoints_xy_m[list(self.tour)], 3).tolist(),
            "leg_m": [round(v, 3) for v in self.leg_m],
            "timings_s": {k: round(v, 3) for k, v in self.timings_s.items()},
        }


# ---- viewpoints and what they see --------------------------------------------------------------------------------
def planning_grid(raster: PlanRaster) -> tuple[GridSpec, np.ndarray]:
    """The reachable planning cells (0.10 m) of ``raster``: where the vehicle's centre may be planned."""
    factor = FLIGHT_CLEARANCE.planning_factor
    reachable = reachable_cells(raster)
    grid = raster.grid.coarsened(factor)
    mask = np.zeros(grid.shape, dtype=bool)
    rows, cols = np.nonzero(reachable)
    mask[rows // factor, cols // factor] = True
    return grid, mask


def viewpoint_candidates(mask: np.ndarray, grid: GridSpec, spacing_m: float) -> np.ndarray:
    """(n, 2) row/col of the planning cells on a lattice of ``spacing_m`` (every cell if the lattice misses all)."""
    step = max(int(round(spacing_m / grid.resolution_m)), 1)
    lattice = np.zeros_like(mask)
    lattice[::step, ::step] = True
    cells = np.argwhere(mask & lattice)
    return cells if len(cells) else np.argwhere(mask)


def visible_cells(
    raster: PlanRaster, xy_m: np.ndarray, n_m_mask: np.ndarray, range_m: float = VIEW_RANGE_M
) -> list[np.ndarray]:
    """For each point of ``xy_m`` (n, 2), the flat indices (sorted) of the 0.20 m N_M cells a full turn of the
    noiseless sensor there shows: a 0.20 m cell counts when any of its 0.05 m cells is seen (free or the occupied
    cell a ray stops at)."""
    config = SensorConfig(fov_rad=FULL_TURN_RAD, range_m=range_m, occupied_noise_prob=0.0)
    factor = resolution_factor(raster.grid.resolution_m, LOW_RES_M)
    occupied = np.ascontiguousarray(raster.occupied)
    n_cols_low = n_m_mask.shape[1]
    flat_nm = n_m_mask.ravel()
    out = []
    for x, y in xy_m:
        patch = scan(occupied, raster.grid, float(x), float(y), 0.0, config)
        rows, cols = np.nonzero(patch.codes != UNKNOWN)
        low = np.unique(((rows + patch.row0) // factor) * n_cols_low + (cols + patch.col0) // factor)
        out.append(low[flat_nm[low]])
    return out


def greedy_cover(sets: list[np.ndarray], target: int, given: np.ndarray, n_cells: int) -> list[int]:
    """Indices of ``sets`` chosen greedily (most new cells first, ties by index) until the union with
    ``given`` holds ``target`` cells or nothing adds any; lazy evaluation keeps it near-linear."""
    covered = np.zeros(n_cells, dtype=bool)
    covered[given] = True
    count = int(covered.sum())
    heap = [(-len(s), i) for i, s in enumerate(sets) if len(s)]
    heapq.heapify(heap)
    chosen: list[int] = []
    while count < target and heap:
        _, i = heapq.heappop(heap)
        gain = int((~covered[sets[i]]).sum())
        if gain == 0:
            continue
        if heap and (-gain, i) > heap[0]:
            heapq.heappush(heap, (-gain, i))  # stale bound: re-queue with the true gain
            continue
        chosen.append(i)
        covered[sets[i]] = True
        count += gain
    return chosen


def prune_cover(sets: list[np.ndarray], chosen: list[int], target: int, given: np.ndarray, n_cells: int) -> list[int]:
    """``chosen`` without the viewpoints (tried last chosen first) whose removal keeps ≥ ``target`` cells."""
    times = np.zeros(n_cells, dtype=np.int32)  # how many of the kept views (and the start) see each cell
    times[given] += 1
    for i in chosen:
        times[sets[i]] += 1
    kept = list(chosen)
    count = int((times > 0).sum())
    for i in reversed(chosen):
        lost = int((times[sets[i]] == 1).sum())
        if count - lost >= target:
            times[sets[i]] -= 1
            count -= lost
            kept.remove(i)
    return kept


# ---- flyable distances and the tour ------------------------------------------------------------------------------
def path_lengths(
    mask: np.ndarray, resolution_m: float, cells: np.ndarray, chunk: int = 16
) -> tuple[np.ndarray, np.ndarray]:
    """(k, k) shortest flyable path lengths (m) between the planning cells ``cells`` (k, 2), through the cells of
    ``mask`` with 16-connectivity (module docstring), ``inf`` where no path exists; and the (k, n) Dijkstra
    predecessors over the flat indices of ``mask``'s cells (−9999: none), to trace the paths."""
    index = np.full(mask.shape, -1, dtype=np.int64)
    index[mask] = np.arange(int(mask.sum()))
    n_rows, n_cols = mask.shape
    heads, tails, lengths = [], [], []
    for dr, dc, crossed in _MOVES:
        rows = np.arange(max(0, -dr), n_rows - max(0, dr))
        cols = np.arange(max(0, -dc), n_cols - max(0, dc))
        a = mask[np.ix_(rows, cols)] & mask[np.ix_(rows + dr, cols + dc)]
        for cr, cc in crossed:
            a &= mask[np.ix_(rows + cr, cols + cc)]
        r, c = np.nonzero(a)
        heads.append(index[rows[r], cols[c]])
        tails.append(index[rows[r] + dr, cols[c] + dc])
        lengths.append(np.full(len(r), math.hypot(dr, dc) * resolution_m))
    n = int(mask.sum())
    graph = csr_matrix((np.concatenate(lengths), (np.concatenate(heads), np.concatenate(tails))), shape=(n, n))
    nodes = index[cells[:, 0], cells[:, 1]]
    if (nodes < 0).any():
        raise ValueError("a tour point is not a planning cell of the mask")
    out = np.empty((len(nodes), len(nodes)))
    pred = np.empty((len(nodes), n), dtype=np.int32)
    for k in range(0, len(nodes), chunk):
        dist, pred[k : k + chunk] = dijkstra(
            graph, directed=False, indices=nodes[k : k + chunk], return_predecessors=True
        )
        out[k : k + chunk] = dist[:, nodes]
    return out, pred


def open_tour(dist_m: np.ndarray, solution_limit: int, time_limit_s: float) -> tuple[list[int], bool]:
    """(order of all nodes from node 0, ending anywhere, minimising the summed ``dist_m``; whether the wall-clock
    cap ended the search). OR-Tools routing with a dummy end node that every node reaches for free; cheapest-arc
    start, guided local search for ``solution_limit`` solutions (module docstring)."""
    n = len(dist_m)
    if n <= 2:
        return list(range(n)), False
    matrix = np.zeros((n + 1, n + 1), dtype=np.int64)
    matrix[:n, :n] = np.where(np.isfinite(dist_m), np.rint(dist_m * 100.0), _UNREACHABLE_CM)  # cm: ints wanted
    manager = pywrapcp.RoutingIndexManager(n + 1, 1, [0], [n])
    routing = pywrapcp.RoutingModel(manager)
    routing.SetArcCostEvaluatorOfAllVehicles(routing.RegisterTransitMatrix(matrix.tolist()))
    params = pywrapcp.DefaultRoutingSearchParameters()
    params.first_solution_strategy = routing_enums_pb2.FirstSolutionStrategy.PATH_CHEAPEST_ARC
    params.local_search_metaheuristic = routing_enums_pb2.LocalSearchMetaheuristic.GUIDED_LOCAL_SEARCH
    params.solution_limit = solution_limit
    params.time_limit.FromMilliseconds(int(time_limit_s * 1000))
    start = time.perf_counter()
    solution = routing.SolveWithParameters(params)
    capped = time.perf_counter() - start >= 0.98 * time_limit_s
    order, index = [], routing.Start(0)
    while not routing.IsEnd(index):
        order.append(manager.IndexToNode(index))
        index = solution.Value(routing.NextVar(index))
    return order, capped


# ---- the oracle --------------------------------------------------------------------------------------------------
def oracle_path(
    raster: PlanRaster,
    start_pose: tuple[float, float, float],
    goal: float = 0.95,
    config: OracleConfig = OracleConfig(),
) -> OracleResult:
    """The perfect-knowledge flight on ``raster`` (a plan as the loaders give it: interior cut to the flight space)
    from ``start_pose`` (x, y, yaw; e.g. :func:`~edge_explorer.sim.starts.start_pose`) to ``goal`` of N_M; see
    the module docstring. The start is snapped to the nearest reachable planning cell."""
    if not 0 < goal <= 1:
        raise ValueError(f"goal must be in (0, 1], got {goal}")
    t0 = time.perf_counter()
    n_m_mask = raster.coarsened(LOW_RES_M).interior
    n_m = int(n_m_mask.sum())
    target = math.ceil(goal * n_m - 1e-9)
    grid, mask = planning_grid(raster)
    start_rc = _snap(mask, grid, start_pose[0], start_pose[1])
    cells = viewpoint_candidates(mask, grid, config.spacing_m)
    cells = cells[~((cells[:, 0] == start_rc[0]) & (cells[:, 1] == start_rc[1]))]
    x, y = grid.center_of(np.r_[start_rc[0], cells[:, 0]], np.r_[start_rc[1], cells[:, 1]])
    xy = np.stack([x, y], axis=1)
    sets = visible_cells(raster, xy, n_m_mask, config.range_m)
    t1 = time.perf_counter()
    given, candidate_sets = sets[0], sets[1:]
    chosen = greedy_cover(candidate_sets, target, given, n_m_mask.size)
    if config.prune:
        chosen = prune_cover(candidate_sets, chosen, target, given, n_m_mask.size)
    covered = np.zeros(n_m_mask.size, dtype=bool)
    covered[given] = True
    for i in chosen:
        covered[candidate_sets[i]] = True
    t2 = time.perf_counter()
    tour_cells = np.vstack([np.asarray(start_rc)[None], cells[chosen]])
    dist, pred = path_lengths(mask, grid.resolution_m, tour_cells)
    t3 = time.perf_counter()
    order, capped = open_tour(dist, config.solution_limit, config.time_limit_s)
    t4 = time.perf_counter()
    legs = tuple(float(dist[a, b]) for a, b in zip(order[:-1], order[1:], strict=True))
    at_goal = flown_path_at_goal(raster, mask, grid, tour_cells, order, pred, n_m_mask, target, config.range_m)
    t5 = time.perf_counter()
    return OracleResult(
        plan=raster.name,
        goal=goal,
        start_xy_m=(float(xy[0, 0]), float(xy[0, 1])),
        viewpoints_xy_m=xy[1:][chosen],
        tour=tuple(k - 1 for k in order[1:]),
        path_m=float(sum(legs)),
        path_at_goal_m=at_goal,
        leg_m=legs,
        coverage=float(covered.sum() / max(n_m, 1)),
        n_m=n_m,
        candidates=len(cells),
        tour_capped=capped,
        timings_s={
            "visibility": t1 - t0,
            "cover": t2 - t1,
            "paths": t3 - t2,
            "tour": t4 - t3,
            "flight": t5 - t4,
            "total": t5 - t0,
        },
    )


def flown_path_at_goal(
    raster: PlanRaster,
    mask: np.ndarray,
    grid: GridSpec,
    tour_cells: np.ndarray,
    order: list[int],
    pred: np.ndarray,
    n_m_mask: np.ndarray,
    target: int,
    range_m: float = VIEW_RANGE_M,
) -> float | None:
    """Fly the tour cell by cell with the real 87° sensor facing the direction of travel (noiseless), turning a
    full circle at the start and at every viewpoint, and return the path (m) at which ``target`` N_M cells are
    first known — the bench's headline measure applied to the oracle's flight (``None`` if never)."""
    forward = SensorConfig(range_m=range_m, occupied_noise_prob=0.0)
    factor = resolution_factor(raster.grid.resolution_m, LOW_RES_M)
    occupied = np.ascontiguousarray(raster.occupied)
    known = np.zeros(n_m_mask.size, dtype=bool)
    flat_nm = n_m_mask.ravel()
    n_cols_low = n_m_mask.shape[1]
    flat_of = np.flatnonzero(mask)  # Dijkstra node → flat index of the planning grid

    def look(rc: np.ndarray, yaw: float, config: SensorConfig | None) -> bool:
        x, y = grid.center_of(int(rc[0]), int(rc[1]))
        if config is None:
            cells = visible_cells(raster, np.array([[x, y]]), n_m_mask, range_m)[0]
        else:
            patch = scan(occupied, raster.grid, float(x), float(y), yaw, config)
            rows, cols = np.nonzero(patch.codes != UNKNOWN)
            cells = ((rows + patch.row0) // factor) * n_cols_low + (cols + patch.col0) // factor
            cells = cells[flat_nm[cells]]
        known[cells] = True
        return int(known.sum()) >= target

    if look(tour_cells[order[0]], 0.0, None):
        return 0.0
    index = np.full(mask.shape, -1, dtype=np.int64)
    index[mask] = np.arange(int(mask.sum()))
    path_m = 0.0
    for a, b in zip(order[:-1], order[1:], strict=True):
        source_node = index[tuple(tour_cells[a])]
        node, nodes = index[tuple(tour_cells[b])], []
        while node != source_node and node >= 0:
            nodes.append(node)
            node = pred[a, node]
        cells = np.column_stack(np.unravel_index(flat_of[nodes[::-1]], mask.shape))
        previous = tour_cells[a]
        for rc in cells:
            step = rc - previous
            path_m += math.hypot(*step) * grid.resolution_m
            if look(rc, math.atan2(step[0], step[1]), forward):
                return path_m
            previous = rc
        if look(tour_cells[b], 0.0, None):
            return path_m
    return None


def _snap(mask: np.ndarray, grid: GridSpec, x_m: float, y_m: float) -> tuple[int, int]:
    """The planning cell of (x, y), or the nearest one of ``mask`` if that is not in it."""
    row, col = (int(v) for v in grid.cell_of(x_m, y_m))
    if grid.contains(np.asarray(row), np.asarray(col)) and mask[row, col]:
        return row, col
    _, (rows, cols) = ndimage.distance_transform_edt(~mask, return_indices=True)
    row, col = min(max(row, 0), mask.shape[0] - 1), min(max(col, 0), mask.shape[1] - 1)
    return int(rows[row, col]), int(cols[row, col])
