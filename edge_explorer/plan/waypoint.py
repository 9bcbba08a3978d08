"""Action → waypoint, and the safety check every waypoint passes before the daemon flies it (docs/design.md §8).

**Waypoint.** An action moves the vehicle by the shared action table's mean motion for (previous action, action)
(:mod:`edge_explorer.vehicle.dynamics`, momentum included), from the pose the step starts at — the same motion the
simulator trained the policy with. The trajectory reaches the waypoint after one step period at the action's
*cruise* velocity (:func:`cruise_velocity`), so consecutive steps join as the table's vehicle model assumes.

**Safety.** A waypoint is flown only if the straight motion from where the vehicle is (its odometry position) to the
waypoint, and the drift of braking there (hover after the action, also from the table), stay on cells that are

* observed FREE — **unknown space is not allowed**: the vehicle only flies where its camera has looked (the camera
  looks along the direction of travel, so forward motions land in seen space; the frontier planner's follower uses
  the same rule, so the fallback never proposes what this check refuses), and
* at least ``safe_distance_m`` from every observed OCCUPIED cell — the robot radius plus the follower's margin, so
  strictly outside the NON_FLIGHT band of the inflated 0.05 m map (the band is the cells within the robot radius).

The map is :class:`~edge_explorer.plan.follow.FreeSpace` and the test its ``unsafe_mask`` with
:func:`~edge_explorer.vehicle.dynamics.swept_path_blocked`: one definition of "safe" for the follower and the daemon.
If the vehicle already stands closer to an obstacle than ``safe_distance_m`` (sensor noise, a gust), motions that
do not bring it closer remain allowed, so it can fly out.

**Fallback.** :meth:`WaypointPlanner.first_safe` takes candidate actions in order of preference (the policy's, the
frontier planner's, hover) and returns the first safe one; when none is, it returns a *hold* — the current odometry
position at rest, which is always allowed.

**Going home.** :func:`path_home` plans the way back to the take-off point over the frontier planner's planning
graph (observed free cells only); the daemon follows it with the six actions through the shared follower.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from edge_explorer.plan.follow import FollowConfig, FreeSpace, Pose
from edge_explorer.plan.graph import GraphConfig, PlanningGraph
from edge_explorer.vehicle.dynamics import Action, ActionTable, body_to_map, swept_path_blocked

HOLD = "hold"  # the source of a waypoint that keeps the vehicle where it is


@dataclass(frozen=True)
class Waypoint:
    """Where one step ends: the map-frame pose and the velocity to arrive with (``(vx, vy, yaw rate)``).

    ``action`` is the action whose motion this is (HOVER for a hold); ``source`` says who chose it (``policy``,
    ``frontier``, ``home``, ``hover`` or ``hold``).
    """

    x_m: float
    y_m: float
    yaw_rad: float
    velocity: tuple[float, float, float]
    action: int
    source: str


def action_pose(table: ActionTable, start: Pose, previous_action: int, action: int) -> Pose:
    """The pose ``action`` reaches from ``start`` after ``previous_action``: the table's mean motion, in the map."""
    return body_to_map(*start, *table.mean_step(previous_action, action))


def cruise_velocity(table: ActionTable, action: int, yaw_rad: float) -> tuple[float, float, float]:
    """(vx, vy, yaw rate) the vehicle carries at the end of ``action`` when facing ``yaw_rad``.

    It is the action's steady state: the table's motion for the action repeated, (action, action), per step
    period — 0.5 m/s along the heading for the forward actions, ±30°/s for the turns, nothing for hover.
    """
    dx, dy, dyaw = table.mean_step(action, action)
    step_s = table.model.step_s
    speed = math.hypot(dx, dy) / step_s
    return speed * math.cos(yaw_rad), speed * math.sin(yaw_rad), dyaw / step_s


@dataclass(frozen=True)
class WaypointPlanner:
    """Turns actions into safe waypoints over one step's observed high-res map (see the module docstring)."""

    table: ActionTable
    free: FreeSpace
    safe_distance_m: float = FollowConfig().safe_distance_m

    def is_safe(self, from_xy_m: tuple[float, float], pose: Pose, previous_action: int, action: int) -> bool:
        """Whether flying ``action`` from the step-start ``pose`` is safe for a vehicle now at ``from_xy_m``.

        Checked: the straight motion from ``from_xy_m`` to the action's end, and the braking drift after it.
        """
        return self._clear(self._unsafe(from_xy_m), from_xy_m, pose, previous_action, action)

    def _unsafe(self, from_xy_m: tuple[float, float]) -> np.ndarray:
        return self.free.unsafe_mask(from_xy_m[0], from_xy_m[1], self.safe_distance_m)

    def _clear(
        self, unsafe: np.ndarray, from_xy_m: tuple[float, float], pose: Pose, previous_action: int, action: int
    ) -> bool:
        end = action_pose(self.table, pose, previous_action, action)
        brake = action_pose(self.table, end, action, Action.HOVER)
        for a, b in ((tuple(from_xy_m), end[:2]), (end[:2], brake[:2])):
            if a != b and swept_path_blocked(unsafe, self.free.grid, a, b):
                return False
        return True

    def waypoint(self, pose: Pose, previous_action: int, action: int, source: str) -> Waypoint:
        """The waypoint of ``action`` from the step-start ``pose`` (no safety check: see :meth:`first_safe`)."""
        x, y, yaw = action_pose(self.table, pose, previous_action, action)
        return Waypoint(x, y, yaw, cruise_velocity(self.table, action, yaw), int(action), source)

    def first_safe(
        self,
        from_xy_m: tuple[float, float],
        pose: Pose,
        previous_action: int,
        candidates: Iterable[tuple[str, int | None]],
    ) -> Waypoint:
        """The first safe waypoint among ``candidates`` — (source, action) pairs, best first, evaluated lazily so
        a fallback is only computed when needed; a ``None`` action is skipped. A hold at ``from_xy_m`` (facing
        ``pose``'s heading) when none is safe."""
        unsafe = self._unsafe(from_xy_m)
        for source, action in candidates:
            if action is not None and self._clear(unsafe, from_xy_m, pose, previous_action, action):
                return self.waypoint(pose, previous_action, action, source)
        return hold_waypoint((from_xy_m[0], from_xy_m[1], pose[2]))


def hold_waypoint(pose: Pose) -> Waypoint:
    """Stay at ``pose``, at rest."""
    return Waypoint(pose[0], pose[1], pose[2], (0.0, 0.0, 0.0), int(Action.HOVER), HOLD)


def path_home(
    free: FreeSpace,
    from_xy_m: tuple[float, float],
    home_xy_m: tuple[float, float],
    safe_distance_m: float,
    unseen_distance_m: float = FollowConfig().unseen_clearance_m,
    boxed_in_distance_m: float = FollowConfig().robot_radius_m,
) -> np.ndarray | None:
    """(K, 2) path from ``from_xy_m`` to the reachable planning cell nearest ``home_xy_m``, through observed free
    space at least ``safe_distance_m`` from obstacles and ``unseen_distance_m`` from unknown cells — the follower's
    own rules, so that :func:`~edge_explorer.plan.follow.choose_action` can fly it: a path grazing a small unseen
    patch in the middle of a corridor put the pursuit target behind a patch the follower will not cross, and hover
    won (the whole-floor daemon flight of session 43 hovered there until its return time ran out). ``None`` if the
    vehicle's own cell has no way out.

    **Boxed in.** A planning cell needs *all* its 0.05 m cells ``safe_distance_m`` clear, the follower only the
    cells it flies over. In a gap narrower than twice the safe distance the clearest 0.05 m cells across it can be
    exactly ``safe_distance_m`` clear and straddle two planning cells, each then a cell short: one sensor-noise hit
    on a 0.7 m gap's edge left the whole-floor daemon flight of session 45 no planning cell around its own (the
    escape rule did not apply: the vehicle stood exactly ``safe_distance_m`` clear) while the follower could fly
    out. Only when the vehicle's cell reaches no other cell is the path planned again with planning cells
    ``boxed_in_distance_m`` clear (the robot radius: no cell of the path closer to an obstacle); the follower still
    flies only by its own rules."""
    graph, start, cost, predecessors = _search_from(free, from_xy_m, safe_distance_m, unseen_distance_m)
    if start < 0:
        return None
    if np.isfinite(cost[0]).sum() == 1 and boxed_in_distance_m < safe_distance_m:
        graph, start, cost, predecessors = _search_from(free, from_xy_m, boxed_in_distance_m, unseen_distance_m)
    reachable = np.flatnonzero(np.isfinite(cost[0]))
    xy = graph.node_xy_m(reachable)
    goal = int(reachable[np.argmin(np.hypot(xy[:, 0] - home_xy_m[0], xy[:, 1] - home_xy_m[1]))])
    return graph.path_xy_m(predecessors[0], goal)


def _search_from(
    free: FreeSpace, from_xy_m: tuple[float, float], safe_distance_m: float, unseen_distance_m: float
) -> tuple[PlanningGraph, int, np.ndarray, np.ndarray]:
    """(graph, the vehicle's node, cost, predecessors) of :func:`path_home`'s search; node −1 (and no search)
    where the vehicle's cell is off the graph."""
    graph = PlanningGraph.build(free, safe_distance_m, from_xy_m, GraphConfig(), unseen_distance_m)
    start = graph.node_at(*from_xy_m)
    if start < 0:
        return graph, start, np.empty((1, 0)), np.empty((1, 0), dtype=np.int32)
    cost, predecessors = graph.search([start])
    return graph, start, cost, predecessors
