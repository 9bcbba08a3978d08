"""FUEL-style exploration in 2-D (after Zhou et al., "FUEL: Fast UAV Exploration using Incremental Frontier
Structure and Hierarchical Planning", RA-L 2021).

At each replan:

1. **Frontier clusters**: connected components (8-neighbour) of the 0.20 m frontier cells
   (:func:`~edge_explorer.plan.frontier.frontier_mask`); a cluster with a cell farther than
   ``cluster_max_radius_m`` from its centroid is split in two along its principal axis, recursively
   (:func:`~edge_explorer.plan.frontier.frontier_clusters`, shared with the predictive expert). Components of
   fewer than ``min_cluster_cells`` cells stay out of the tour, as in FUEL: specks of frontier (a corner the
   sensor grazed, a gap behind furniture) would otherwise each pull the global tour towards them; they are
   visited by the nearest-frontier fallback once no large cluster is left.
2. **Viewpoints**: candidates on rings around each cluster's centroid, kept if they are reachable nodes of the
   planning graph. A candidate's coverage is the number of the cluster's cells the planar sensor would see from it
   (within range and field of view, line of sight not crossing an observed OCCUPIED cell — unknown space counts as
   transparent, as in FUEL), for a few headings around the bearing to the centroid (:func:`visible_counts`).
   The candidates covering at least ``keep_fraction`` of the best one are kept, best first.
3. **Global tour**: the best viewpoint of every cluster, ordered by an open asymmetric TSP from the vehicle
   (Google OR-Tools' routing solver; :func:`open_tour`). The cost between two poses is FUEL's travel time,
   max(path length / cruise speed, heading change / yaw rate), with path lengths from the planning graph.
4. **Local refinement**: the viewpoint of the tour's first cluster is re-chosen among its kept candidates to
   minimise the time vehicle → viewpoint → next cluster's viewpoint.

The vehicle then flies to that viewpoint with the shared follower and turns to its heading. It replans only on
events: most of the target cluster seen (``done_fraction``), or the shared events of
:class:`~edge_explorer.plan.frontier.GoalPlanner` (path blocked, stalled). A viewpoint reached without showing its
cluster hands over to the cluster's nearest frontier cell. If no cluster has a reachable viewpoint that sees
anything, it falls back to the nearest frontier.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from ortools.constraint_solver import pywrapcp, routing_enums_pb2

from edge_explorer.plan.follow import Pose
from edge_explorer.plan.frontier import (
    Goal,
    GoalPlanner,
    PlannerConfig,
    View,
    cluster_handover,
    frontier_clusters,
    nearest_frontier_goal,
)
from edge_explorer.vehicle.dynamics import ActionTable
from edge_explorer.vehicle.sensor import SensorConfig
from edge_explorer.world.grid import OCCUPIED, GridSpec

_UNREACHABLE_S = 1e5  # travel time standing in for "no path" in the TSP


@dataclass(frozen=True)
class FuelConfig:
    """Clustering, viewpoint sampling and replanning of :class:`FuelPlanner`."""

    planner: PlannerConfig = PlannerConfig()
    sensor: SensorConfig = SensorConfig()
    cluster_max_radius_m: float = 1.0
    min_cluster_cells: int = 6  # smaller frontier components stay out of the tour (the fallback still visits them)
    viewpoint_radii_m: tuple[float, ...] = (0.5, 1.0, 1.5)
    viewpoint_angles: int = 16  # candidates per ring
    yaw_offsets_rad: tuple[float, ...] = tuple(math.radians(a) for a in (-30.0, -15.0, 0.0, 15.0, 30.0))
    keep_fraction: float = 0.7  # candidates covering this share of the best one stay in the refinement
    max_kept: int = 8
    done_fraction: float = 0.8  # the target cluster is explored when this share of its cells is no frontier

    def __post_init__(self) -> None:
        if self.cluster_max_radius_m <= 0 or not self.viewpoint_radii_m or min(self.viewpoint_radii_m) <= 0:
            raise ValueError("cluster_max_radius_m and viewpoint_radii_m must be positive")
        if self.viewpoint_angles < 1 or self.max_kept < 1:
            raise ValueError("viewpoint_angles and max_kept must be ≥ 1")
        if not (0 < self.keep_fraction <= 1 and 0 < self.done_fraction <= 1):
            raise ValueError("keep_fraction and done_fraction must be in (0, 1]")


@dataclass(frozen=True)
class Viewpoints:
    """Kept candidate viewpoints of one cluster, best coverage first."""

    nodes: np.ndarray  # planning-graph node ids
    yaw_rad: np.ndarray
    coverage: np.ndarray  # cluster cells seen


def visible_counts(
    viewpoints_xy_m: np.ndarray,
    yaws_rad: np.ndarray,
    cells_xy_m: np.ndarray,
    occupied: np.ndarray,
    grid: GridSpec,
    sensor: SensorConfig,
) -> np.ndarray:
    """(M, Y) number of the K target cells the planar sensor sees from viewpoint m with heading ``yaws_rad[m, y]``.

    A cell is seen if its centre is within range and field of view and the segment to it crosses no cell of
    ``occupied`` (bool on ``grid``) before it, sampled every half cell.
    """
    delta = cells_xy_m[None, :, :] - viewpoints_xy_m[:, None, :]  # (M, K, 2)
    distance = np.hypot(delta[..., 0], delta[..., 1])
    samples = int(math.ceil(2.0 * float(distance.max(initial=0.0)) / grid.resolution_m)) + 2
    t = np.linspace(0.0, 1.0, samples)[:-1]  # the target cell itself does not block its own view
    points = viewpoints_xy_m[:, None, None, :] + t[None, None, :, None] * delta[:, :, None, :]  # (M, K, S, 2)
    rows, cols = grid.cell_of(points[..., 0], points[..., 1])
    rows = np.clip(rows, 0, grid.shape[0] - 1)
    cols = np.clip(cols, 0, grid.shape[1] - 1)
    clear = ~occupied[rows, cols].any(axis=-1)
    seen = clear & (distance <= sensor.range_m)  # (M, K)
    bearing = np.arctan2(delta[..., 1], delta[..., 0])
    off_axis = np.abs((bearing[:, None, :] - yaws_rad[:, :, None] + np.pi) % (2 * np.pi) - np.pi)  # (M, Y, K)
    return ((off_axis <= 0.5 * sensor.fov_rad) & seen[:, None, :]).sum(axis=-1)


def open_tour(cost_s: np.ndarray) -> list[int]:
    """Order of all nodes starting at node 0 and ending anywhere, minimising the summed ``cost_s[i, j]``.

    An open asymmetric TSP, solved with OR-Tools' routing solver (cheapest-arc start, greedy local search:
    deterministic and a few milliseconds for the tens of clusters of a floor): the route runs from node 0 to an
    extra end node that every node reaches for free.
    """
    n = len(cost_s)
    if n <= 2:
        return list(range(n))
    matrix = np.zeros((n + 1, n + 1), dtype=np.int64)
    matrix[:n, :n] = np.rint(np.minimum(cost_s, _UNREACHABLE_S) * 100.0)  # centiseconds: the solver wants integers
    manager = pywrapcp.RoutingIndexManager(n + 1, 1, [0], [n])
    routing = pywrapcp.RoutingModel(manager)
    routing.SetArcCostEvaluatorOfAllVehicles(routing.RegisterTransitMatrix(matrix.tolist()))
    params = pywrapcp.DefaultRoutingSearchParameters()
    params.first_solution_strategy = routing_enums_pb2.FirstSolutionStrategy.PATH_CHEAPEST_ARC
    params.local_search_metaheuristic = routing_enums_pb2.LocalSearchMetaheuristic.GREEDY_DESCENT
    solution = routing.SolveWithParameters(params)
    order, index = [], routing.Start(0)
    while not routing.IsEnd(index):
        order.append(manager.IndexToNode(index))
        index = solution.Value(routing.NextVar(index))
    return order


class FuelPlanner(GoalPlanner):
    """FUEL-style hierarchical exploration (see the module docstring)."""

    def __init__(self, config: FuelConfig = FuelConfig(), table: ActionTable | None = None) -> None:
        super().__init__(config.planner, table)
        self.fuel = config
        model = self.table.model
        self._speed_m_s = model.forward_step_m / model.step_s
        self._yaw_rate_rad_s = model.turn_step_rad / model.step_s

    def on_failure(self, goal: Goal, view: View, pose: Pose) -> Goal | None:
        """A viewpoint that did not show its cluster hands over to the nearest of the cluster's frontier cells
        (whose own failure drops it); the nearest-frontier goals fail as in the base class."""
        handover = cluster_handover(view, pose, goal, self.config.goal_radius_m)
        return handover if handover is not None else super().on_failure(goal, view, pose)

    def travel_time_s(self, path_m: np.ndarray, yaw_from_rad: np.ndarray, yaw_to_rad: np.ndarray) -> np.ndarray:
        """FUEL's lower bound of the time between two poses: max(path / speed, heading change / yaw rate)."""
        turn = np.abs((np.asarray(yaw_to_rad) - yaw_from_rad + np.pi) % (2 * np.pi) - np.pi)
        return np.maximum(np.asarray(path_m) / self._speed_m_s, turn / self._yaw_rate_rad_s)

    def select_goal(self, view: View, pose: Pose) -> Goal | None:
        if not view.frontier.any():
            return None
        start = view.graph.node_at(*pose[:2])
        if start < 0:
            return None
        reach_cost, predecessors = view.graph.search([start])
        clusters, options = [], []
        low_grid = view.maps.low_grid
        for cells in frontier_clusters(
            view.frontier, low_grid, self.fuel.cluster_max_radius_m, self.fuel.min_cluster_cells
        ):
            kept = self.viewpoints(view, cells, reach_cost[0])
            if kept is not None:
                clusters.append(cells)
                options.append(kept)
        if not clusters:
            return nearest_frontier_goal(view, pose, view.frontier, self.config.goal_radius_m)
        best_nodes = np.array([o.nodes[0] for o in options])
        best_yaws = np.array([o.yaw_rad[0] for o in options])
        # Tour over the vehicle (0) and each cluster's best viewpoint (1..K); path costs from one search per viewpoint.
        from_view, _ = view.graph.search(best_nodes)
        cost = np.zeros((len(clusters) + 1,) * 2)
        cost[0, 1:] = self.travel_time_s(reach_cost[0, best_nodes], pose[2], best_yaws)
        cost[1:, 1:] = self.travel_time_s(from_view[:, best_nodes], best_yaws[:, None], best_yaws[None, :])
        tour = open_tour(cost)
        first = tour[1] - 1
        kept = options[first]
        total = self.travel_time_s(reach_cost[0, kept.nodes], pose[2], kept.yaw_rad)
        if len(tour) > 2:  # local refinement against the next cluster of the tour
            second = tour[2] - 1
            total = total + self.travel_time_s(from_view[second, kept.nodes], kept.yaw_rad, best_yaws[second])
        choice = int(np.argmin(total))
        path = view.graph.path_xy_m(predecessors[0], int(kept.nodes[choice]))
        return Goal(path, float(kept.yaw_rad[choice]), clusters[first], done_fraction=self.fuel.done_fraction)

    def viewpoints(self, view: View, cells: np.ndarray, reach_cost: np.ndarray) -> Viewpoints | None:
        """Kept candidate viewpoints of one cluster (flat 0.20 m cells), or ``None`` if none sees any cell."""
        low_grid, graph = view.maps.low_grid, view.graph
        cx, cy = low_grid.center_of(*np.divmod(cells, low_grid.shape[1]))
        cells_xy = np.stack([cx, cy], axis=1)
        centre = cells_xy.mean(axis=0)
        angles = np.linspace(0.0, 2 * np.pi, self.fuel.viewpoint_angles, endpoint=False)
        radii = np.asarray(self.fuel.viewpoint_radii_m)
        ring = centre + np.stack(
            [np.outer(radii, np.cos(angles)).ravel(), np.outer(radii, np.sin(angles)).ravel()], axis=1
        )
        rows, cols = graph.grid.cell_of(ring[:, 0], ring[:, 1])
        inside = graph.grid.contains(rows, cols)
        nodes = np.unique(graph.node_of[rows[inside], cols[inside]])
        nodes = nodes[nodes >= 0]
        nodes = nodes[np.isfinite(reach_cost[nodes])]
        if len(nodes) == 0:
            return None
        xy = graph.node_xy_m(nodes)
        toward = np.arctan2(centre[1] - xy[:, 1], centre[0] - xy[:, 0])
        yaws = (toward[:, None] + np.array(self.fuel.yaw_offsets_rad) + np.pi) % (2 * np.pi) - np.pi  # (M, Y)
        counts = visible_counts(xy, yaws, cells_xy, view.maps.low == OCCUPIED, low_grid, self.fuel.sensor)
        best_yaw = counts.argmax(axis=1)
        coverage = counts[np.arange(len(nodes)), best_yaw]
        if coverage.max() == 0:
            return None
        # Best coverage first; among equals the nearer one (a stable sort keeps the ordering by reach cost).
        by_reach = np.argsort(reach_cost[nodes], kind="stable")
        order = by_reach[np.argsort(-coverage[by_reach], kind="stable")]
        order = order[coverage[order] >= self.fuel.keep_fraction * coverage.max()][: self.fuel.max_kept]
        return Viewpoints(nodes[order], yaws[order, best_yaw[order]], coverage[order])
