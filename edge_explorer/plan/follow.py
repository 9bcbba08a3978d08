"""Path following with the six discrete actions of the learned planner (docs/design.md §6).

The baselines (nearest frontier, FUEL-style) and the daemon's frontier fallback fly the same vehicle as the DRL
policy: one of six actions per step, whose motion depends on the previous action (the shared action table). So a
path is not tracked by a continuous controller; at every step :func:`choose_action` tries every two-action
sequence with the table's *mean* motion, drops the unsafe ones and takes the first action of the sequence whose
two poses lie closest to a pure-pursuit target on the path — a point ``lookahead_m`` further along the path than
the vehicle — while facing it, plus a cost for coming closer to a wall than is comfortable and a ten times higher
one inside the caution margin (so a vehicle flies there only through narrow passages, and one that motion noise
pushed there flies out before anything else).
Looking two steps ahead lets it brake or start a turn early, as the momentum requires.

Motion noise (docs/design.md §6: a forward step's position error has a standard deviation of about 3.5 cm per axis) is
larger than the hard margin, and a 0.05 m cell boundary can lie anywhere within it; a follower that only checks the
mean motion therefore ends steps where the next, unavoidable, drift enters the NON_FLIGHT band (measured: 3–18
collisions per 100 test-split flights). So among the safe sequences it prefers those whose first step is *robust*:
that step and its drift, shifted ``noise_sigmas`` standard deviations of the table's noise in any of 8 directions,
stay out of the observed NON_FLIGHT band. Only if no first step is robust (tight passages, or noise already put the
vehicle close to a wall) does it fall back to the mean-safe ones, and then to the most robust of them on a ladder of
two thirds, one third and none of that margin (by path cost alone there it brushed the walls of a 0.7 m passage on a
real floor three times in one flight; with the ladder twice, and the test split's one brush went away).
``noise_sigmas = 0`` turns the preference off.

Hovering is the most robust single step (its noise is a third of a forward step's), but a vehicle that hovers because
no motion keeps the margin will hover again, and its drift random-walks: a learned flight on a real whole floor hovered
20 steps at 0.30 m from a door jamb, goal after back-off goal, until it touched it. So the caller says how many times
in a row the vehicle has hovered (``hovers``), and a hover's noise counts as that of ``hovers + 1`` hovers
(√(hovers + 1) times one step's): after three, a turn in place, whose noise is a hover's and is not counted up,
ranks above it, so the vehicle turns (on 20 two-room poses beside a wall where it hovers, every one; a forward step
there seldom keeps the margin), which changes its heading and with it the motions open to it next. Hovers and turns
that alternate are each counted afresh, so their drift is not bounded by this rule. (Ranking a step away from the
wall with hovering outright after two hovers changed flights where that step was the riskier one: Nearest Frontier
brushed a wall with it on a real whole floor.)

Safety uses :class:`FreeSpace`, derived from the observed 0.05 m map: the distance from each cell to the nearest
observed OCCUPIED cell. A motion is safe if the vehicle's centre stays on known FREE cells whose distance is at
least the robot radius plus a margin for the motion noise (the complement of the inflated map's NON_FLIGHT band,
plus the margin), for the motion itself and for the drift that braking after it still causes — so the vehicle can
always stop. If sensor noise puts the vehicle inside that band, motions that do not bring it closer to an obstacle
stay allowed, so it can fly out again. Unknown cells count as unsafe: the vehicle only flies where it has seen.
And its mean motions keep the centre ``unseen_clearance_m`` (the robot radius) from every unknown cell, so the body
never sweeps over space the sensor has not seen: the camera looks ±43° ahead, and a turn-and-forward along a wall it
has not seen yet would otherwise hit it (docs/policy/goal_policy.md, session 30). Here too, a vehicle that is already
closer may fly anywhere that does not bring it closer still.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from itertools import product

import numpy as np

from edge_explorer.vehicle.dynamics import (
    NUM_ACTIONS,
    Action,
    ActionTable,
    body_to_map,
    swept_path_blocked,
    wrap_angle_rad,
)
from edge_explorer.world.flight_space import FLIGHT_CLEARANCE, centre_clearance_m
from edge_explorer.world.grid import FREE, OCCUPIED, UNKNOWN, GridSpec

Pose = tuple[float, float, float]  # (x_m, y_m, yaw_rad) in the map frame
_BAND_EPS_M = 1e-6  # the NON_FLIGHT band holds the cells *within* the robot radius of an obstacle
# the rungs of robustness (fractions of ``FollowConfig.noise_sigmas``) the follower tells apart when no first step
# holds the full margin: in a passage a step that keeps 2 sigmas clear beats one that keeps none (session 59)
_LADDER = (1.0, 2.0 / 3.0, 1.0 / 3.0, 0.0)
_DIRECTIONS = np.array([(math.cos(a), math.sin(a)) for a in np.linspace(0.0, 2 * math.pi, 8, endpoint=False)])
# FreeSpace measures distances only over the known cells' box grown by this ring (see FreeSpace.from_codes); more
# than any clearance a planner compares with (GraphConfig.clearance_soft_m, 0.6 m, is the largest).
_EXACT_RING_M = 1.0


def _ring_cells(grid: GridSpec) -> int:
    return int(math.ceil(_EXACT_RING_M / grid.resolution_m))


def _grown(rows: np.ndarray, cols: np.ndarray, by: int, within: tuple[slice, slice]) -> tuple[slice, slice]:
    """The box of the (sorted, non-empty) ``rows`` × ``cols`` grown by ``by`` cells, clipped to ``within``."""
    return (
        slice(max(int(rows[0]) - by, within[0].start), min(int(rows[-1]) + 1 + by, within[0].stop)),
        slice(max(int(cols[0]) - by, within[1].start), min(int(cols[-1]) + 1 + by, within[1].stop)),
    )


def _known_box(codes: np.ndarray, grid: GridSpec) -> tuple[slice, slice] | None:
    """The box of the known cells grown by the ring (clipped to the map), or None when no cell is known."""
    known = codes != UNKNOWN
    rows, cols = np.flatnonzero(known.any(axis=1)), np.flatnonzero(known.any(axis=0))
    if not rows.size:
        return None
    return _grown(rows, cols, _ring_cells(grid), (slice(0, codes.shape[0]), slice(0, codes.shape[1])))


@dataclass(frozen=True)
class FollowConfig:
    """Pure-pursuit target, arrival tolerances and the safety distance of :func:`choose_action`."""

    lookahead_m: float = 0.8
    goal_tolerance_m: float = 0.25
    yaw_tolerance_rad: float = math.radians(20.0)
    heading_weight_m_per_rad: float = 0.3  # how much a heading error costs against a distance to the target
    robot_radius_m: float = FLIGHT_CLEARANCE.robot_radius_m
    safety_margin_m: float = FLIGHT_CLEARANCE.safety_margin_m  # hard: mean motions keep this beyond the robot radius
    caution_margin_m: float = 0.1  # soft: closer than the robot radius plus this costs escape_weight
    clearance_weight: float = 2.0  # cost per metre that a pose lies closer than comfort_distance_m to an obstacle
    comfort_distance_m: float = 0.5
    escape_weight: float = 20.0  # cost per metre that a pose lies inside the caution margin: get out first
    noise_sigmas: float = 3.0  # preferred first steps keep out of the NON_FLIGHT band under this much motion noise
    # hard: mean motions keep the centre this far from cells the sensor has not seen (0: not checked). The camera
    # sees ±43° ahead, so a turn-and-forward can sweep the body over space it never saw, and a wall may be there.
    unseen_clearance_m: float = FLIGHT_CLEARANCE.robot_radius_m

    def __post_init__(self) -> None:
        if min(self.lookahead_m, self.goal_tolerance_m, self.yaw_tolerance_rad) <= 0:
            raise ValueError("lookahead_m, goal_tolerance_m and yaw_tolerance_rad must be positive")
        weights = (self.heading_weight_m_per_rad, self.clearance_weight, self.escape_weight)
        if (
            min(*weights, self.robot_radius_m, self.safety_margin_m, self.noise_sigmas, self.unseen_clearance_m) < 0
            or self.caution_margin_m < self.safety_margin_m
        ):
            raise ValueError("the weights, robot_radius_m and safety_margin_m must be ≥ 0, caution_margin_m ≥ safety")

    @property
    def safe_distance_m(self) -> float:
        """Closest a mean motion may take the vehicle's centre to an observed obstacle."""
        return self.robot_radius_m + self.safety_margin_m

    @property
    def caution_distance_m(self) -> float:
        """Closer than this to an obstacle the vehicle flies only where the path leads through a narrow passage."""
        return self.robot_radius_m + self.caution_margin_m


@dataclass(frozen=True)
class FreeSpace:
    """Where the vehicle may fly, from an observed high-res code map (one per step, shared with the planners)."""

    grid: GridSpec
    known_free: np.ndarray  # bool: observed FREE
    clearance_m: np.ndarray  # float32: distance between cell centres to the nearest observed OCCUPIED cell
    unseen_clearance_m: np.ndarray  # float32: the same to the nearest UNKNOWN cell
    _codes: np.ndarray = field(repr=False)  # the code map measured (a copy): what the next step's update compares
    _box: tuple[slice, slice] | None = field(repr=False)  # the known cells' box grown by the ring; None: none known

    @classmethod
    def from_codes(cls, codes: np.ndarray, grid: GridSpec, previous: FreeSpace | None = None) -> FreeSpace:
        """Distances as :func:`~edge_explorer.mapping.ego.inflate_codes` measures them (centre to centre), so
        ``clearance_m <= radius`` is exactly its NON_FLIGHT band; an all-free map has infinite clearance.

        Both are measured over the box of the known cells grown by :data:`_EXACT_RING_M` only (maps that are mostly
        unknown — a window on a floor, maps that grow with the flight — cost what their known part costs). Every
        value in that box is the whole map's (to float rounding: opencv's transform differs by about 1e-7 m with the
        array's size; A and C flew step for step as before): all OCCUPIED cells lie in it, and the unknown cell
        nearest to one of its cells is never outside it (the ring is unknown, and clamping a cell outside onto the
        box brings it closer). Outside it every cell is UNKNOWN (unseen clearance 0, exact) and farther than the
        ring from any obstacle: its obstacle clearance reads inf, which no comparison with a distance below the ring
        tells from its true value.

        ``previous``, the free space of the same grid at an earlier step, makes it incremental: a step's scan
        changes a few square metres of a 24 m window, and only the distances within the ring of a changed cell can
        change below the ring, so those alone are measured again, over the changed cells' box grown by twice the
        ring (a distance at most the ring there sees every cell that sets it); the rest is copied. Values at most
        the ring are exact either way; one above it may then stay a larger value above the ring (the same
        contract as the inf outside the box). Without ``previous``, or when the known cells' box changed, it
        measures the whole box."""
        box = _known_box(codes, grid)
        if previous is None or previous.grid != grid or previous._box != box:
            return cls._measured(codes, grid, box)
        changed = codes != previous._codes
        rows, cols = np.flatnonzero(changed.any(axis=1)), np.flatnonzero(changed.any(axis=0))
        clearance, unseen = previous.clearance_m.copy(), previous.unseen_clearance_m.copy()
        if rows.size:
            ring = _ring_cells(grid)
            outer = _grown(rows, cols, 2 * ring + 1, box)
            inner = _grown(rows, cols, ring + 1, box)
            within = tuple(slice(i.start - o.start, i.stop - o.start) for i, o in zip(inner, outer, strict=True))
            part = codes[outer]
            clearance[inner] = centre_clearance_m(part == OCCUPIED, grid.resolution_m)[within]
            unseen[inner] = centre_clearance_m(part == UNKNOWN, grid.resolution_m)[within]
        return cls(grid, codes == FREE, clearance, unseen, codes.copy(), box)

    @classmethod
    def _measured(cls, codes: np.ndarray, grid: GridSpec, box: tuple[slice, slice] | None) -> FreeSpace:
        clearance = np.full(codes.shape, np.inf, dtype=np.float32)
        unseen = np.zeros(codes.shape, dtype=np.float32)
        if box is not None:
            part = codes[box]
            clearance[box] = centre_clearance_m(part == OCCUPIED, grid.resolution_m)
            unseen[box] = centre_clearance_m(part == UNKNOWN, grid.resolution_m)
        return cls(grid, codes == FREE, clearance, unseen, codes.copy(), box)

    def _at(self, values: np.ndarray, x_m: float, y_m: float) -> float:
        row, col = (int(v) for v in self.grid.cell_of(x_m, y_m))
        if not (0 <= row < self.grid.shape[0] and 0 <= col < self.grid.shape[1]):
            return 0.0
        return float(values[row, col])

    def clearance_at(self, x_m: float, y_m: float) -> float:
        """Clearance of the cell holding (x_m, y_m); 0 off the grid."""
        return self._at(self.clearance_m, x_m, y_m)

    def unseen_clearance_at(self, x_m: float, y_m: float) -> float:
        """Distance from the cell holding (x_m, y_m) to the nearest UNKNOWN cell; 0 off the grid."""
        return self._at(self.unseen_clearance_m, x_m, y_m)

    def unsafe_mask(self, x_m: float, y_m: float, safe_distance_m: float, unseen_distance_m: float = 0.0) -> np.ndarray:
        """Cells a motion from (x_m, y_m) may not enter: unknown or occupied, or closer to an obstacle than
        ``safe_distance_m`` (to an unknown cell than ``unseen_distance_m``) — or, if the vehicle is already that
        close, closer than it is now."""
        row, col = (int(v) for v in self.grid.cell_of(x_m, y_m))
        threshold = min(safe_distance_m, self.clearance_at(x_m, y_m))
        unsafe = ~self.known_free | (self.clearance_m < threshold)
        if unseen_distance_m > 0:
            unsafe |= self.unseen_clearance_m < min(unseen_distance_m, self._at(self.unseen_clearance_m, x_m, y_m))
        if 0 <= row < self.grid.shape[0] and 0 <= col < self.grid.shape[1]:
            unsafe[row, col] = False  # where it is now: it must be able to leave
        return unsafe


def _project(path_xy_m: np.ndarray, xy_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Where ``xy_m`` lies along the polyline: (segment lengths, cumulative length at each vertex, arc length of
    the polyline point nearest to ``xy_m``, distance to that point)."""
    a, b = path_xy_m[:-1], path_xy_m[1:]
    seg = b - a
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    t = np.clip(np.einsum("ij,ij->i", xy_m - a, seg) / np.maximum(seg_len**2, 1e-12), 0.0, 1.0)
    nearest = a + t[:, None] * seg
    gaps = np.hypot(*(nearest - xy_m).T)
    k = int(np.argmin(gaps))
    cumulative = np.concatenate([[0.0], np.cumsum(seg_len)])
    return seg_len, cumulative, float(cumulative[k] + t[k] * seg_len[k]), float(gaps[k])


def remaining_path_m(path_xy_m: np.ndarray, xy_m: tuple[float, float] | np.ndarray) -> float:
    """How far the vehicle at ``xy_m`` still has to fly along the polyline: the distance to the nearest point of
    it plus the polyline's length from there to its end. Progress along a path that winds away from its end
    (around a wall, through another room) shrinks this, where the straight-line distance to the end would grow."""
    path = np.asarray(path_xy_m, dtype=np.float64).reshape(-1, 2)
    xy = np.asarray(xy_m, dtype=np.float64)
    if len(path) == 1:
        return float(np.hypot(*(path[0] - xy)))
    _, cumulative, s, gap = _project(path, xy)
    return gap + float(cumulative[-1]) - s


def _pursuit_target(path_xy_m: np.ndarray, xy_m: np.ndarray, lookahead_m: float) -> np.ndarray:
    """Point ``lookahead_m`` along the polyline beyond the point of the polyline nearest to ``xy_m``."""
    if len(path_xy_m) == 1:
        return path_xy_m[0]
    seg_len, cumulative, s, _ = _project(path_xy_m, xy_m)
    s_target = s + lookahead_m
    if s_target >= cumulative[-1]:
        return path_xy_m[-1]
    j = int(np.searchsorted(cumulative, s_target, side="right")) - 1
    u = (s_target - cumulative[j]) / max(seg_len[j], 1e-12)
    return path_xy_m[j] + u * (path_xy_m[j + 1] - path_xy_m[j])


def _pose_cost(pose: Pose, target_xy_m: np.ndarray, final_yaw_rad: float | None, config: FollowConfig) -> float:
    """Distance to the target plus the heading error towards it and, if ``final_yaw_rad`` is given, the turn from
    that bearing to it (towards ``final_yaw_rad`` alone once there). Counting the final turn before arrival too
    keeps arriving facing the wrong way cheaper than hovering short of the end. The caller passes
    ``final_yaw_rad`` only when the target is the path's end: a target part-way along the path (near a bend) says
    nothing about the final heading. The caller adds the clearance term."""
    dx, dy = target_xy_m[0] - pose[0], target_xy_m[1] - pose[1]
    distance = math.hypot(dx, dy)
    if distance > config.goal_tolerance_m:
        bearing = math.atan2(dy, dx)
        yaw_error = abs(wrap_angle_rad(bearing - pose[2]))
        if final_yaw_rad is not None:  # the turn still to come on arrival: staying away does not save it
            yaw_error += abs(wrap_angle_rad(final_yaw_rad - bearing))
    elif final_yaw_rad is not None:
        yaw_error = abs(wrap_angle_rad(final_yaw_rad - pose[2]))
    else:
        yaw_error = 0.0
    return distance + config.heading_weight_m_per_rad * yaw_error


def arrived(pose: Pose, path_xy_m: np.ndarray, final_yaw_rad: float | None, config: FollowConfig) -> bool:
    """At the path's end within the tolerance, facing ``final_yaw_rad`` (if given) within the yaw tolerance."""
    end = path_xy_m[-1]
    if math.hypot(end[0] - pose[0], end[1] - pose[1]) > config.goal_tolerance_m:
        return False
    return final_yaw_rad is None or abs(wrap_angle_rad(final_yaw_rad - pose[2])) <= config.yaw_tolerance_rad


def choose_action(
    table: ActionTable,
    pose: Pose,
    previous_action: int,
    path_xy_m: np.ndarray,
    free: FreeSpace,
    config: FollowConfig = FollowConfig(),
    final_yaw_rad: float | None = None,
    blocked_actions: frozenset[int] = frozenset(),
    hovers: int = 0,
) -> int | None:
    """The action that best advances along ``path_xy_m`` ((N, 2) metres, from near the vehicle to the goal).

    Returns ``None`` once the vehicle has :func:`arrived`. Among the two-action sequences whose mean motions are
    safe (see the module docstring) it picks the first action of the one with the lowest summed pursuit cost of its
    two poses, preferring sequences whose first step is robust to motion noise. Hover
    when no sequence is safe (a state the follower's own choices never lead to). ``blocked_actions`` are first
    actions known to be blocked from this very pose (a collision the map does not explain: the caller's memory).
    ``hovers``: how many times in a row the vehicle has hovered; a hover's noise counts as that many more hovers'
    (module docstring).
    """
    path = np.asarray(path_xy_m, dtype=np.float64).reshape(-1, 2)
    if arrived(pose, path, final_yaw_rad, config):
        return None
    target = _pursuit_target(path, np.array(pose[:2]), config.lookahead_m)
    target_yaw_rad = final_yaw_rad if np.array_equal(target, path[-1]) else None
    unsafe = free.unsafe_mask(pose[0], pose[1], config.safe_distance_m, config.unseen_clearance_m)
    band = free.unsafe_mask(pose[0], pose[1], config.robot_radius_m + _BAND_EPS_M)  # the observed NON_FLIGHT band

    def safe_step(start: Pose, previous: int, action: int) -> Pose | None:
        end = body_to_map(*start, *table.mean_step(previous, action))
        brake = body_to_map(*end, *table.mean_step(action, Action.HOVER))
        for a, b in ((start, end), (end, brake)):
            if (a[0], a[1]) != (b[0], b[1]) and swept_path_blocked(unsafe, free.grid, a[:2], b[:2]):
                return None
        return end

    def within_noise(action: int, end: Pose, sigmas: float) -> bool:
        """The first step stays out of the band for every end ``sigmas`` standard deviations of its own and the
        following drift's noise away from the mean (the drift shifted with it)."""
        std_m = math.hypot(table.pos_std_m[previous_action, action], table.pos_std_m[action, Action.HOVER])
        if action == Action.HOVER:
            std_m *= math.sqrt(1 + hovers)  # the drift of the hovers still to come (module docstring)
        brake = body_to_map(*end, *table.mean_step(action, Action.HOVER))
        for dx, dy in sigmas * std_m * _DIRECTIONS:
            shifted = (end[0] + dx, end[1] + dy)
            drift = (brake[0] + dx, brake[1] + dy)
            if swept_path_blocked(band, free.grid, pose[:2], shifted) or swept_path_blocked(
                band, free.grid, shifted, drift
            ):
                return False
        return True

    def robustness(action: int, end: Pose | None) -> float:
        """How many standard deviations of motion noise ``action``'s first step keeps out of the band: the
        largest rung of the ladder from ``noise_sigmas`` down to 0 that holds, -0.5 if even its mean motion enters
        the band, -1 if it is not mean-safe."""
        if end is None:
            return -1.0
        for fraction in _LADDER:
            if within_noise(action, end, fraction * config.noise_sigmas):
                return fraction * config.noise_sigmas
        return -0.5

    first = {a: None if a in blocked_actions else safe_step(pose, previous_action, a) for a in range(NUM_ACTIONS)}
    robust_first = {a: robustness(a, end) for a, end in first.items()}
    best_action, best_cost = int(Action.HOVER), math.inf
    best_robust = -1.0
    for a1, a2 in product(range(NUM_ACTIONS), repeat=2):
        p1 = first[a1]
        p2 = safe_step(p1, a1, a2) if p1 is not None else None
        if p2 is None:
            continue
        # Both poses count, so progress now beats the same progress later (no waiting for a better next step);
        # hover costs a little extra so that an equally good motion wins.
        cost = 1e-3 if a1 == Action.HOVER else 0.0
        for p in (p1, p2):  # and keep off the walls where there is room: motion noise then cannot reach them
            cost += _pose_cost(p, target, target_yaw_rad, config)
            clearance = free.clearance_at(p[0], p[1])
            cost += config.clearance_weight * max(0.0, config.comfort_distance_m - clearance)
            cost += config.escape_weight * max(0.0, config.caution_distance_m - clearance)
        if (robust_first[a1], -cost) > (best_robust, -best_cost):
            best_action, best_cost, best_robust = a1, cost, robust_first[a1]
    return best_action
