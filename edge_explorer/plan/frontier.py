"""Frontiers, the shared goal-planner loop and the Nearest Frontier baseline (Yamauchi 1997).

Frontier (:func:`frontier_mask`): a FREE cell with an UNKNOWN 8-neighbour. The planners look for frontiers on the
0.20 m observed map, the grid coverage is counted on (docs/design.md §7): a coarse cell is known as soon as one of its
0.05 m cells is, so every frontier there borders cells whose observation raises coverage, and the unknown specks
of the fine map that do not count (a ray's grazing gap, the inside of a wall) are no targets.

The planning graph the goals are searched on: :mod:`edge_explorer.plan.graph`.

Nearest Frontier (:class:`NearestFrontier`): go to the traversable cell within ``goal_radius_m`` of a frontier
that is nearest along the graph, then face the frontier. The shared :class:`GoalPlanner` loop flies the path with
:func:`~edge_explorer.plan.follow.choose_action` and replans when the target is no longer a frontier (seen), when
the path became untraversable; a goal *fails* when the vehicle reached and faced its target and it is still a
frontier, or when the vehicle stalls (no 5 cm of progress along the path — not towards its end: a path around a
wall first leads away from it — for ``stall_steps``, or hovering because no safe motion gets it closer). A target
that fails on arrival cannot be seen from where the graph leads and is dropped. A vehicle that stalls still far
along the path has not shown that: the follower could not thread a passage (a door between noise-thickened jambs)
from the way it came. It backs off to the most open spot 0.8–2 m away and tries again, up to twice until some
target is seen, before the target is dropped.
With no reachable frontier left the vehicle first turns a full circle in place (it may have seen too little, e.g. at
the start), then reports that it is done.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cached_property

import cv2
import numpy as np
from scipy import ndimage

from edge_explorer.mapping.observed import ObservedMaps
from edge_explorer.plan.follow import FollowConfig, FreeSpace, Pose, choose_action, remaining_path_m
from edge_explorer.plan.graph import GraphConfig, PlanningGraph, Traversable
from edge_explorer.vehicle.dynamics import Action, ActionTable, load_action_table
from edge_explorer.world.grid import FREE, UNKNOWN, GridSpec, resolution_factor

_FULL_TURN_STEPS = 12  # 12 × 30°
_MAX_HOVERS = 3  # hovers in a row after which the follower counts as stuck
_MAX_HOVER_RUN = 6  # hovers in a row over any goals after which a vehicle next to a wall backs off into the open
_NEARBY_M = 4.0  # graph cost within which the nearest-frontier search looks first
_FAR_M = 1.0  # a goal that stalls with more path than this left to fly was not failed by its target …
_MAX_RETREATS = 2  # … so the vehicle backs off (this many times until a target is seen) and tries again …
_RETREAT_MIN_M, _RETREAT_MAX_M = 0.8, 2.0  # … to the most open spot this far away along the graph
_DETOUR_M = 0.5  # a replanned path this much longer than the old one's remainder restarts the stall detection


def frontier_mask(codes: np.ndarray) -> np.ndarray:
    """FREE cells with at least one UNKNOWN 8-neighbour (cells beyond the array edge do not count)."""
    unknown = (codes == UNKNOWN).astype(np.uint8)
    near_unknown = cv2.dilate(unknown, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return (codes == FREE) & near_unknown.astype(bool)


def frontier_clusters(
    frontier: np.ndarray, grid: GridSpec, max_radius_m: float, min_cells: int = 1
) -> list[np.ndarray]:
    """Flat indices of each cluster of ``frontier`` cells (bool on ``grid``), split as the module docstring says;
    connected components of fewer than ``min_cells`` cells are left out."""
    labels, count = ndimage.label(frontier, structure=np.ones((3, 3), dtype=bool))
    flat_labels = labels.ravel()
    order = np.argsort(flat_labels, kind="stable")
    bounds = np.searchsorted(flat_labels[order], np.arange(1, count + 2))
    clusters: list[np.ndarray] = []
    for k in range(count):
        cells = order[bounds[k] : bounds[k + 1]]
        if len(cells) < min_cells:
            continue
        x, y = grid.center_of(*np.divmod(cells, grid.shape[1]))
        clusters.extend(_split(cells, np.stack([x, y], axis=1), max_radius_m))
    return clusters


def _split(cells: np.ndarray, xy_m: np.ndarray, max_radius_m: float) -> list[np.ndarray]:
    centred = xy_m - xy_m.mean(axis=0)
    if len(cells) < 2 or np.hypot(centred[:, 0], centred[:, 1]).max() <= max_radius_m:
        return [cells]
    _, vectors = np.linalg.eigh(centred.T @ centred)
    side = centred @ vectors[:, -1] >= 0  # principal axis: the eigenvector of the largest eigenvalue
    return _split(cells[side], xy_m[side], max_radius_m) + _split(cells[~side], xy_m[~side], max_radius_m)


@dataclass(frozen=True)
class PlannerConfig:
    """Settings the frontier planners share."""

    follow: FollowConfig = FollowConfig()
    graph: GraphConfig = GraphConfig()
    goal_radius_m: float = 0.5  # a goal cell lies this close to its frontier
    stall_steps: int = 12  # a goal fails after this many steps without getting 5 cm closer along its path

    def __post_init__(self) -> None:
        if self.goal_radius_m <= 0 or self.stall_steps < 1:
            raise ValueError("goal_radius_m must be positive and stall_steps ≥ 1")


@dataclass
class Goal:
    """Where the vehicle is flying and why: the path, the heading to take at its end and the target cells.

    ``target_cells`` are flat indices of 0.20 m cells; the goal is achieved once too few of them are frontiers
    (all of them gone for a single cell, ``done_fraction`` of them for a cluster). A goal whose vehicle arrives
    (or gets stuck) with the target still a frontier *fails*: see :meth:`GoalPlanner.on_failure`.
    """

    path_xy_m: np.ndarray
    yaw_rad: float
    target_cells: np.ndarray
    done_fraction: float = 1.0
    best_remaining_m: float = math.inf  # progress bookkeeping: least path left to fly (remaining_path_m) …
    steps_since_progress: int = 0  # … steps since it last improved by 5 cm …
    hovers: int = 0  # … and hovers in a row (the follower's answer when it cannot get closer)
    retreat: bool = False  # a back-off into open space after getting stuck on the way to ``target_cells``

    def inherit_progress(self, previous: Goal | None) -> None:
        """Keep the progress bookkeeping of ``previous`` if it led to the same place by about the same way (a
        replan that changed nothing must not reset the stall detection; a detour the map now demands must)."""
        if (
            previous is not None
            and np.hypot(*(previous.path_xy_m[-1] - self.path_xy_m[-1])) < 0.15
            and remaining_path_m(self.path_xy_m, self.path_xy_m[0]) <= previous.best_remaining_m + _DETOUR_M
        ):
            self.best_remaining_m = previous.best_remaining_m
            self.steps_since_progress = previous.steps_since_progress
            self.hovers = previous.hovers

    def on_grid(self, old: GridSpec, new: GridSpec) -> Goal | None:
        """This goal with its target cells (indices on ``old``) re-indexed on ``new``, a grid of the same
        resolution whose cells line up with ``old``'s (a moved window); ``None`` when a target cell lies off
        ``new``. The path is in metres and carries over as it is."""
        rows, cols = np.divmod(self.target_cells, old.shape[1])
        rows = rows + int(round((old.origin_xy[1] - new.origin_xy[1]) / new.resolution_m))
        cols = cols + int(round((old.origin_xy[0] - new.origin_xy[0]) / new.resolution_m))
        if not new.contains(rows, cols).all():
            return None
        return replace(self, target_cells=rows * new.shape[1] + cols)


class View:
    """What a planner derives from the observed maps at one step; the graph is built only if a planner asks."""

    def __init__(
        self,
        maps: ObservedMaps,
        pose: Pose,
        frontier: np.ndarray,
        config: PlannerConfig,
        previous_free: FreeSpace | None = None,
    ) -> None:
        """``previous_free``: the free space of an earlier step's view, updated where the map changed since (see
        :meth:`FreeSpace.from_codes`)."""
        self.maps = maps
        self.frontier = frontier  # bool on the 0.20 m grid, dropped targets removed
        self.free = FreeSpace.from_codes(maps.high, maps.high_grid, previous_free)
        self.traversable = Traversable.from_free_space(
            self.free, config.follow.safe_distance_m, pose[:2], config.graph.factor
        )
        self._graph_config = config.graph

    @cached_property
    def graph(self) -> PlanningGraph:
        return PlanningGraph.from_traversable(self.traversable, self._graph_config)


class GoalPlanner:
    """The loop both frontier planners share: keep a :class:`Goal`, follow it, replan on events.

    Subclasses implement :meth:`select_goal`. :meth:`act` returns the next action id, or ``None`` when no
    frontier is reachable any more (exploration is over for this planner).
    """

    def __init__(self, config: PlannerConfig = PlannerConfig(), table: ActionTable | None = None) -> None:
        self.config = config
        self.table = table if table is not None else load_action_table()
        self.replans = 0
        self._goal: Goal | None = None
        self._dropped: np.ndarray | None = None  # bool on the 0.20 m grid
        self._spin_steps_left: int | None = None  # None: not spinning
        self._retreats_left = _MAX_RETREATS
        self._hover_run = 0  # hovers in a row, whatever the goal
        self._last_targets: np.ndarray | None = None  # target cells of the latest goal
        self._last_command: tuple[Pose, int] | None = None  # the pose of the latest call and the action returned
        self._blocked: dict[Pose, set[int]] = {}  # actions that collided from exactly this pose (see act)
        self._free: FreeSpace | None = None  # the latest view's free space, which the next view updates

    def reset(self) -> None:
        """Forget the goal, the dropped targets and the blocked motions (a new flight)."""
        self._goal = None
        self._dropped = None
        self._spin_steps_left = None
        self._retreats_left = _MAX_RETREATS
        self._hover_run = 0
        self._last_targets = None
        self._last_command = None
        self._blocked = {}
        self._free = None
        self.replans = 0

    def select_goal(self, view: View, pose: Pose) -> Goal | None:  # pragma: no cover - abstract
        raise NotImplementedError

    def on_whole_floor(self) -> None:
        """Called by the planning hierarchy (:mod:`edge_explorer.plan.window`) when the maps outgrow its window, so
        a planner tuned on small buildings can take its whole-floor settings for the rest of the flight (until
        :meth:`reset`). The frontier planners have none."""

    def view(self, maps: ObservedMaps, pose: Pose, fused_low: np.ndarray | None = None) -> View:
        """This step's free space, traversable cells and frontier (less the dropped targets). The frontier planners
        target the observed map's frontier and ignore ``fused_low``; a predictive planner overrides this."""
        return View(maps, pose, frontier_mask(maps.low) & ~self.dropped(maps), self.config, self._free)

    def dropped(self, maps: ObservedMaps) -> np.ndarray:
        """The targets dropped this flight (bool on the 0.20 m grid), reset when the map's shape changes."""
        if self._dropped is None or self._dropped.shape != maps.low.shape:
            self._dropped = np.zeros(maps.low.shape, dtype=bool)
        return self._dropped

    def memory(self) -> dict[str, np.ndarray]:
        """What the planner remembers on the 0.20 m grid across steps, as bool masks of the map's shape (the dropped
        targets); a planner that flies a moving window of the maps (:mod:`edge_explorer.plan.window`) carries them
        over when the window moves."""
        return {} if self._dropped is None else {"dropped": self._dropped}

    def goal_on(self, old: GridSpec, new: GridSpec) -> Goal | None:
        """The goal being flown with its target cells on ``new`` (:meth:`Goal.on_grid`), for :meth:`remember`;
        ``None`` when there is none or it does not carry over."""
        return None if self._goal is None else self._goal.on_grid(old, new)

    def remember(self, memory: dict[str, np.ndarray], goal: Goal | None = None) -> None:
        """Take ``memory`` (:meth:`memory`'s masks on the grid of the next maps) and ``goal`` (:meth:`goal_on`'s
        answer on that grid; ``None``: replan at the next step)."""
        self._dropped = memory.get("dropped")
        self._goal = goal
        self._last_targets = None if goal is None else goal.target_cells

    def targets(self, low: np.ndarray, fused_low: np.ndarray | None) -> np.ndarray:
        """bool, ``low``'s shape: the cells this planner explores towards on the observed 0.20 m map ``low`` (and
        the fused one): the frontier. The hierarchy's global layer looks for them beyond its window."""
        return frontier_mask(low)

    def act(
        self, maps: ObservedMaps, pose: Pose, previous_action: int, fused_low: np.ndarray | None = None
    ) -> int | None:
        """The next action at ``pose``, given the motion the vehicle carries into this step (``previous_action``:
        HOVER after a collision, which stops the vehicle where it was).

        A motion answered by HOVER at exactly the same pose was not flown from there: in the simulator it collided
        with something the observed map does not show (a wall the sensor has not seen yet can lie within the robot
        radius of cells it saw free); in the daemon its safety check replaced it by hover. The same map would choose
        the same motion again, step after step (in the simulator a vehicle pinned against a wall: 43 collisions in
        one val flight), so that action is blocked from that exact pose until the vehicle moves."""
        pose = (float(pose[0]), float(pose[1]), float(pose[2]))
        if self._last_command is not None:
            last_pose, last_action = self._last_command
            if last_action != Action.HOVER and previous_action == Action.HOVER and pose == last_pose:
                self._blocked.setdefault(pose, set()).add(last_action)
        view = self.view(maps, pose, fused_low)
        self._free = view.free
        action = self._act(view, pose, previous_action)
        self._hover_run = self._hover_run + 1 if action == Action.HOVER else 0
        self._last_command = None if action is None else (pose, action)
        return action

    def _act(self, view: View, pose: Pose, previous_action: int) -> int | None:
        near_wall = view.free.clearance_at(*pose[:2]) < self.config.follow.caution_distance_m
        if self._hover_run >= _MAX_HOVER_RUN and near_wall and self._last_targets is not None:
            # goal after goal hovers at once (each new goal restarts its own count) next to a wall, where no motion
            # towards them is safe: hovering there lets the drift reach the wall, so back off into open space first
            stuck = Goal(np.array([pose[:2]]), pose[2], self._last_targets, 1.0)
            if self._goal is None or not self._goal.retreat:
                self._goal = retreat_goal(view, pose, stuck) or self._goal
            self._hover_run = 0
        for _ in range(3):  # a new goal may fail at once (reached, target unseen): then take the next one
            goal = self._goal
            status = "replan" if goal is None else self.status(goal, view, pose)
            if status == "failed":
                assert goal is not None
                self._goal = self._handle_failure(goal, view, pose, arrived=False)
                status = "replan" if self._goal is None else "ok"
            if status == "replan":
                self.replans += 1
                self._goal = self.select_goal(view, pose)
                if self._goal is None:
                    break
                self._goal.inherit_progress(goal)
            goal = self._goal
            assert goal is not None
            self._last_targets = goal.target_cells
            action = choose_action(
                self.table,
                pose,
                previous_action,
                goal.path_xy_m,
                view.free,
                self.config.follow,
                goal.yaw_rad,
                frozenset(self._blocked.get(pose, ())),
                hovers=self._hover_run,  # a vehicle that keeps hovering drifts (plan/follow.py)
            )
            goal.hovers = goal.hovers + 1 if action == Action.HOVER else 0
            if action is not None and goal.hovers <= _MAX_HOVERS:
                self._spin_steps_left = None
                return action
            # arrived or stuck, and the target is still a frontier
            self._goal = self._handle_failure(goal, view, pose, arrived=action is None)
        return self._spin(view, pose, previous_action)

    def status(self, goal: Goal, view: View, pose: Pose) -> str:
        """``"ok"`` to keep flying ``goal``, ``"replan"`` (target seen, path blocked) or ``"failed"`` (stalled)."""
        if view.frontier.flat[goal.target_cells].mean() <= 1.0 - goal.done_fraction:
            self._retreats_left = _MAX_RETREATS  # a target seen: the follower may back off again
            return "replan"
        if not view.traversable.contains_path(goal.path_xy_m):
            return "replan"
        remaining = remaining_path_m(goal.path_xy_m, pose[:2])
        if remaining < goal.best_remaining_m - 0.05:
            goal.best_remaining_m, goal.steps_since_progress = remaining, 0
        else:
            goal.steps_since_progress += 1
        return "failed" if goal.steps_since_progress > self.config.stall_steps else "ok"

    def _handle_failure(self, goal: Goal, view: View, pose: Pose, arrived: bool) -> Goal | None:
        """The next goal after ``goal`` ended without its target seen. A back-off goal just ends (replan from
        where it got to). A vehicle that got stuck still far along the path from its goal — the follower failed
        to thread a passage from the way it came, which says nothing about the target — backs off into open space
        and tries again (:data:`_MAX_RETREATS` times until some target is seen); otherwise :meth:`on_failure`. A
        goal the follower got stuck on is first reported to :meth:`on_stuck`."""
        if goal.retreat:
            return None
        if not arrived:
            self.on_stuck(goal, view, pose)
        if not arrived and self._retreats_left > 0 and remaining_path_m(goal.path_xy_m, pose[:2]) > _FAR_M:
            retreat = retreat_goal(view, pose, goal)
            if retreat is not None:
                self._retreats_left -= 1
                return retreat
        return self.on_failure(goal, view, pose)

    def on_stuck(self, goal: Goal, view: View, pose: Pose) -> None:
        """``goal`` failed with the vehicle short of its end: the follower found no safe motion on (it hovered) or
        made no progress. Nothing here; the learned planner counts these (a stuck spot)."""

    def on_failure(self, goal: Goal, view: View, pose: Pose) -> Goal | None:
        """What to do when ``goal`` failed: drop its target (it cannot be seen from where the graph leads) and
        return the next goal, or ``None`` to select one."""
        self._drop(goal, view)
        return None

    def _drop(self, goal: Goal, view: View) -> None:
        """Stop targeting the goal's cells and the frontier cells next to them (seen from nowhere reachable)."""
        assert self._dropped is not None
        targets = np.zeros(view.frontier.shape, dtype=np.uint8)
        targets.flat[goal.target_cells] = 1
        near = cv2.dilate(targets, np.ones((3, 3), np.uint8)).astype(bool)
        self._dropped |= near & view.frontier

    def _spin(self, view: View, pose: Pose, previous_action: int) -> int | None:
        """Turn a full circle in place (12 turns of 30°) before declaring that nothing is left to explore."""
        if self._spin_steps_left is None:
            self._spin_steps_left = _FULL_TURN_STEPS
        if self._spin_steps_left == 0:
            return None  # stays done until a goal shows up again
        self._spin_steps_left -= 1
        here = np.array([pose[:2]])
        action = choose_action(
            self.table,
            pose,
            previous_action,
            here,
            view.free,
            self.config.follow,
            pose[2] + math.pi / 2,
            frozenset(self._blocked.get(pose, ())),
        )
        return 0 if action is None else action


def goal_candidates(view: View, frontier: np.ndarray, goal_radius_m: float) -> np.ndarray:
    """Node ids whose planning cell lies within ``goal_radius_m`` of a cell of ``frontier`` (0.20 m grid)."""
    graph, low_grid = view.graph, view.maps.low_grid
    up = resolution_factor(graph.grid.resolution_m, low_grid.resolution_m)
    fine = np.repeat(np.repeat(frontier, up, axis=0), up, axis=1)[: graph.grid.shape[0], : graph.grid.shape[1]]
    radius = int(math.floor(goal_radius_m / graph.grid.resolution_m))
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    near = cv2.dilate(fine.astype(np.uint8), disk, borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    nodes = graph.node_of[near]
    return nodes[nodes >= 0]


def cluster_handover(view: View, pose: Pose, goal: Goal, goal_radius_m: float) -> Goal | None:
    """After a goal at a frontier *cluster* (``done_fraction`` < 1) was reached without showing enough of it: the
    nearest of the cluster's cells that are still frontier, as a single-cell goal (whose own failure drops it);
    ``None`` for a single-cell goal or when none of the cluster's cells is reachable."""
    if goal.done_fraction >= 1.0:
        return None
    remaining = np.zeros(view.frontier.shape, dtype=bool)
    remaining.flat[goal.target_cells] = True
    return nearest_frontier_goal(view, pose, remaining & view.frontier, goal_radius_m)


def retreat_goal(view: View, pose: Pose, stuck: Goal) -> Goal | None:
    """Back-off goal for a vehicle stuck on the way to ``stuck``: the graph node with the most clearance among
    those :data:`_RETREAT_MIN_M` to :data:`_RETREAT_MAX_M` away along the graph (the nearest among equals), facing
    the way the path there ends; ``None`` if there is none."""
    graph = view.graph
    start = graph.node_at(*pose[:2])
    if start < 0:
        return None
    cost, predecessors = graph.search([start], _RETREAT_MAX_M)
    nodes = np.flatnonzero(np.isfinite(cost[0]) & (cost[0] >= _RETREAT_MIN_M))
    if len(nodes) == 0:
        return None
    clearance = view.traversable.clearance_m.flat[graph.cells[nodes]]
    best = int(nodes[np.lexsort((cost[0, nodes], -clearance))[0]])
    path = graph.path_xy_m(predecessors[0], best)
    (x0, y0), (x1, y1) = path[-2], path[-1]
    return Goal(path, math.atan2(y1 - y0, x1 - x0), stuck.target_cells, stuck.done_fraction, retreat=True)


def nearest_cell(grid: GridSpec, mask: np.ndarray, xy_m: np.ndarray) -> int:
    """Flat index of the cell of ``mask`` (on ``grid``) whose centre is nearest to ``xy_m``."""
    flat = np.flatnonzero(mask)
    x, y = grid.center_of(*np.divmod(flat, grid.shape[1]))
    return int(flat[np.argmin(np.hypot(x - xy_m[0], y - xy_m[1]))])


def nearest_frontier_goal(view: View, pose: Pose, frontier: np.ndarray, goal_radius_m: float) -> Goal | None:
    """Goal at the graph node nearest to the vehicle among those within ``goal_radius_m`` of ``frontier``,
    facing the frontier cell nearest to it; ``None`` if no such node is reachable."""
    start = view.graph.node_at(*pose[:2])
    candidates = goal_candidates(view, frontier, goal_radius_m)
    if start < 0 or len(candidates) == 0:
        return None
    for limit in (_NEARBY_M, np.inf):  # most frontiers are near: search the neighbourhood first
        cost, predecessors = view.graph.search([start], limit)
        reachable = candidates[np.isfinite(cost[0, candidates])]
        if len(reachable):
            break
    else:
        return None
    goal_node = int(reachable[np.argmin(cost[0, reachable])])
    path = view.graph.path_xy_m(predecessors[0], goal_node)
    low_grid = view.maps.low_grid
    target = nearest_cell(low_grid, frontier, path[-1])
    tx, ty = low_grid.center_of(*divmod(target, low_grid.shape[1]))
    return Goal(path, math.atan2(float(ty) - path[-1, 1], float(tx) - path[-1, 0]), np.array([target]))


class NearestFrontier(GoalPlanner):
    """Yamauchi's frontier explorer: always fly to the frontier nearest along the planning graph."""

    def select_goal(self, view: View, pose: Pose) -> Goal | None:
        if not view.frontier.any():
            return None
        return nearest_frontier_goal(view, pose, view.frontier, self.config.goal_radius_m)
