"""The global layer of the planning hierarchy: a route to the nearest target anywhere on the observed map.

The local planners search a fine graph (0.10 m, :mod:`edge_explorer.plan.graph`) over a window of the maps
(:mod:`edge_explorer.plan.window`); beyond it this layer searches the whole observed 0.20 m map once per event (the
window ran out of targets, or it moved while the vehicle was in transit), not once per step. Its graph
(:func:`route_graph`) is the 0.20 m cells observed FREE whose centre lies at least ``min_clearance_m`` from every
observed OCCUPIED cell (two cells by default, so a 0.8 m door stays open at this resolution), 8-connected, edges
weighted as the fine graph weights them; the vehicle's own cell is always a node. A route (:func:`nearest_route`)
leads to the reachable node nearest along the graph among those within ``goal_radius_m`` of a target cell — Nearest
Frontier at building scale, the global half of a local-first hierarchy like TARE's. The route only leads the way:
the vehicle flies it through the window's fine graph and follower (:class:`~edge_explorer.plan.window.Transit`),
so the follower's safety rules hold.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from edge_explorer.plan.graph import GraphConfig, PlanningGraph, Traversable
from edge_explorer.world.flight_space import centre_clearance_m
from edge_explorer.world.grid import FREE, OCCUPIED, GridSpec


@dataclass(frozen=True)
class RouteConfig:
    """The global layer's graph and goals."""

    min_clearance_m: float = 0.4  # a route cell's centre keeps this far from the centre of every OCCUPIED cell
    goal_radius_m: float = 0.6  # a route ends this close to a target cell
    graph: GraphConfig = GraphConfig(factor=1)

    def __post_init__(self) -> None:
        if self.min_clearance_m < 0 or self.goal_radius_m <= 0:
            raise ValueError("min_clearance_m must be ≥ 0 and goal_radius_m > 0")


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
    """The route to the nearest reachable node within ``goal_radius_m`` of a ``targets`` cell (bool on ``grid``),
    ``None`` when no target is reachable."""
    if not targets.any():
        return None
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
    reachable = candidates[np.isfinite(cost[0, candidates])]
    if len(reachable) == 0:
        return None
    end = int(reachable[np.argmin(cost[0, reachable])])
    path = graph.path_xy_m(predecessors[0], end)
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
