"""The global layer of the planning hierarchy: a route to the nearest target anywhere on the observed map.

The local planners search a fine graph (0.10 m, :mod:`edge_explorer.plan.graph`) over a window of the maps
(:mod:`edge_explorer.plan.window`); beyond it this layer searches the whole observed 0.20 m map once per event (the
window ran out of targets, or it moved while the vehicle was in transit), not once per step. Its graph
(:func:`route_graph`) is the 0.20 m cells observed FREE whose centre lies at least ``min_clearance_m`` from every
observed OCCUPIED cell (two cells by default, so a 0.8 m door stays open at this resolution), 8-connected, edges
weighted as the fine graph weights them; the vehicle's own cell is always a node. A route (:func:`nearest_route`)
leads to the reachable node nearest along the graph among those within ``goal_radius_m`` of a target cell — Nearest
Frontier at building scale, the global half of a local-first hierarchy like TARE's. When no target is reachable on
that graph, the search is repeated on the graph of every cell observed FREE (``narrow_clearance_m``): a 0.6–0.8 m
door can show only two FREE cells across at 0.20 m, which ``min_clearance_m`` closes although the window's fine graph
flies it, and a vehicle beyond such doors would end its flight with the building unexplored. A vehicle whose cell
reaches no target (among cells the map has not seen FREE, or too near a wall) is routed from the nodes within
``escape_m`` that its cell reaches without crossing an observed wall (:func:`escape_sources`). The route only leads
the way: the vehicle flies it through the window's fine graph and follower
(:class:`~edge_explorer.plan.window.Transit`), so the follower's safety rules hold.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.sparse.csgraph import dijkstra

from edge_explorer.plan.graph import GraphConfig, PlanningGraph, Traversable
from edge_explorer.world.flight_space import centre_clearance_m
from edge_explorer.world.grid import FREE, OCCUPIED, GridSpec


@dataclass(frozen=True)
class RouteConfig:
    """The global layer's graph and goals."""

    min_clearance_m: float = 0.4  # a route cell's centre keeps this far from the centre of every OCCUPIED cell
    goal_radius_m: float = 0.6  # a route ends this close to a target cell
    # when the vehicle's own cell reaches no target on the graph (it sits among cells the 0.20 m map has not seen
    # FREE, or too near a wall), the route may start from the graph's nodes this close to it that its cell reaches
    # through cells not observed OCCUPIED (:func:`escape_sources`): a learned flight on a real whole floor ended
    # with a "planner stall" at 41.8 % coverage and 3,120 m² reachable, its vehicle in a 0.6 m unseen slot between
    # two walls whose cell reached 8 nodes (kthwhole_50037765_PLAN3, run 1, session 56)
    escape_m: float = 2.0
    # when no route keeps min_clearance_m, one may pass cells this near an OCCUPIED cell's centre (0.2 m: every cell
    # observed FREE; not below min_clearance_m: no second search). A door or slot of 0.6–0.8 m can show only two FREE
    # cells across on the 0.20 m map, which min_clearance_m closes although the window's fine graph flies it: Nearest
    # Frontier on a real whole floor ended its flight with a "planner stall" at 44 % coverage and 5,312 m² reachable,
    # in a corridor whose ways on were such slots (kthwhole_50010535_PLAN1, run 1, with a target rule that was not
    # adopted, session 60)
    narrow_clearance_m: float = 0.2
    graph: GraphConfig = GraphConfig(factor=1)

    def __post_init__(self) -> None:
        if min(self.min_clearance_m, self.narrow_clearance_m, self.escape_m) < 0 or self.goal_radius_m <= 0:
            raise ValueError("min_clearance_m, narrow_clearance_m and escape_m must be ≥ 0 and goal_radius_m > 0")


@dataclass(frozen=True)
class Route:
    """Where the global layer leads: the path (m) from the vehicle's cell and the target cells at its end."""

    path_xy_m: np.ndarray  # (K, 2) centres of 0.20 m cells, the vehicle's first
    target_cells: np.ndarray  # flat indices on the 0.20 m map: the targets within goal_radius_m of the end

    @property
    def length_m(self) -> float:
        return float(np.hypot(*np.diff(self.path_xy_m, axis=0).T).sum()) if len(self.path_xy_m) > 1 else 0.0


def route_graph(low: np.ndarray, grid: GridSpec, pose_xy_m: tuple[float, float], config: RouteConfig) -> PlanningGraph:
    """The global layer's graph of the observed 0.20 m map ``low`` (module docstring)."""
    clearance = centre_clearance_m(low == OCCUPIED, grid.resolution_m)
    mask = (low == FREE) & (clearance >= config.min_clearance_m)
    row, col = (int(v) for v in grid.cell_of(*pose_xy_m))
    if grid.contains(np.array(row), np.array(col)):
        mask[row, col] = True
    return PlanningGraph.from_traversable(Traversable(grid, mask, clearance), config.graph)


def nearest_route(
    low: np.ndarray, grid: GridSpec, targets: np.ndarray, pose_xy_m: tuple[float, float], config: RouteConfig
) -> Route | None:
    """The route to the nearest reachable node within ``goal_radius_m`` of a ``targets`` cell (bool on ``grid``);
    when no target is reachable on the graph, the same on the graph of ``narrow_clearance_m``; ``None`` when none is
    reachable on either."""
    if not targets.any():
        return None
    route = _nearest_route(low, grid, targets, pose_xy_m, config)
    if route is None and config.narrow_clearance_m < config.min_clearance_m:
        narrow = dataclasses.replace(config, min_clearance_m=config.narrow_clearance_m)
        route = _nearest_route(low, grid, targets, pose_xy_m, narrow)
    return route


def _nearest_route(
    low: np.ndarray, grid: GridSpec, targets: np.ndarray, pose_xy_m: tuple[float, float], config: RouteConfig
) -> Route | None:
    """:func:`nearest_route` on the graph of ``config.min_clearance_m``."""
    graph = route_graph(low, grid, pose_xy_m, config)
    start = graph.node_at(*pose_xy_m)
    if start < 0:
        return None
    radius = max(int(math.ceil(config.goal_radius_m / grid.resolution_m)), 1)
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    near = cv2.dilate(targets.astype(np.uint8), disk, borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    candidates = graph.node_of[near]
    candidates = candidates[candidates >= 0]
    if len(candidates) == 0:
        return None
    cost, predecessors = graph.search([start])
    cost, predecessors = cost[0], predecessors[0]
    if not np.isfinite(cost[candidates]).any():  # the vehicle's cell is cut off: start from the nodes near it
        sources = escape_sources(low, grid, graph, pose_xy_m, config.escape_m)
        if len(sources) == 0:
            return None
        cost, predecessors, _ = dijkstra(
            graph.graph, directed=False, indices=sources, return_predecessors=True, min_only=True
        )
    reachable = candidates[np.isfinite(cost[candidates])]
    if len(reachable) == 0:
        return None
    end = int(reachable[np.argmin(cost[reachable])])
    path = graph.path_xy_m(predecessors, end)
    if graph.node_at(*path[0]) != start:  # an escape: the route starts at the vehicle's cell all the same
        path = np.vstack([graph.node_xy_m(np.array([start])), path])
    rows, cols = np.nonzero(targets)
    x, y = grid.center_of(rows, cols)
    close = np.hypot(x - path[-1, 0], y - path[-1, 1]) <= config.goal_radius_m + grid.resolution_m
    return Route(path, np.ravel_multi_index((rows[close], cols[close]), targets.shape))


def via_index(path_xy_m: np.ndarray, inside: tuple[float, float, float, float]) -> int:
    """The index of the last point of ``path_xy_m`` before it first leaves the box ``inside`` (x0, y0, x1, y1 in
    metres); the last index when it never leaves. The vehicle (the path's first point) is inside."""
    x0, y0, x1, y1 = inside
    x, y = path_xy_m[:, 0], path_xy_m[:, 1]
    out = np.flatnonzero((x < x0) | (x > x1) | (y < y0) | (y > y1))
    return len(path_xy_m) - 1 if len(out) == 0 else max(int(out[0]) - 1, 0)


def escape_sources(
    low: np.ndarray, grid: GridSpec, graph: PlanningGraph, pose_xy_m: tuple[float, float], escape_m: float
) -> np.ndarray:
    """The route graph's nodes within ``escape_m`` of the vehicle that its cell reaches through 4-connected cells
    not observed OCCUPIED (so never through a wall the map shows): where a cut-off vehicle's route may start."""
    row, col = (int(v) for v in grid.cell_of(*pose_xy_m))
    k = int(math.ceil(escape_m / grid.resolution_m))
    r0, c0 = max(row - k, 0), max(col - k, 0)
    patch = np.ascontiguousarray(low[r0 : row + k + 1, c0 : col + k + 1] != OCCUPIED).astype(np.uint8)
    if not (0 <= row - r0 < patch.shape[0] and 0 <= col - c0 < patch.shape[1]):
        return np.zeros(0, dtype=np.int64)
    patch[row - r0, col - c0] = 1
    _, labels = cv2.connectedComponents(patch, connectivity=4)
    rows, cols = np.nonzero(labels == labels[row - r0, col - c0])
    near = np.hypot(rows + r0 - row, cols + c0 - col) * grid.resolution_m <= escape_m
    nodes = graph.node_of[rows[near] + r0, cols[near] + c0]
    return np.unique(nodes[nodes >= 0])
