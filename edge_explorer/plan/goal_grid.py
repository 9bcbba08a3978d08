"""The learned goal planner's action space: a coarse heading-up grid of goal cells and the mask of valid goals.

The goal policy (docs/design.md §6) scores the cells of a *spatial action map*: the heading-up 0.20 m observation window
(:data:`~edge_explorer.mapping.ego.OBSERVATION_WINDOW_CELLS` = 237 cells, robot at its centre, heading along +row)
pooled ``GOAL_POOL`` × ``GOAL_POOL`` — 59 × 59 goal cells of 0.80 m, so a fully convolutional network's output lines
up with its input (ego goal cell (i, j) covers ego rows [4i, 4i + 4) and columns [4j, 4j + 4)).

A goal cell is *valid* when it holds a goal candidate the shared planner loop can fly to: a node of the planning
graph (observed free space at the robot's clearance) that is reachable from the vehicle and lies within
``goal_radius_m`` of a frontier cell (:func:`~edge_explorer.plan.frontier.goal_candidates`). Invalid cells are
masked, so a chosen goal is always reachable by construction. The cell's goal is its candidate nearest to the
vehicle along the graph; :func:`goal_options` computes them all from one Dijkstra search.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from edge_explorer.mapping.ego import OBSERVATION_WINDOW_CELLS, map_to_ego_cells
from edge_explorer.plan.follow import Pose

GOAL_POOL = 4  # observation cells per goal cell along each axis
GOAL_GRID_CELLS = OBSERVATION_WINDOW_CELLS // GOAL_POOL  # 59


@dataclass(frozen=True)
class GoalOptions:
    """The valid goals of one decision: per goal cell, its node (−1 where invalid) and the path cost to it."""

    node: np.ndarray  # int64 (G, G): planning-graph node id of the cell's goal, −1 if the cell is masked
    cost_m: np.ndarray  # float64 (G, G): graph cost from the vehicle to that node, inf where masked

    @property
    def mask(self) -> np.ndarray:
        """bool (G, G): the cells a policy may choose."""
        return self.node >= 0

    def flat_mask(self) -> np.ndarray:
        """The mask as the flat action mask of a Discrete(G·G) action space (row-major)."""
        return self.mask.ravel()


def ego_goal_cells(xy_m: np.ndarray, pose: Pose, low_origin_xy: tuple[float, float], low_res_m: float) -> np.ndarray:
    """(K, 2) ego goal cells (row, col) of map points ``xy_m`` (K, 2) for a vehicle at ``pose``; may lie outside
    the grid. The rotation is about the centre of the vehicle's 0.20 m cell, exactly as the observation's."""
    x0, y0 = low_origin_xy
    center = (int(np.floor((pose[1] - y0) / low_res_m)), int(np.floor((pose[0] - x0) / low_res_m)))
    map_rc = np.stack([(xy_m[:, 1] - y0) / low_res_m - 0.5, (xy_m[:, 0] - x0) / low_res_m - 0.5], axis=1)
    ego = map_to_ego_cells(map_rc, center, pose[2], OBSERVATION_WINDOW_CELLS)
    return np.floor((ego + 0.5) / GOAL_POOL).astype(np.int64)


def goal_options(
    candidate_nodes: np.ndarray,
    candidate_xy_m: np.ndarray,
    cost_m: np.ndarray,
    pose: Pose,
    low_origin_xy: tuple[float, float],
    low_res_m: float,
) -> GoalOptions:
    """The valid goal cells among ``candidate_nodes`` (planning-graph node ids with their centres
    ``candidate_xy_m``), given the graph cost of every node from the vehicle (``cost_m``, inf if unreachable):
    each goal cell holding a reachable candidate gets the one nearest along the graph."""
    size = GOAL_GRID_CELLS
    node = np.full((size, size), -1, dtype=np.int64)
    best = np.full((size, size), np.inf)
    candidate_nodes = np.asarray(candidate_nodes, dtype=np.int64)
    reach = cost_m[candidate_nodes]
    keep = np.isfinite(reach)
    if keep.any():
        cells = ego_goal_cells(np.asarray(candidate_xy_m)[keep], pose, low_origin_xy, low_res_m)
        inside = (cells >= 0).all(axis=1) & (cells < size).all(axis=1)
        nodes, reach, cells = candidate_nodes[keep][inside], reach[keep][inside], cells[inside]
        flat = cells[:, 0] * size + cells[:, 1]
        order = np.lexsort((reach, flat))  # by cell, nearest first within a cell
        first = order[np.unique(flat[order], return_index=True)[1]]
        node.flat[flat[first]] = nodes[first]
        best.flat[flat[first]] = reach[first]
    return GoalOptions(node, best)
