"""The goal policy's action space (edge_explorer.plan.goal_grid): ego goal cells and the mask of valid goals."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from edge_explorer.mapping.ego import OBSERVATION_WINDOW_CELLS, rotate_crop
from edge_explorer.plan.follow import FreeSpace
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS, GOAL_POOL, ego_goal_cells, goal_options
from edge_explorer.plan.graph import GraphConfig, PlanningGraph
from edge_explorer.world.grid import FREE, OCCUPIED, UNKNOWN, GridSpec


def test_goal_cells_line_up_with_the_observation_window():
    low = GridSpec((0.0, 0.0), 0.2, (100, 100))
    pose = (10.1, 10.1, 0.3)
    codes = np.zeros(low.shape, dtype=np.int8)
    target = np.array([[13.3, 11.7]])  # a point ahead-left of the vehicle
    row, col = (int(v) for v in low.cell_of(*target[0]))
    codes[row, col] = OCCUPIED
    window = rotate_crop(codes, (int(pose[1] / 0.2), int(pose[0] / 0.2)), pose[2], OBSERVATION_WINDOW_CELLS)
    ego_rc = np.argwhere(window == OCCUPIED)[0]
    assert tuple(ego_goal_cells(target, pose, low.origin_xy, 0.2)[0]) == tuple(ego_rc // GOAL_POOL)
    here = ego_goal_cells(np.array([pose[:2]]), pose, low.origin_xy, 0.2)[0]
    assert tuple(here) == (OBSERVATION_WINDOW_CELLS // 2 // GOAL_POOL,) * 2  # the vehicle sits in the centre cell


def _random_map(seed: int) -> tuple[np.ndarray, GridSpec]:
    """A 0.05 m map of a few random rectangular free rooms, walls and unknown blocks."""
    rng = np.random.default_rng(seed)
    grid = GridSpec((0.0, 0.0), 0.05, (160, 160))
    codes = np.full(grid.shape, OCCUPIED, dtype=np.int8)
    for _ in range(6):
        r, c = rng.integers(5, 120, 2)
        h, w = rng.integers(15, 40, 2)
        codes[r : r + h, c : c + w] = FREE
    for _ in range(4):
        r, c = rng.integers(0, 150, 2)
        codes[r : r + rng.integers(3, 20), c : c + rng.integers(3, 20)] = UNKNOWN
    return codes, grid


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), yaw=st.floats(-math.pi, math.pi))
def test_the_mask_never_admits_an_unreachable_goal(seed, yaw):
    codes, grid = _random_map(seed)
    free = FreeSpace.from_codes(codes, grid)
    free_cells = np.argwhere(codes == FREE)
    start_rc = free_cells[len(free_cells) // 2]
    x, y = grid.center_of(*start_rc)
    pose = (float(x), float(y), yaw)
    graph = PlanningGraph.build(free, 0.3, pose[:2], GraphConfig())
    start = graph.node_at(*pose[:2])
    cost, _ = graph.search([start])
    nodes = np.arange(len(graph.cells))  # every node is a candidate: reachable or not
    options = goal_options(nodes, graph.node_xy_m(nodes), cost[0], pose, (0.0, 0.0), 0.2)
    assert options.mask.shape == (GOAL_GRID_CELLS, GOAL_GRID_CELLS)
    chosen = options.node[options.mask]
    assert np.isfinite(cost[0, chosen]).all()  # every admitted goal is reachable through observed free space
    np.testing.assert_allclose(options.cost_m[options.mask], cost[0, chosen])
    reachable = np.flatnonzero(np.isfinite(cost[0]))
    cells = ego_goal_cells(graph.node_xy_m(reachable), pose, (0.0, 0.0), 0.2)
    inside = ((cells >= 0) & (cells < GOAL_GRID_CELLS)).all(axis=1)
    assert options.mask.sum() == len({tuple(c) for c in cells[inside]})  # … and every reachable cell is admitted
    for (i, j), n in zip(cells[inside], reachable[inside], strict=True):
        assert options.cost_m[i, j] <= cost[0, n]  # the cell's goal is its nearest reachable candidate
