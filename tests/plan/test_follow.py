"""Path following with the six actions (edge_explorer.plan.follow)."""

import math

import numpy as np
import pytest

from edge_explorer.mapping import ego
from edge_explorer.plan.follow import FollowConfig, FreeSpace, arrived, choose_action, remaining_path_m
from edge_explorer.vehicle import dynamics
from edge_explorer.vehicle.dynamics import Action, load_action_table
from edge_explorer.world.grid import FREE, NON_FLIGHT, OCCUPIED, GridSpec
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


def test_free_space_measures_over_the_known_part_of_a_mostly_unknown_map():
    """Distances are measured over the known cells' box and a 1 m ring only: the whole map's there (to float
    rounding: opencv's distance transform differs by up to 2e-6 m with the array's size); beyond, every cell is unknown,
    its unseen clearance 0 and its obstacle clearance above the ring (inf), as the whole map would say."""
    from edge_explorer.world.flight_space import centre_clearance_m
    from edge_explorer.world.grid import UNKNOWN

    rng = np.random.default_rng(1)
    codes = np.full((400, 500), UNKNOWN, dtype=np.int8)
    codes[150:260, 120:300] = FREE
    for _ in range(40):
        r, c, h, w = int(rng.integers(140, 260)), int(rng.integers(110, 300)), *rng.integers(1, 12, 2).tolist()
        codes[r : r + h, c : c + w] = OCCUPIED if rng.random() < 0.6 else UNKNOWN
    grid = GridSpec((0.0, 0.0), 0.05, codes.shape)
    free = FreeSpace.from_codes(codes, grid)
    clearance = centre_clearance_m(codes == OCCUPIED, 0.05)
    np.testing.assert_allclose(free.unseen_clearance_m, centre_clearance_m(codes == UNKNOWN, 0.05), atol=1e-5)
    known_box = (codes != UNKNOWN).any(axis=1).nonzero()[0], (codes != UNKNOWN).any(axis=0).nonzero()[0]
    inside = np.zeros(codes.shape, dtype=bool)  # the known cells' box and the 1 m ring
    inside[known_box[0][0] - 20 : known_box[0][-1] + 21, known_box[1][0] - 20 : known_box[1][-1] + 21] = True
    np.testing.assert_allclose(free.clearance_m[inside], clearance[inside], atol=1e-5)
    assert (codes[~inside] == UNKNOWN).all() and np.isinf(free.clearance_m[~inside]).all()
    assert clearance[~inside].min() > 1.0
    everywhere_known = np.where(codes == UNKNOWN, FREE, codes)
    np.testing.assert_allclose(
        FreeSpace.from_codes(everywhere_known, grid).clearance_m,
        centre_clearance_m(everywhere_known == OCCUPIED, 0.05),
        atol=1e-5,
    )


def test_free_space_updated_step_by_step_agrees_with_one_measured_afresh():
    """A step's update measures again only near the changed cells; what every comparison reads (a distance up to the
    1 m ring) is what measuring the whole map afresh gives, and a distance above the ring stays above it. A change
    that grows the known cells' box measures the box afresh."""
    from edge_explorer.world.grid import UNKNOWN

    rng = np.random.default_rng(3)
    codes = np.full((300, 360), UNKNOWN, dtype=np.int8)
    codes[60:240, 60:300] = FREE
    codes[100:104, 80:200] = OCCUPIED
    grid = GridSpec((0.0, 0.0), 0.05, codes.shape)
    free = FreeSpace.from_codes(codes, grid)
    for step in range(12):
        codes = codes.copy()
        r, c = int(rng.integers(60, 230)), int(rng.integers(60, 290))
        h, w = rng.integers(1, 10, 2).tolist()
        codes[r : r + h, c : c + w] = (OCCUPIED, FREE, UNKNOWN)[step % 3]
        if step == 7:
            codes[20:24, 20:40] = FREE  # outside the box: measured afresh
        free = FreeSpace.from_codes(codes, grid, previous=free)
        fresh = FreeSpace.from_codes(codes, grid)
        np.testing.assert_array_equal(free.known_free, fresh.known_free)
        for updated, measured in (
            (free.clearance_m, fresh.clearance_m),
            (free.unseen_clearance_m, fresh.unseen_clearance_m),
        ):
            close = measured <= 1.0
            np.testing.assert_allclose(updated[close], measured[close], atol=1e-5)
            assert (updated[~close] > 1.0).all()
    assert free.clearance_m[101, 150] == 0.0 and free.unseen_clearance_m[0, 0] == 0.0


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


def test_blocked_actions_are_never_chosen(rooms, table):
    _, free = rooms
    pose, path = (1.0, 1.5, 0.0), np.array([[1.0, 1.5], [3.0, 1.5]])
    blocked: set[int] = set()
    for _ in range(3):
        action = choose_action(table, pose, Action.HOVER, path, free, blocked_actions=frozenset(blocked))
        assert action is not None and action not in blocked
        blocked.add(action)
    assert choose_action(table, pose, Action.HOVER, path, free, blocked_actions=frozenset(range(1, 6))) == Action.HOVER


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


def test_keeps_its_centre_away_from_unseen_cells_when_asked(rooms, table):
    """An unseen cell beside the path may be a wall: with ``unseen_clearance_m`` (the default) no chosen mean motion
    (nor the drift braking after it) takes the centre closer than that to an unseen cell; without it some do."""
    raster, _ = rooms
    codes = raster.truth_codes()
    codes[:, raster.grid.cell_of(2.4, 0.0)[1] :] = 0  # the east room beyond x = 2.4 m unseen
    free = FreeSpace.from_codes(codes, raster.grid)
    near_unseen = free.unseen_clearance_m < 0.25
    careful = FollowConfig()
    assert careful.unseen_clearance_m == 0.25  # the robot radius
    rng = np.random.default_rng(0)
    start = np.argwhere(free.known_free & (free.clearance_m >= careful.safe_distance_m) & ~near_unseen)
    start = start[free.unseen_clearance_m[tuple(start.T)] < 0.4]  # where one motion can come too close
    bold_violations = 0
    for _ in range(200):
        row, col = start[rng.integers(len(start))]
        x, y = (float(v) for v in raster.grid.center_of(row, col))
        pose, previous = (x, y, float(rng.uniform(-math.pi, math.pi))), int(rng.integers(6))
        drift = dynamics.body_to_map(*pose, *table.mean_step(previous, Action.HOVER))
        if dynamics.swept_path_blocked(near_unseen, raster.grid, pose[:2], drift[:2]):
            continue  # its momentum alone carries it there: a state the careful follower never gets into
        bearing = rng.uniform(-math.pi, math.pi)
        target = np.array([[x + 2.0 * math.cos(bearing), y + 2.0 * math.sin(bearing)]])
        for config in (careful, FollowConfig(unseen_clearance_m=0.0)):
            action = choose_action(table, pose, previous, target, free, config)
            end = dynamics.body_to_map(*pose, *table.mean_step(previous, action))
            brake = dynamics.body_to_map(*end, *table.mean_step(action, Action.HOVER))
            entered = dynamics.swept_path_blocked(near_unseen, raster.grid, pose[:2], end[:2]) or (
                dynamics.swept_path_blocked(near_unseen, raster.grid, end[:2], brake[:2])
            )
            if config is careful:
                assert not entered
            else:
                bold_violations += entered
    assert bold_violations > 0


def test_arrival_needs_the_heading():
    config = FollowConfig()
    path = np.array([[0.0, 0.0], [1.0, 0.0]])
    assert arrived((1.1, 0.0, 0.0), path, None, config)
    assert not arrived((1.1, 0.0, 0.0), path, math.pi, config)
    assert not arrived((0.5, 0.0, 0.0), path, None, config)
    with pytest.raises(ValueError):
        FollowConfig(lookahead_m=0.0)


def test_remaining_path_is_measured_along_the_path():
    path = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])  # a U whose end is 1 m from its start
    assert remaining_path_m(path, (0.0, 0.0)) == pytest.approx(5.0)
    # Halfway up the bend: farther from the end in a straight line than at the start, but nearer along the path.
    assert remaining_path_m(path, (2.0, 0.5)) == pytest.approx(2.5)
    assert remaining_path_m(path, (1.0, -0.2)) == pytest.approx(0.2 + 4.0)  # off the path: the gap counts
    assert remaining_path_m(path[-1:], (0.0, 0.0)) == pytest.approx(1.0)


def open_space(size_m: float = 8.0) -> FreeSpace:
    """All-FREE 0.05 m grid centred on the origin, no obstacles."""
    cells = int(size_m / 0.05)
    grid = GridSpec((-size_m / 2, -size_m / 2), 0.05, (cells, cells))
    return FreeSpace.from_codes(np.full((cells, cells), FREE, dtype=np.int8), grid)


def test_final_heading_only_counts_at_the_path_end(table):
    """A final heading opposite to the path must not make the follower hover half-way: the pursuit target part-way
    along the path says nothing about the heading to take at its end."""
    path = np.array([[0.0, 0.0], [3.0, 0.0]])
    poses, done = fly(table, open_space(), (0.0, 0.0, 0.0), path, final_yaw=math.pi)
    assert done
    steps_to_end = next(k for k, p in enumerate(poses) if math.hypot(p[0] - 3.0, p[1]) <= 0.5)
    assert steps_to_end <= 8  # 3 m at about 0.5 m per step, without stops


def within_noise(table, blocked, grid, pose, previous, action, sigmas=None):
    """The mean step of ``action`` and its drift, shifted ``sigmas`` standard deviations (by default the
    follower's ``noise_sigmas``) in 8 directions, stay out of ``blocked``."""
    sigmas = FollowConfig().noise_sigmas if sigmas is None else sigmas
    end = dynamics.body_to_map(*pose, *table.mean_step(previous, action))
    drift = dynamics.body_to_map(*end, *table.mean_step(action, Action.HOVER))
    std_m = math.hypot(table.pos_std_m[previous, action], table.pos_std_m[action, Action.HOVER])
    for angle in np.linspace(0.0, 2 * math.pi, 8, endpoint=False):
        dx, dy = sigmas * std_m * math.cos(angle), sigmas * std_m * math.sin(angle)
        shifted, shifted_drift = (end[0] + dx, end[1] + dy), (drift[0] + dx, drift[1] + dy)
        if dynamics.swept_path_blocked(blocked, grid, pose[:2], shifted) or dynamics.swept_path_blocked(
            blocked, grid, shifted, shifted_drift
        ):
            return False
    return True


def pose_near(rng, raster, cells, previous_actions):
    """A random pose on one of ``cells`` (row, col) with a random heading, and a previous action among
    ``previous_actions``."""
    row, col = cells[rng.integers(len(cells))]
    x, y = (float(v) for v in raster.grid.center_of(row, col))
    return (x, y, float(rng.uniform(-math.pi, math.pi))), int(rng.choice(previous_actions))


def target_near(rng, pose):
    """A one-point path 0.5–3 m from ``pose`` in a random direction."""
    bearing, distance = rng.uniform(-math.pi, math.pi), rng.uniform(0.5, 3.0)
    return np.array([[pose[0] + distance * math.cos(bearing), pose[1] + distance * math.sin(bearing)]])


def test_prefers_motions_that_motion_noise_cannot_push_into_the_band(rooms, table):
    """Near walls, whenever some first step keeps the NON_FLIGHT band out of reach of ``noise_sigmas`` standard
    deviations of its motion noise, the follower takes such a step; without the preference (``noise_sigmas=0``) it
    does not always."""
    raster, free = rooms
    rng = np.random.default_rng(7)
    blocked = ego.inflate_codes(raster.truth_codes(), 0.05, 0.25) != -1
    near_wall = np.argwhere(free.known_free & (free.clearance_m >= 0.30) & (free.clearance_m <= 0.45))
    violations = {True: 0, False: 0}
    checked = 0
    while checked < 60:
        pose, previous = pose_near(rng, raster, near_wall, range(6))
        if not any(within_noise(table, blocked, raster.grid, pose, previous, a) for a in range(6)):
            continue  # nothing robust to prefer
        target = target_near(rng, pose)
        checked += 1
        for robust in (True, False):
            config = FollowConfig() if robust else FollowConfig(noise_sigmas=0.0)
            action = choose_action(table, pose, previous, target, free, config)
            violations[robust] += not within_noise(table, blocked, raster.grid, pose, previous, action)
    assert violations[True] == 0
    assert violations[False] > 0


def test_without_a_fully_robust_step_takes_the_most_robust_one(rooms, table):
    """Close to a wall, where no first step keeps the full ``noise_sigmas`` margin (a tight passage, or noise
    already pushed the vehicle in), the follower takes a step that keeps as many standard deviations (2, 1, 0 of
    the ladder) as the most robust one does; choosing by the path cost alone (``noise_sigmas=0``) does not always."""
    raster, free = rooms
    rng = np.random.default_rng(3)
    blocked = ego.inflate_codes(raster.truth_codes(), 0.05, 0.25) != -1
    near_wall = np.argwhere(free.known_free & (free.clearance_m >= 0.30) & (free.clearance_m <= 0.36))
    sigmas = FollowConfig().noise_sigmas
    rungs = (2 * sigmas / 3, sigmas / 3, 0.0)

    def rung(pose, previous, action):
        return next((s for s in rungs if within_noise(table, blocked, raster.grid, pose, previous, action, s)), -1.0)

    def mean_safe(pose, previous, action):
        """The follower's own test for a first step: its mean motion and drift keep the safe distance."""
        unsafe = free.unsafe_mask(pose[0], pose[1], FollowConfig().safe_distance_m, FollowConfig().unseen_clearance_m)
        end = dynamics.body_to_map(*pose, *table.mean_step(previous, action))
        drift = dynamics.body_to_map(*end, *table.mean_step(action, Action.HOVER))
        return not any(
            (a[0], a[1]) != (b[0], b[1]) and dynamics.swept_path_blocked(unsafe, raster.grid, a[:2], b[:2])
            for a, b in ((pose, end), (end, drift))
        )

    shortfalls = {True: 0, False: 0}
    checked = 0
    for _ in range(5000):
        if checked >= 40:
            break
        pose, previous = pose_near(rng, raster, near_wall, range(3, 6))
        if any(within_noise(table, blocked, raster.grid, pose, previous, a) for a in range(6)):
            continue  # a fully robust step exists: the preference above
        safe = [a for a in range(6) if mean_safe(pose, previous, a)]
        if not safe:
            continue  # nothing to choose from: the follower hovers
        best = max(rung(pose, previous, a) for a in safe)
        target = target_near(rng, pose)
        checked += 1
        for graded in (True, False):
            config = FollowConfig() if graded else FollowConfig(noise_sigmas=0.0)
            action = choose_action(table, pose, previous, target, free, config)
            shortfalls[graded] += rung(pose, previous, action) < best
    assert checked >= 40
    assert shortfalls[True] == 0
    assert shortfalls[False] > 0


def test_a_vehicle_that_keeps_hovering_beside_a_wall_stops_hovering_once_its_drift_would_reach_the_wall(rooms, table):
    """Beside a wall, where a hover keeps more of the noise margin for one step than any motion, the follower hovers;
    but a vehicle that has hovered there several times in a row (``hovers``) will keep drifting, and a hover's noise
    then counts as that of the hovers to come: it takes another action instead (here a turn in place, which changes
    its heading; a learned flight on a real whole floor hovered 20 steps at 0.30 m from a door jamb and touched it)."""
    raster, free = rooms
    rng = np.random.default_rng(11)
    config = FollowConfig()
    near_wall = np.argwhere(
        free.known_free & (free.clearance_m > 0.25) & (free.clearance_m < config.caution_distance_m)
    )
    cases = moved = 0
    for _ in range(5000):
        if cases >= 20:
            break
        pose, previous = pose_near(rng, raster, near_wall, [int(Action.HOVER)])
        target = target_near(rng, pose)
        if choose_action(table, pose, previous, target, free, config) != Action.HOVER:
            continue
        cases += 1
        assert choose_action(table, pose, previous, target, free, config, hovers=0) == Action.HOVER  # the default
        moved += choose_action(table, pose, previous, target, free, config, hovers=8) not in (Action.HOVER, None)
    assert cases >= 20
    assert moved == cases
