"""Frontiers, the goal-planner loop and Nearest Frontier (edge_explorer.plan.frontier)."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from edge_explorer.mapping.observed import ObservedMaps, coarsen_codes
from edge_explorer.plan.follow import remaining_path_m
from edge_explorer.plan.frontier import Goal, NearestFrontier, frontier_mask
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.world.grid import FREE, LOW_RES_M, OCCUPIED, UNKNOWN, GridSpec, resolution_factor
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan


@pytest.fixture(scope="module")
def rooms():
    return rasterize(two_room_plan(), 0.05)


def test_frontier_cells_are_free_cells_next_to_unknown():
    codes = np.full((6, 7), UNKNOWN, dtype=np.int8)
    codes[1:5, 1:4] = FREE
    codes[1:5, 4] = OCCUPIED  # a wall east of the free block: no frontier there
    expected = np.zeros_like(codes, dtype=bool)
    expected[1, 1:4] = expected[4, 1:4] = True  # north and south rows border unknown
    expected[1:5, 1] = True  # west column too
    np.testing.assert_array_equal(frontier_mask(codes), expected)
    assert not frontier_mask(np.full((3, 3), FREE, dtype=np.int8)).any()  # beyond the edge is not unknown


@pytest.mark.slow
def test_nearest_frontier_explores_the_two_rooms(rooms):
    env = ExplorationEnv([rooms], EnvConfig(coverage_goal=1.0, max_steps=400))
    _, info = env.reset(seed=3, options={"start_pose": (1.0, 1.5, -math.pi / 2)})
    planner = NearestFrontier(table=env.table)
    previous = 0
    for _ in range(400):
        action = planner.act(env.maps, env.pose, previous)
        if action is None or info["coverage"] >= 0.95:
            break
        _, _, _, _, info = env.step(action)
        assert not info["collided"]
        previous = action
    assert info["coverage"] >= 0.95
    assert env.pose[0] > 2.0  # it went through the door to see the east room


def west_room_seen(raster) -> ObservedMaps:
    """The two-room plan observed up to x = 2.5 m: the door and a strip of the east room known, the rest not."""
    codes = raster.truth_codes()
    codes[:, raster.grid.cell_of(2.5, 0.0)[1] :] = UNKNOWN
    factor = resolution_factor(raster.grid.resolution_m, LOW_RES_M)
    return ObservedMaps(raster.grid, raster.grid.coarsened(factor), codes, coarsen_codes(codes, factor))


class _PathView:
    """Stand-in for a View: the target is still a frontier and every path is traversable."""

    def __init__(self, shape):
        self.frontier = np.ones(shape, dtype=bool)
        self.traversable = SimpleNamespace(contains_path=lambda path: True)


def test_stall_detection_measures_progress_along_the_path():
    """A vehicle flying a U-shaped path gets farther from the path's end in a straight line for a while; that is
    progress, not a stall. A vehicle that does not move stalls after ``stall_steps``."""
    planner = NearestFrontier()
    path = np.array([[0.0, 0.0], [6.0, 0.0], [6.0, 1.0], [0.0, 1.0]])
    view = _PathView((4, 4))
    goal = Goal(path, 0.0, np.array([0]))
    for k in range(1, planner.config.stall_steps + 6):  # 0.3 m a step along the first leg: farther from the end
        assert planner.status(goal, view, (0.3 * k, 0.0, 0.0)) == "ok"
    stuck = Goal(path, 0.0, np.array([0]))
    statuses = [planner.status(stuck, view, (0.5, 0.0, 0.0)) for _ in range(planner.config.stall_steps + 2)]
    assert statuses[-1] == "failed" and "failed" not in statuses[: planner.config.stall_steps]


def test_stuck_far_from_the_goal_backs_off_before_giving_up_the_target(rooms):
    planner = NearestFrontier()
    pose = (0.6, 0.6, 0.0)
    view = planner.view(west_room_seen(rooms), pose)
    goal = planner.select_goal(view, pose)
    assert goal is not None and remaining_path_m(goal.path_xy_m, pose[:2]) > 1.0  # through the door, east
    for _ in range(2):
        retreat = planner._handle_failure(goal, view, pose, arrived=False)
        assert retreat is not None and retreat.retreat
        assert view.free.clearance_at(*retreat.path_xy_m[-1]) > view.free.clearance_at(*pose[:2])  # into the open
        assert not planner._dropped.any()  # the target is kept
        assert planner._handle_failure(retreat, view, pose, arrived=False) is None  # a back-off just ends
    assert planner._handle_failure(goal, view, pose, arrived=False) is None  # out of back-offs …
    assert planner._dropped.flat[goal.target_cells].all()  # … the target is given up


def test_arriving_without_seeing_the_target_drops_it_at_once(rooms):
    planner = NearestFrontier()
    pose = (0.6, 0.6, 0.0)
    view = planner.view(west_room_seen(rooms), pose)
    goal = planner.select_goal(view, pose)
    assert planner._handle_failure(goal, view, pose, arrived=True) is None
    assert planner._dropped.flat[goal.target_cells].all()


def test_hovering_goal_after_goal_backs_off_into_the_open(rooms, monkeypatch):
    """Each new goal restarts its own stuck count, so a vehicle where no motion towards any target is safe used to
    hover for dozens of steps while its drift carried it to the wall (a real plan, issue #18). After a run of
    hovers over any goals next to a wall the planner backs off into open space instead."""
    from edge_explorer.plan import frontier
    from edge_explorer.vehicle.dynamics import Action

    planner = NearestFrontier()
    planner._retreats_left = 0  # the back-offs for a follower stuck on its way are used up, as in that flight
    maps, pose = west_room_seen(rooms), (0.6, 0.35, 0.0)  # 0.30 m from the wall: inside the caution distance
    real_choose = frontier.choose_action
    monkeypatch.setattr(frontier, "choose_action", lambda *a, **k: Action.HOVER)
    actions = [planner.act(maps, pose, 0) for _ in range(frontier._MAX_HOVER_RUN)]
    assert actions == [Action.HOVER] * frontier._MAX_HOVER_RUN
    monkeypatch.setattr(frontier, "choose_action", real_choose)
    assert planner.act(maps, pose, 0) is not None
    goal = planner._goal
    assert goal is not None and goal.retreat
    view = planner.view(maps, pose)
    assert view.free.clearance_at(*goal.path_xy_m[-1]) > view.free.clearance_at(*pose[:2])


def test_hovering_in_the_open_keeps_the_goal_loop(rooms, monkeypatch):
    """Away from walls a run of hovers is harmless (the drift has room): no back-off, which would change the
    flights of the learned policy, whose goals often make the follower wait."""
    from edge_explorer.plan import frontier
    from edge_explorer.vehicle.dynamics import Action

    planner = NearestFrontier()
    planner._retreats_left = 0
    maps, pose = west_room_seen(rooms), (0.6, 0.9, 0.0)
    real_choose = frontier.choose_action
    monkeypatch.setattr(frontier, "choose_action", lambda *a, **k: Action.HOVER)
    for _ in range(frontier._MAX_HOVER_RUN):
        planner.act(maps, pose, 0)
    monkeypatch.setattr(frontier, "choose_action", real_choose)
    planner.act(maps, pose, 0)
    assert planner._goal is None or not planner._goal.retreat


def test_a_motion_that_left_the_vehicle_where_it_was_is_not_flown_again_from_there(rooms):
    """A collision stops the vehicle where it was (previous action HOVER, same pose). The map did not show what it
    hit (a wall not yet seen can lie within the robot radius of cells seen free), so the same map would choose the
    same motion again, step after step: a val flight made 43 collisions that way. It is blocked from that pose."""
    from edge_explorer.vehicle.dynamics import Action

    planner = NearestFrontier()
    maps, pose = west_room_seen(rooms), (0.6, 0.6, 0.0)
    first = planner.act(maps, pose, Action.HOVER)
    assert first not in (None, Action.HOVER)
    second = planner.act(maps, pose, Action.HOVER)  # it collided: stopped, nothing seen changed
    assert second is not None and second != first
    third = planner.act(maps, pose, Action.HOVER)
    assert third not in (first, second) or third == Action.HOVER
    moved = (pose[0] + 0.05, pose[1], pose[2])
    assert planner.act(maps, moved, first) is not None  # a vehicle that moved flies on as before
    planner.reset()
    assert planner.act(maps, pose, Action.HOVER) == first  # a new flight forgets


def test_a_commanded_hover_is_not_a_collision(rooms, monkeypatch):
    from edge_explorer.plan import frontier
    from edge_explorer.vehicle.dynamics import Action

    planner = NearestFrontier()
    maps, pose = west_room_seen(rooms), (0.6, 0.6, 0.0)
    real_choose = frontier.choose_action
    monkeypatch.setattr(frontier, "choose_action", lambda *a, **k: Action.HOVER)
    assert planner.act(maps, pose, Action.HOVER) == Action.HOVER
    monkeypatch.setattr(frontier, "choose_action", real_choose)
    assert planner._blocked == {}
    free_choice = NearestFrontier().act(maps, pose, Action.HOVER)
    assert planner.act(maps, pose, Action.HOVER) == free_choice


def test_a_goal_moved_to_a_shifted_grid_keeps_its_targets_in_metres_and_is_lost_off_it():
    old = GridSpec((2.0, 1.0), 0.2, (4, 5))
    new = GridSpec((2.4, 0.8), 0.2, (6, 6))  # its origin two columns after old's and one row before
    goal = Goal(np.array([[2.1, 1.1], [2.9, 1.5]]), 0.5, np.array([1 * 5 + 3, 2 * 5 + 4]), 0.5, hovers=2)
    moved = goal.on_grid(old, new)
    assert moved is not None and moved.hovers == 2 and moved.done_fraction == 0.5
    np.testing.assert_array_equal(moved.path_xy_m, goal.path_xy_m)
    for before, after in zip(goal.target_cells, moved.target_cells, strict=True):
        x, y = old.center_of(*divmod(int(before), 5))
        assert tuple(int(v) for v in new.cell_of(x, y)) == divmod(int(after), 6)
    off = Goal(goal.path_xy_m, 0.5, np.array([1 * 5 + 1]))  # old column 1 is new column −1
    assert off.on_grid(old, new) is None
