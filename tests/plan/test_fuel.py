"""FUEL-style planner (edge_explorer.plan.fuel)."""

import itertools
import math

import numpy as np
import pytest

from edge_explorer.plan.frontier import frontier_clusters
from edge_explorer.plan.fuel import FuelPlanner, open_tour, visible_counts
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.vehicle.sensor import SensorConfig
from edge_explorer.world.grid import GridSpec
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan

GRID = GridSpec((0.0, 0.0), 0.2, (30, 40))


def test_clusters_are_components_split_along_their_axis():
    frontier = np.zeros(GRID.shape, dtype=bool)
    frontier[5, 2:32] = True  # a 6 m line
    frontier[20:23, 10:12] = True  # a small blob
    clusters = frontier_clusters(frontier, GRID, max_radius_m=1.0)
    assert sorted(np.concatenate(clusters).tolist()) == np.flatnonzero(frontier).tolist()  # a partition
    blob = [c for c in clusters if (c // GRID.shape[1] >= 20).all()]
    assert len(blob) == 1 and len(blob[0]) == 6
    line = [c for c in clusters if (c // GRID.shape[1] == 5).all()]
    assert len(line) == 4  # 30 cells of 0.2 m split in halves until each is within 1 m of its centroid
    for cells in line:
        x, _ = GRID.center_of(*np.divmod(cells, GRID.shape[1]))
        assert np.abs(x - x.mean()).max() <= 1.0
        assert np.all(np.diff(np.sort(cells)) == 1)  # contiguous pieces of the line
    assert len(frontier_clusters(frontier, GRID, max_radius_m=1.0, min_cells=7)) == 4  # the blob is too small


def test_visibility_respects_walls_range_and_field_of_view():
    occupied = np.zeros(GRID.shape, dtype=bool)
    occupied[10:20, 20] = True  # a wall at x = 4.0..4.2 m
    cells = np.array([[5.1, 3.1], [3.1, 3.1], [3.1, 1.1], [7.9, 3.1]])  # behind the wall, open, open, beyond range
    viewpoint = np.array([[2.1, 3.1]])
    sensor = SensorConfig()
    east = visible_counts(viewpoint, np.array([[0.0]]), cells, occupied, GRID, sensor)
    assert east[0, 0] == 1  # only the open cell straight ahead; the south one is 63° off axis
    south = visible_counts(viewpoint, np.array([[-math.pi / 2]]), cells, occupied, GRID, sensor)
    assert south[0, 0] == 1
    wide = visible_counts(viewpoint, np.array([[0.0]]), cells, occupied, GRID, SensorConfig(fov_rad=math.radians(170)))
    assert wide[0, 0] == 2


def test_open_tour_is_optimal_on_a_small_asymmetric_instance():
    rng = np.random.default_rng(4)
    cost = rng.uniform(1, 10, (6, 6))
    cost[:, 0] = 50.0  # returning to the start is never part of an open tour

    def length(order):
        return sum(cost[a, b] for a, b in itertools.pairwise(order))

    best = min(([0, *p] for p in itertools.permutations(range(1, 6))), key=length)
    tour = open_tour(cost)
    assert tour[0] == 0 and sorted(tour) == list(range(6))
    assert length(tour) == pytest.approx(length(best), rel=0.05)
    assert open_tour(cost[:2, :2]) == [0, 1]


@pytest.mark.slow
def test_fuel_explores_the_two_rooms():
    rooms = rasterize(two_room_plan(), 0.05)
    env = ExplorationEnv([rooms], EnvConfig(coverage_goal=1.0, max_steps=400))
    _, info = env.reset(seed=5, options={"start_pose": (3.0, 1.5, math.pi)})
    planner = FuelPlanner(table=env.table)
    previous = 0
    for _ in range(400):
        action = planner.act(env.maps, env.pose, previous)
        if action is None or info["coverage"] >= 0.95:
            break
        _, _, _, _, info = env.step(action)
        assert not info["collided"]
        previous = action
    assert info["coverage"] >= 0.95
    assert planner.replans >= 2
