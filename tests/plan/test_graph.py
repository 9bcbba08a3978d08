"""The planning graph (edge_explorer.plan.graph): paths keep off walls, unseen space is never crossed."""

import numpy as np
import pytest

from edge_explorer.plan.follow import FollowConfig, FreeSpace
from edge_explorer.plan.graph import GraphConfig, PlanningGraph, Traversable
from edge_explorer.world.grid import UNKNOWN, GridSpec
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan


@pytest.fixture(scope="module")
def rooms():
    return rasterize(two_room_plan(), 0.05)


def test_path_through_the_door_keeps_off_the_walls(rooms):
    free = FreeSpace.from_codes(rooms.truth_codes(), rooms.grid)
    safe = FollowConfig().safe_distance_m
    graph = PlanningGraph.build(free, safe, (1.0, 0.6), GraphConfig())
    assert graph.grid.resolution_m == pytest.approx(0.10)
    start, goal = graph.node_at(1.0, 0.6), graph.node_at(3.0, 0.6)
    cost, predecessors = graph.search([start])
    path = graph.path_xy_m(predecessors[0], goal)
    assert np.hypot(*(path[0] - (1.0, 0.6))) < 0.08 and np.hypot(*(path[-1] - (3.0, 0.6))) < 0.08  # cell centres
    crossing = path[np.abs(path[:, 0] - 2.0) < 0.1]
    assert len(crossing) and ((crossing[:, 1] > 1.0) & (crossing[:, 1] < 2.0)).all()  # through the door
    assert all(free.clearance_at(x, y) >= safe for x, y in path)
    length = np.hypot(*np.diff(path, axis=0).T).sum()
    assert length <= cost[0, goal] <= 3.0 * length  # the clearance term only ever adds to the length


def test_unknown_space_is_not_traversable(rooms):
    codes = rooms.truth_codes()
    codes[:, rooms.grid.cell_of(2.5, 0.0)[1] :] = UNKNOWN  # the east room unseen
    graph = PlanningGraph.build(FreeSpace.from_codes(codes, rooms.grid), 0.325, (1.0, 1.5), GraphConfig())
    assert graph.node_at(3.0, 1.5) == -1 and graph.node_at(1.0, 1.5) >= 0


def test_each_pair_of_neighbouring_nodes_is_joined_once_weighted_by_length_and_clearance():
    rng = np.random.default_rng(5)
    grid = GridSpec((0.0, 0.0), 0.1, (9, 11))
    mask = rng.random(grid.shape) < 0.6
    clearance = rng.uniform(0.0, 1.0, grid.shape).astype(np.float32)
    config = GraphConfig()
    graph = PlanningGraph.from_traversable(Traversable(grid, mask, clearance), config)
    penalty = config.clearance_weight * np.clip(1.0 - clearance / config.clearance_soft_m, 0.0, 1.0)
    expected = {}
    for r, c in zip(*np.nonzero(mask), strict=True):
        for dr, dc in ((0, 1), (1, -1), (1, 0), (1, 1)):
            if 0 <= r + dr < grid.shape[0] and 0 <= c + dc < grid.shape[1] and mask[r + dr, c + dc]:
                weight = 0.1 * np.hypot(dr, dc) * (1.0 + 0.5 * (penalty[r, c] + penalty[r + dr, c + dc]))
                expected[(int(graph.node_of[r, c]), int(graph.node_of[r + dr, c + dc]))] = weight
    matrix = graph.graph
    coo = matrix.tocoo()
    got = {(int(i), int(j)): float(v) for i, j, v in zip(coo.row, coo.col, coo.data, strict=True)}
    assert got.keys() == expected.keys()  # each edge once, from its lower node id
    assert np.allclose([got[e] for e in expected], list(expected.values()), rtol=1e-6)
    assert matrix.has_canonical_format  # rows sorted, no duplicates: what the search expects
    cost, _ = graph.search([0])
    assert np.isfinite(cost[0]).sum() > 1
