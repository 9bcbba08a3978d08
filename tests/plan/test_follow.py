"""Path following with the six actions (edge_explorer.plan.follow)."""

import math

import numpy as np
import pytest

from edge_explorer.mapping import ego
from edge_explorer.plan.follow import FollowConfig, FreeSpace, arrived, choose_action
from edge_explorer.sim import dynamics
from edge_explorer.sim.dynamics import Action, load_action_table
from edge_explorer.world.grid import NON_FLIGHT, OCCUPIED
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan


@pytest.fixture(scope="module")
def rooms():
    """The two-room plan fully observed: its truth codes (OCCUPIED/FREE inside, UNKNOWN outside)."""
    raster = rasterize(two_room_plan(), 0.05)
    return raster, FreeSpace.from_codes(raster.truth_codes(), raster.grid)


@pytest.fixture(scope="module")
def table():
    return load_action_table()


def fly(table, free, pose, path, final_yaw=None, steps=60):
    """Follow ``path`` with the table's mean motions; returns the poses visited and whether it arrived."""
    poses, previous = [pose], Action.HOVER
    for _ in range(steps):
        action = choose_action(table, pose, previous, path, free, final_yaw_rad=final_yaw)
        if action is None:
            return poses, True
        pose = dynamics.body_to_map(*pose, *table.mean_step(previous, action))
        previous = action
        poses.append(pose)
    return poses, False


def test_clearance_is_the_inflation_band(rooms):
    raster, free = rooms
    codes = raster.truth_codes()
    band = ego.inflate_codes(codes, 0.05, 0.25)
    inside = codes != OCCUPIED
    np.testing.assert_array_equal((free.clearance_m <= 0.25 + 1e-6)[inside], (band == NON_FLIGHT)[inside])


def test_follows_a_path_through_the_door(rooms, table):
    raster, free = rooms
    path = np.array([[1.0, 1.5], [2.0, 1.5], [3.0, 1.5]])  # west room → door (y 1..2 at x = 2) → east room
    poses, done = fly(table, free, (1.0, 1.5, math.pi / 2), path, final_yaw=0.0)
    assert done
    x, y, yaw = poses[-1]
    assert math.hypot(x - 3.0, y - 1.5) <= FollowConfig().goal_tolerance_m
    assert abs(dynamics.wrap_angle_rad(yaw)) <= FollowConfig().yaw_tolerance_rad
    blocked = ego.inflate_codes(raster.truth_codes(), 0.05, 0.25) != -1  # any cell not FREE outside the band
    for a, b in zip(poses[:-1], poses[1:], strict=True):
        assert not dynamics.swept_path_blocked(blocked, raster.grid, a[:2], b[:2])


@pytest.mark.parametrize("seed", range(5))
def test_never_picks_a_motion_into_a_wall(rooms, table, seed):
    """From random poses near walls, with targets beyond them, the chosen action's mean motion stays clear."""
    raster, free = rooms
    rng = np.random.default_rng(seed)
    blocked = ego.inflate_codes(raster.truth_codes(), 0.05, 0.25) != -1
    clear = np.argwhere(free.known_free & (free.clearance_m >= FollowConfig().safe_distance_m))
    for _ in range(40):
        row, col = clear[rng.integers(len(clear))]
        x, y = (float(v) for v in raster.grid.center_of(row, col))
        pose = (x, y, float(rng.uniform(-math.pi, math.pi)))
        previous = int(rng.integers(6))
        drift = dynamics.body_to_map(*pose, *table.mean_step(previous, Action.HOVER))
        if dynamics.swept_path_blocked(blocked, raster.grid, pose[:2], drift[:2]):
            continue  # a state the follower never gets into: its momentum alone carries it into the band
        bearing, distance = rng.uniform(-math.pi, math.pi), rng.uniform(0.5, 3.0)  # beyond the arrival tolerance
        target = np.array([[x + distance * math.cos(bearing), y + distance * math.sin(bearing)]])
        action = choose_action(table, pose, previous, target, free)
        assert action is not None
        end = dynamics.body_to_map(*pose, *table.mean_step(previous, action))
        brake = dynamics.body_to_map(*end, *table.mean_step(action, Action.HOVER))
        assert not dynamics.swept_path_blocked(blocked, raster.grid, pose[:2], end[:2])
        assert not dynamics.swept_path_blocked(blocked, raster.grid, end[:2], brake[:2])


def test_does_not_fly_into_unknown_space(rooms, table):
    raster, _ = rooms
    codes = raster.truth_codes()
    codes[:, raster.grid.cell_of(1.5, 0.0)[1] :] = 0  # everything east of x = 1.5 m unseen
    free = FreeSpace.from_codes(codes, raster.grid)
    poses, _ = fly(table, free, (1.0, 1.5, 0.0), np.array([[3.0, 1.5]]), steps=10)
    assert max(p[0] for p in poses) < 1.5


def test_arrival_needs_the_heading():
    config = FollowConfig()
    path = np.array([[0.0, 0.0], [1.0, 0.0]])
    assert arrived((1.1, 0.0, 0.0), path, None, config)
    assert not arrived((1.1, 0.0, 0.0), path, math.pi, config)
    assert not arrived((0.5, 0.0, 0.0), path, None, config)
    with pytest.raises(ValueError):
        FollowConfig(lookahead_m=0.0)
