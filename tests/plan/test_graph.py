"""The planning graph (edge_explorer.plan.graph): paths keep off walls, unseen space is never crossed."""

import numpy as np
import pytest

from edge_explorer.plan.follow import FollowConfig, FreeSpace
from edge_explorer.plan.graph import GraphConfig, PlanningGraph
from edge_explorer.world.grid import UNKNOWN
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
