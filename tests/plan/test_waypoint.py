"""Action → waypoint and the waypoint safety check (edge_explorer.plan.waypoint)."""

import math

import numpy as np
import pytest

from edge_explorer.mapping import ego
from edge_explorer.plan.follow import FollowConfig, FreeSpace, choose_action, remaining_path_m
from edge_explorer.plan.waypoint import HOLD, WaypointPlanner, action_pose, cruise_velocity, path_home
from edge_explorer.vehicle import dynamics
from edge_explorer.vehicle.dynamics import Action, body_to_map, load_action_table
from edge_explorer.world.grid import CELL_DTYPE, FREE, NON_FLIGHT, OCCUPIED, UNKNOWN, GridSpec
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan

GRID = GridSpec((0.0, 0.0), 0.05, (80, 120))  # 6 m × 4 m
START = (1.0, 2.0, 0.0)  # facing +x


@pytest.fixture(scope="module")
def table():
    return load_action_table()


def free_space(codes: np.ndarray) -> FreeSpace:
    return FreeSpace.from_codes(codes, GRID)


def open_map() -> np.ndarray:
    return np.full(GRID.shape, FREE, dtype=CELL_DTYPE)


def with_wall_at(x_m: float) -> np.ndarray:
    codes = open_map()
    codes[:, int(x_m / GRID.resolution_m) :] = OCCUPIED
    return codes


def test_waypoint_is_the_tables_mean_motion(table):
    for previous in Action:
        for action in Action:
            expected = dynamics.body_to_map(*START, *table.mean_step(previous, action))
            assert action_pose(table, START, previous, action) == pytest.approx(expected)
    x, y, yaw = action_pose(table, START, Action.FORWARD, Action.FORWARD)
    assert (x, y, yaw) == pytest.approx((1.5, 2.0, 0.0), abs=1e-6)  # forward after forward: 0.5 m


def test_cruise_velocity_is_the_actions_steady_state(table):
    vx, vy, rate = cruise_velocity(table, Action.FORWARD, math.pi / 2)
    assert (vx, vy, rate) == pytest.approx((0.0, 0.5, 0.0), abs=1e-6)
    assert cruise_velocity(table, Action.TURN_LEFT, 0.3)[2] == pytest.approx(math.radians(30), abs=1e-6)
    assert cruise_velocity(table, Action.TURN_RIGHT, 0.3)[2] == pytest.approx(-math.radians(30), abs=1e-6)
    assert cruise_velocity(table, Action.HOVER, 1.0) == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)


def test_free_forward_motion_is_accepted(table):
    planner = WaypointPlanner(table, free_space(open_map()))
    waypoint = planner.first_safe(START[:2], START, Action.FORWARD, [("policy", Action.FORWARD)])
    assert (waypoint.source, waypoint.action) == ("policy", Action.FORWARD)
    assert (waypoint.x_m, waypoint.y_m) == pytest.approx((1.5, 2.0), abs=1e-6)
    assert waypoint.velocity == pytest.approx((0.5, 0.0, 0.0), abs=1e-6)


@pytest.mark.parametrize("wall_x_m", [1.55, 1.7, 1.8])
def test_never_a_waypoint_into_occupied_or_the_non_flight_band(table, wall_x_m):
    """Forward after forward ends at x = 1.5 and brakes to x = 1.625: with these walls that motion ends in the
    inflated map's OCCUPIED or NON_FLIGHT cells, so the next candidate is taken instead."""
    codes = with_wall_at(wall_x_m)
    end = action_pose(table, START, Action.FORWARD, Action.FORWARD)
    brake = action_pose(table, end, Action.FORWARD, Action.HOVER)
    row, col = (int(v) for v in GRID.cell_of(brake[0], brake[1]))
    assert ego.inflate_codes(codes, GRID.resolution_m)[row, col] in (OCCUPIED, NON_FLIGHT)
    planner = WaypointPlanner(table, free_space(codes))
    waypoint = planner.first_safe(
        START[:2], START, Action.FORWARD, [("policy", Action.FORWARD), ("frontier", Action.TURN_LEFT)]
    )
    assert (waypoint.source, waypoint.action) == ("frontier", Action.TURN_LEFT)


def test_the_check_keeps_its_safe_distance_beyond_the_band(table):
    """A wall 0.3 m (cell centre to cell centre) past the braking point is outside the NON_FLIGHT band (0.25 m): a
    planner keeping 0.35 m refuses the motion, one keeping the bare band accepts it."""
    free = free_space(with_wall_at(1.9))
    assert not WaypointPlanner(table, free, safe_distance_m=0.35).is_safe(START[:2], START, Action.FORWARD, 3)
    assert WaypointPlanner(table, free, safe_distance_m=0.25).is_safe(START[:2], START, Action.FORWARD, 3)


def test_unknown_space_is_not_flown_into(table):
    codes = open_map()
    codes[:, int(1.3 / GRID.resolution_m) :] = UNKNOWN  # unseen beyond x = 1.3 m
    planner = WaypointPlanner(table, free_space(codes))
    assert not planner.is_safe(START[:2], START, Action.FORWARD, Action.FORWARD)
    assert planner.is_safe(START[:2], START, Action.HOVER, Action.TURN_LEFT)


def test_nothing_safe_holds_where_the_vehicle_is(table):
    codes = with_wall_at(1.35)
    planner = WaypointPlanner(table, free_space(codes))
    odometry_xy = (1.02, 1.98)
    waypoint = planner.first_safe(odometry_xy, START, Action.FORWARD, [("policy", Action.FORWARD), ("hover", 0)])
    assert waypoint.source == HOLD and waypoint.action == Action.HOVER  # even hover drifts 0.125 m into the wall
    assert (waypoint.x_m, waypoint.y_m, waypoint.yaw_rad) == (1.02, 1.98, 0.0)
    assert waypoint.velocity == (0.0, 0.0, 0.0)


def test_candidates_are_evaluated_lazily(table):
    planner = WaypointPlanner(table, free_space(open_map()))
    asked = []

    def candidates():
        for source, action in (("policy", Action.FORWARD), ("frontier", Action.TURN_LEFT)):
            asked.append(source)
            yield source, action

    planner.first_safe(START[:2], START, Action.FORWARD, candidates())
    assert asked == ["policy"]  # the fallback was never computed


def test_a_none_candidate_is_skipped(table):
    planner = WaypointPlanner(table, free_space(open_map()))
    waypoint = planner.first_safe(START[:2], START, Action.HOVER, [("frontier", None), ("hover", Action.HOVER)])
    assert waypoint.source == "hover"


def test_the_safety_check_starts_at_the_odometry_position(table):
    """The step starts at the reference, but the vehicle is elsewhere: its straight way to the waypoint counts."""
    codes = open_map()
    codes[30:50, 28:32] = OCCUPIED  # a post between the vehicle (x 1.0) and the reference (x 2.0) at y 2.0
    planner = WaypointPlanner(table, free_space(codes))
    reference = (2.0, 2.0, 0.0)
    assert planner.is_safe((2.0, 2.0), reference, Action.HOVER, Action.FORWARD)
    assert not planner.is_safe((1.0, 2.0), reference, Action.HOVER, Action.FORWARD)


def test_path_home_goes_round_the_wall_through_the_door():
    raster = rasterize(two_room_plan(), 0.05)
    free = FreeSpace.from_codes(raster.truth_codes(), raster.grid)
    path = path_home(free, (3.0, 1.5), (1.0, 1.5), FollowConfig().safe_distance_m)
    assert path is not None
    assert math.dist(path[-1], (1.0, 1.5)) < 0.15
    crossing = path[np.argmin(np.abs(path[:, 0] - 2.0))]
    assert 1.0 < crossing[1] < 2.0  # through the door (y 1..2 at x = 2)
    assert all(free.clearance_at(*p) >= FollowConfig().safe_distance_m for p in path[1:])


# The whole-floor daemon flight of session 43 hovered on its way home for 150 s: a small unseen patch in the middle
# of a wide corridor, just ahead of the vehicle at rest; path_home grazed it (0.1 m off), closer than the follower's
# unseen_clearance_m, so every moving two-action sequence cost more than hovering.
CORRIDOR = GridSpec((0.0, 0.0), 0.05, (40, 120))  # 6 m × 2 m corridor, walls along y = 0 and y = 2
CORRIDOR_HOME = (5.0, 1.1)
CORRIDOR_START = (1.0, 0.95, math.radians(9.0))  # at rest, 0.35 m short of the patch, as the daemon was


def corridor_with_patch() -> np.ndarray:
    codes = np.full(CORRIDOR.shape, FREE, dtype=CELL_DTYPE)
    codes[0, :] = codes[-1, :] = OCCUPIED
    codes[19:22, 27:34] = UNKNOWN  # x 1.35–1.70 m, y 0.95–1.10 m: the daemon's patch, 0.35 × 0.15 m
    return codes


def test_the_path_home_keeps_the_followers_distance_from_unseen_cells():
    free = FreeSpace.from_codes(corridor_with_patch(), CORRIDOR)
    path = path_home(free, CORRIDOR_START[:2], CORRIDOR_HOME, FollowConfig().safe_distance_m)
    assert path is not None and math.dist(path[-1], CORRIDOR_HOME) < 0.15
    assert min(free.unseen_clearance_at(*p) for p in path[1:]) >= FollowConfig().unseen_clearance_m


def test_the_follower_flies_on_past_a_small_unseen_patch():
    table, config = load_action_table(), FollowConfig(noise_sigmas=0.0)  # the daemon's follower
    free = FreeSpace.from_codes(corridor_with_patch(), CORRIDOR)
    pose, previous = CORRIDOR_START, int(Action.HOVER)
    for _ in range(10):
        path = path_home(free, pose[:2], CORRIDOR_HOME, config.safe_distance_m)
        action = choose_action(table, pose, previous, path, free, config)
        assert action not in (None, Action.HOVER), f"hovers at {pose} with the way home open"
        pose, previous = body_to_map(*pose, *table.mean_step(previous, action)), action
    assert pose[0] > 3.0  # well past the patch (x ≤ 1.7 m), on the way home


# The whole-floor daemon flight of session 45 stood in a 0.7 m gap exactly safe_distance_m from its wall when one
# sensor-noise hit landed on the gap's other edge: the clearest 0.05 m cells across the gap, 0.30 m clear, then
# straddled two 0.10 m planning cells, each with a cell 0.25 m clear, and no planning cell around the vehicle's own
# was left (the escape rule did not apply: it stood exactly safe_distance_m clear) — no way home, though the
# follower could fly out.
ROOMS = GridSpec((0.0, 0.0), 0.05, (80, 80))  # 4 m × 4 m: a wall across y 1.8–2.2 m, two rooms either side
ROOMS_HOME = (2.0, 3.5)  # in the north room
IN_THE_GAP = (2.0, 2.0, math.radians(90.0))  # facing north, at rest, exactly 0.30 m from the gap's west edge


def rooms_with_a_noisy_gap() -> np.ndarray:
    codes = np.full(ROOMS.shape, FREE, dtype=CELL_DTYPE)
    codes[0, :] = codes[-1, :] = codes[:, 0] = codes[:, -1] = OCCUPIED
    codes[36:44, :] = OCCUPIED  # the wall, 0.4 m thick
    codes[36:44, 34:47] = FREE  # the gap: x 1.70–2.35 m, 0.65 m wide
    codes[40, 46] = OCCUPIED  # one sensor-noise hit on the gap's east edge (x 2.30–2.35 m, y 2.00–2.05 m)
    return codes


def test_a_vehicle_in_a_gap_a_noise_hit_narrowed_gets_a_way_out_the_follower_flies():
    table, config = load_action_table(), FollowConfig(noise_sigmas=0.0)  # the daemon's follower
    free = FreeSpace.from_codes(rooms_with_a_noisy_gap(), ROOMS)
    assert free.clearance_at(*IN_THE_GAP[:2]) == pytest.approx(config.safe_distance_m)
    pose, previous = IN_THE_GAP, int(Action.HOVER)
    path = path_home(free, pose[:2], ROOMS_HOME, config.safe_distance_m)
    assert path is not None and len(path) > 1 and math.dist(path[-1], ROOMS_HOME) < 0.15, "boxed in the gap"
    assert min(free.clearance_at(*p) for p in path[1:]) >= config.robot_radius_m  # never into the band's inside
    action = choose_action(table, pose, previous, path, free, config)
    assert action not in (None, Action.HOVER)
    end = body_to_map(*pose, *table.mean_step(previous, action))
    assert remaining_path_m(path, end[:2]) < remaining_path_m(path, pose[:2]) - 0.1
    for _ in range(6):  # and on, out of the gap into the north room, planning again every step as the daemon does
        path = path_home(free, pose[:2], ROOMS_HOME, config.safe_distance_m)
        action = choose_action(table, pose, previous, path, free, config)
        if action is None:  # arrived
            break
        assert action != Action.HOVER, f"hovers at {pose}"
        pose, previous = body_to_map(*pose, *table.mean_step(previous, action)), action
        assert free.clearance_at(*pose[:2]) >= config.safe_distance_m
    assert pose[1] > 2.5  # out of the wall (y ≤ 2.2 m), in the north room
