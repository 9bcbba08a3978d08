"""The learned goal planner (benchmark method ``drl``): a policy scores the goal cells, the shared loop flies the goal.

At each decision — when the planner loop of :class:`~edge_explorer.plan.frontier.GoalPlanner` asks for a goal: at
the start, when the target is seen or predicted, when a goal failed — :func:`goal_decision` builds

* the paper's observation (docs/design.md §5): heading-up windows of the inflated 0.05 m observed map and of the
  inflated fused 0.20 m map (observed ∪ thresholded prediction), and the one-hot last motion, exactly as
  :func:`~edge_explorer.mapping.ego.observation_from_maps` makes them for every stage;
* the goal options (:mod:`edge_explorer.plan.goal_grid`): the 59 × 59 heading-up goal cells, valid where a
  reachable planning node lies within ``goal_radius_m`` of a fused frontier cell.

A :data:`GoalPolicy` maps the observation to a 59 × 59 array of scores; :class:`GoalPolicyPlanner` ranks the valid
cells by score − ``policy_cost_weight_per_m`` × path cost (:func:`weighted_scores`; 0.3 per m since session 34)
+ ``policy_gain_weight`` × ln(1 + the unknown cells a view from the cell shows) (:func:`with_view_gain`; 2 since
session 36) and takes the best one that is worth a look — a view from its goal node shows at least the expert's
``min_gain_cells`` cells unknown in the fused map (:func:`worth_a_look`; the issue's "goals that reveal nothing are
masked"), the best valid cell when none is, and the best-ranked cell itself when the one worth a look is a detour
of more than ``policy_max_detour_m`` (session 35) — and flies to that cell's goal node along the planning graph
(observed free space at the robot's clearance: a collision-free path by construction), facing the frontier cells near
it. When no cell is valid the predictive expert's fallbacks apply (observed frontier, then done). The expert
(:class:`~edge_explorer.plan.predictive.PredictiveFrontier`) decides from the same view, so its choices label the
same decisions (:func:`expert_label`) for behaviour cloning.

On a whole floor (:meth:`GoalPolicyPlanner.on_whole_floor`) the goal cells are valid near the *observed* frontier
instead (``whole_floor_observed_targets``): the policy still sees the fused map, but a room the prediction filled
is no longer left behind for a second pass along the corridor. That frontier also leads into slots the prediction
had closed, where the follower may find no safe motion: goals it gets stuck on again and again at one spot give up
the frontier they were after there (``whole_floor_stuck_failures``, :meth:`GoalPolicyPlanner.on_stuck`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import cv2
import numpy as np

from edge_explorer.mapping.ego import observation_from_maps
from edge_explorer.plan.follow import Pose
from edge_explorer.plan.frontier import Goal, View, goal_candidates
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS, GoalOptions, ego_goal_cells, goal_options
from edge_explorer.plan.predictive import PredictiveConfig, PredictiveFrontier, view_windows, visible_unknown
from edge_explorer.vehicle.dynamics import ActionTable
from edge_explorer.world.grid import OCCUPIED, UNKNOWN

GoalPolicy = Callable[[dict[str, np.ndarray]], np.ndarray]  # observation → (59, 59) goal-cell scores


@runtime_checkable
class ConcurrentGoalPolicy(Protocol):
    """A :data:`GoalPolicy` that can also start scoring an observation and answer later (a model that runs off the
    interpreter's lock, on a thread of its own): the planner searches its goal options meanwhile."""

    def __call__(self, observation: dict[str, np.ndarray]) -> np.ndarray: ...

    def submit(self, observation: dict[str, np.ndarray]) -> Future[np.ndarray]: ...


_TARGET_RADIUS_M = 1.0  # frontier cells this close to a chosen goal are its target
_STUCK_SPOT_M = 1.0  # stuck goals with the vehicle this close to the first one's spot count as one stuck spot
_STUCK_DROP_M = 5.0  # a stuck spot drops the stuck targets' frontier piece within this distance of them
_EXPERT_DEFAULTS = PredictiveConfig()


@dataclass(frozen=True)
class GoalDecision:
    """Everything one decision needs: the observation, the valid goals and the search they came from."""

    observation: dict[str, np.ndarray]
    options: GoalOptions
    predecessors: np.ndarray  # Dijkstra predecessors from the vehicle's node (one row)


def goal_decision(
    view: View, pose: Pose, fused_low: np.ndarray, last_action: int, goal_radius_m: float
) -> GoalDecision:
    """The observation and goal options of ``view`` (whose frontier is the fused one) at ``pose``."""
    return decision_with(view, pose, decision_observation(view, pose, fused_low, last_action), goal_radius_m)


def decision_observation(view: View, pose: Pose, fused_low: np.ndarray, last_action: int) -> dict[str, np.ndarray]:
    """The policy's observation of ``view`` at ``pose`` (the first half of :func:`goal_decision`)."""
    maps = view.maps
    high_cell = tuple(int(v) for v in maps.high_grid.cell_of(*pose[:2]))
    low_cell = tuple(int(v) for v in maps.low_grid.cell_of(*pose[:2]))
    return observation_from_maps(
        maps.high,
        fused_low,
        maps.high_grid.resolution_m,
        maps.low_grid.resolution_m,
        high_cell,
        low_cell,
        pose[2],
        last_action,
    )


def decision_with(view: View, pose: Pose, observation: dict[str, np.ndarray], goal_radius_m: float) -> GoalDecision:
    """The decision of ``observation`` (:func:`decision_observation`'s): the goal options searched on ``view``'s
    planning graph from ``pose`` (the second half of :func:`goal_decision`)."""
    maps = view.maps
    graph = view.graph
    start = graph.node_at(*pose[:2])
    size = GOAL_GRID_CELLS
    if start < 0 or not view.frontier.any():
        empty = GoalOptions(np.full((size, size), -1, np.int64), np.full((size, size), np.inf))
        return GoalDecision(observation, empty, np.full(len(graph.cells), -9999, np.int32))
    cost, predecessors = graph.search([start])
    candidates = goal_candidates(view, view.frontier, goal_radius_m)
    options = goal_options(
        candidates, graph.node_xy_m(candidates), cost[0], pose, maps.low_grid.origin_xy, maps.low_grid.resolution_m
    )
    return GoalDecision(observation, options, predecessors[0])


def nearest_goals(options: GoalOptions, max_extra_m: float) -> GoalOptions:
    """``options`` less the goals whose path costs more than ``max_extra_m`` beyond the nearest valid one's: on a whole
    floor the planner chooses among the near goals, so it finishes where it is before it crosses the window for a
    large view (``PredictiveConfig.policy_max_extra_m``). Unchanged when ``max_extra_m`` is inf or nothing is valid."""
    mask = options.mask
    if math.isinf(max_extra_m) or not mask.any():
        return options
    near = mask & (options.cost_m <= float(options.cost_m[mask].min()) + max_extra_m)
    return GoalOptions(np.where(near, options.node, -1), np.where(near, options.cost_m, np.inf))


def expert_label(goal: Goal, pose: Pose, view: View, options: GoalOptions) -> int | None:
    """Flat goal cell of the expert's ``goal`` (where its path ends), or ``None`` if that cell is not a valid
    option (the expert fell back to the observed frontier, or its goal lies outside the goal grid)."""
    low = view.maps.low_grid
    row, col = ego_goal_cells(goal.path_xy_m[-1:], pose, low.origin_xy, low.resolution_m)[0]
    if not (0 <= row < GOAL_GRID_CELLS and 0 <= col < GOAL_GRID_CELLS) or not options.mask[row, col]:
        return None
    return int(row * GOAL_GRID_CELLS + col)


def weighted_scores(scores: np.ndarray, options: GoalOptions, cost_weight_per_m: float) -> np.ndarray:
    """(G, G) scores the planner ranks goal cells by: the policy's ``scores`` less ``cost_weight_per_m`` × the path
    cost to each cell (the network sees the maps, not path lengths through them), −inf where masked."""
    scores = np.asarray(scores, dtype=np.float64).reshape(options.mask.shape)
    return np.where(options.mask, scores - cost_weight_per_m * np.where(options.mask, options.cost_m, 0.0), -np.inf)


class _Gains:
    """The expert's gain of goal nodes at one decision, measured once per node: how many cells UNKNOWN in the fused
    map a view from the node shows (:func:`~edge_explorer.plan.predictive.visible_unknown`)."""

    def __init__(self, view: View, decision: GoalDecision, fused_low: np.ndarray, config: PredictiveConfig) -> None:
        self.view, self.decision, self.config = view, decision, config
        self.unknown, self.blocking = fused_low == UNKNOWN, fused_low == OCCUPIED
        self.cells: dict[int, int] = {}
        self._summed: np.ndarray | None = None  # integral image of ``unknown``, made on the first bound

    def _xy(self, cell: int) -> np.ndarray:
        return self.view.graph.node_xy_m([int(self.decision.options.node.flat[cell])])[0]

    def count(self, cell: int) -> int:
        """How many unknown cells the view from flat goal cell ``cell``'s node shows."""
        node = int(self.decision.options.node.flat[cell])
        if node not in self.cells:
            xy = self._xy(cell)
            seen = visible_unknown(xy, self.unknown, self.blocking, self.view.maps.low_grid, self.config.sensor.range_m)
            self.cells[node] = len(seen)
        return self.cells[node]

    def bounds(self, cells: np.ndarray) -> np.ndarray:
        """Upper bounds of :meth:`count` for the flat goal ``cells``, all at once: the unknown cells of the square
        each view scans (:func:`~edge_explorer.plan.predictive.view_windows`), read off an integral image. One call
        per decision, not one per valid cell (per cell they cost 7 ms of a decision on a whole floor)."""
        if self._summed is None:
            self._summed = cv2.integral(self.unknown.astype(np.uint8))
        xy = self.view.graph.node_xy_m(self.decision.options.node.flat[np.asarray(cells, dtype=np.int64)])
        r0, r1, c0, c1 = view_windows(xy, self.view.maps.low_grid, self.config.sensor.range_m)
        s = self._summed
        return s[r1, c1] - s[r0, c1] - s[r1, c0] + s[r0, c0]

    def worth_a_look(self, cell: int) -> bool:
        """Whether the view from flat goal cell ``cell``'s node shows at least ``min_gain_cells`` unknown cells."""
        return self.count(cell) >= self.config.min_gain_cells

    def counts(self) -> np.ndarray:
        """int (G, G): :meth:`count` of every valid goal cell, 0 where masked."""
        mask = self.decision.options.mask
        cells = np.zeros(mask.size, dtype=np.int64)
        for cell in np.flatnonzero(mask):
            cells[cell] = self.count(int(cell))
        return cells.reshape(mask.shape)


def view_cells(view: View, decision: GoalDecision, fused_low: np.ndarray, config: PredictiveConfig) -> np.ndarray:
    """int (G, G): how many cells UNKNOWN in the fused map a view from each valid goal cell shows (0 where masked):
    the expert's gain, which :func:`worth_a_look` and the planner's view-gain term read."""
    return _Gains(view, decision, fused_low, config).counts()


def worth_a_look_of(mask: np.ndarray, cells: np.ndarray, min_gain_cells: int) -> np.ndarray:
    """bool, ``mask``'s shape: the valid cells whose view shows at least ``min_gain_cells`` (``cells`` from
    :func:`view_cells`), or every valid cell when none does."""
    worth = mask & (cells >= min_gain_cells)
    return worth if worth.any() else mask


def worth_a_look(view: View, decision: GoalDecision, fused_low: np.ndarray, config: PredictiveConfig) -> np.ndarray:
    """bool (G, G): the valid goal cells whose view shows at least the expert's ``min_gain_cells`` unknown cells of
    the fused map, or every valid cell when none does. Issue #21 masks goals that reveal nothing; this is the
    expert's own measure of a goal worth a look (docs/policy/goal_policy.md, session 33)."""
    cells = view_cells(view, decision, fused_low, config)
    return worth_a_look_of(decision.options.mask, cells, config.min_gain_cells)


def with_view_gain(scores: np.ndarray, cells: np.ndarray, weight: float) -> np.ndarray:
    """``scores`` (goal cells, −inf where masked) plus ``weight`` × ln(1 + ``cells``), the unknown cells a view from
    each shows (:func:`view_cells`, same shape): the policy ranks goals by what it learned from its teacher, which
    preferred near goals, and this adds what each view would reveal on this map. Logarithmic, so a view of 500 cells
    outranks one of 50 by 2.3 × ``weight``, not tenfold."""
    scores = np.asarray(scores, dtype=np.float64)
    return np.where(np.isfinite(scores), scores + weight * np.log1p(cells), scores)


def _best_cells(flat_scores: np.ndarray, gains: _Gains, gain_weight: float) -> tuple[int, int]:
    """(the best cell, the best cell worth a look — or the best when none is) by ``flat_scores`` + ``gain_weight`` ×
    ln(1 + view count), ties to the lower cell index. Branch and bound: cells are visited by an optimistic total (the
    view's :meth:`_Gains.bounds` for its count) and views are measured only until no unvisited cell can beat the best
    worth a look; without the gain term that is the first cell worth a look, so a decision measures one or two
    views, and with it a handful, not every valid cell's (all of them cost the daemon 60 × the decision time,
    session 36)."""
    finite = np.flatnonzero(np.isfinite(flat_scores))
    if gain_weight > 0:
        optimistic = flat_scores[finite] + gain_weight * np.log1p(gains.bounds(finite).astype(np.float64))
    else:
        optimistic = flat_scores[finite]
    visit = np.argsort(-optimistic, kind="stable")
    best = worth = None
    best_total = worth_total = -math.inf
    for cell, ceiling in zip(finite[visit].tolist(), optimistic[visit].tolist(), strict=True):
        if worth is not None and (ceiling, -cell) < (worth_total, -worth):
            break  # sorted by ceiling: no later cell beats the best worth a look (nor the best, which is ≥ it)
        total = flat_scores[cell] + (gain_weight * math.log1p(gains.count(cell)) if gain_weight > 0 else 0.0)
        if best is None or (total, -cell) > (best_total, -best):
            best, best_total = cell, total
        if (worth is None or (total, -cell) > (worth_total, -worth)) and gains.worth_a_look(cell):
            worth, worth_total = cell, total
    assert best is not None, "no valid goal cell"
    return best, worth if worth is not None else best


def best_cell_worth_a_look(
    view: View, decision: GoalDecision, scores: np.ndarray, fused_low: np.ndarray, config: PredictiveConfig
) -> int:
    """The best-scored cell of :func:`worth_a_look` (``scores`` from :func:`weighted_scores`), found lazily: cells
    are checked best first, so a decision usually measures one or two views, not every valid cell's. The best-scored
    cell of all is taken instead when the one worth a look would cost more than ``policy_max_detour_m`` more path and
    a view from the best still shows ``policy_detour_min_cells``: the rule must not send the vehicle across the
    building from a place it will have to come back to (building D, docs/policy/goal_policy.md, session 35).

    With ``policy_gain_weight`` > 0 every valid cell's view is measured and the scores gain that weight × ln(1 + its
    unknown cells) first (:func:`with_view_gain`; building C's short legs, session 36)."""
    gains = _Gains(view, decision, fused_low, config)
    best, cell = _best_cells(scores.ravel(), gains, config.policy_gain_weight)
    cost = decision.options.cost_m.ravel()
    if cost[cell] - cost[best] > config.policy_max_detour_m and gains.count(best) >= config.policy_detour_min_cells:
        return best
    return cell


def frontier_piece(frontier: np.ndarray, target_cells: np.ndarray, radius_cells: float) -> np.ndarray:
    """bool, ``frontier``'s shape: the cells of ``frontier`` 8-connected to the flat ``target_cells`` (those still
    frontier) and within ``radius_cells`` of one of them."""
    targets = np.zeros(frontier.shape, dtype=np.uint8)
    cells = np.asarray(target_cells, dtype=np.int64)
    targets.flat[cells[(cells >= 0) & (cells < frontier.size)]] = 1
    _, labels = cv2.connectedComponents(frontier.astype(np.uint8), connectivity=8)
    pieces = np.unique(labels[targets.astype(bool) & frontier])
    r = int(math.ceil(radius_cells))
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    near = cv2.dilate(targets, disk, borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    return near & np.isin(labels, pieces[pieces > 0])


def goal_at_cell(view: View, decision: GoalDecision, cell: int) -> Goal:
    """The goal of a valid flat goal cell: the path to its node, facing the frontier cells within
    :data:`_TARGET_RADIUS_M` of the node (its targets, done when 80 % of them are no frontier)."""
    node = int(decision.options.node.flat[cell])
    if node < 0:
        raise ValueError(f"goal cell {cell} is masked: not a valid goal")
    path = view.graph.path_xy_m(decision.predecessors, node)
    low = view.maps.low_grid
    frontier = np.flatnonzero(view.frontier)
    x, y = low.center_of(*np.divmod(frontier, low.shape[1]))
    distance = np.hypot(x - path[-1, 0], y - path[-1, 1])
    near = distance <= max(_TARGET_RADIUS_M, float(distance.min()))
    yaw = math.atan2(float(y[near].mean()) - path[-1, 1], float(x[near].mean()) - path[-1, 0])
    return Goal(path, yaw, frontier[near], done_fraction=0.8)


class GoalPolicyPlanner(PredictiveFrontier):
    """The learned goal planner: the expert's view and loop, the policy's choice of goal."""

    def __init__(
        self, policy: GoalPolicy, config: PredictiveConfig = _EXPERT_DEFAULTS, table: ActionTable | None = None
    ) -> None:
        super().__init__(config, table)
        self.policy = policy
        self.settings = config  # the goal choice's settings: ``config``, or its whole-floor variant
        self._stuck: tuple[tuple[float, float], int] | None = None  # where goals got stuck in a row, and how many

    def reset(self) -> None:
        super().reset()
        self.settings = self.predictive
        self._stuck = None

    def on_stuck(self, goal: Goal, view: View, pose: Pose) -> None:
        """Counts the goals the follower got stuck on: the ``stuck_failures``-th in a row with the vehicle within
        :data:`_STUCK_SPOT_M` of the first one's spot drops the connected frontier within :data:`_STUCK_DROP_M` of
        its targets for the flight. Each failure drops only its own targets, and a long frontier strip the follower
        cannot reach would otherwise be tried a few cells at a time."""
        limit = self.settings.stuck_failures
        if limit <= 0:
            return
        here = (pose[0], pose[1])
        same = self._stuck is not None and math.dist(here, self._stuck[0]) <= _STUCK_SPOT_M
        self._stuck = (self._stuck[0], self._stuck[1] + 1) if same and self._stuck is not None else (here, 1)
        if self._stuck[1] >= limit:
            radius_cells = _STUCK_DROP_M / view.maps.low_grid.resolution_m
            self.dropped(view.maps)[...] |= frontier_piece(view.frontier, goal.target_cells, radius_cells)
            self._stuck = None

    @property
    def observed_targets(self) -> bool:
        return self.settings.observed_targets

    def on_whole_floor(self) -> None:
        """On a whole floor every valid goal may be flown, not only those worth a look, goals are ranked with the
        whole-floor weights of path cost and view gain, only those near the nearest are chosen from, the targets
        are the observed frontier, and a stuck spot gives up its frontier (:class:`PredictiveConfig`'s ``whole_floor_``
        settings)."""
        whole = self.predictive
        self.settings = dataclasses.replace(
            whole,
            min_gain_cells=whole.whole_floor_min_gain_cells,
            policy_cost_weight_per_m=whole.whole_floor_cost_weight_per_m,
            policy_gain_weight=whole.whole_floor_gain_weight,
            policy_max_extra_m=whole.whole_floor_max_extra_m,
            observed_targets=whole.whole_floor_observed_targets,
            stuck_failures=whole.whole_floor_stuck_failures,
        )

    def select_goal(self, view: View, pose: Pose) -> Goal | None:
        """The policy's goal (module docstring). A policy that can also :meth:`~ConcurrentGoalPolicy.submit` an
        observation scores it while the goal options are searched (the daemon's, on its own thread): the same
        scores, sooner."""
        fused = self.fused if self.fused is not None else view.maps.low
        observation = decision_observation(view, pose, fused, self.last_action)
        pending = self.policy.submit(observation) if isinstance(self.policy, ConcurrentGoalPolicy) else None
        decision = decision_with(view, pose, observation, self.config.goal_radius_m)
        if not decision.options.mask.any():
            return super().select_goal(view, pose)  # the expert's fallbacks: observed frontier, then done
        scores = pending.result() if pending is not None else self.policy(decision.observation)
        return self.policy_goal(view, decision, scores, fused)

    def policy_goal(self, view: View, decision: GoalDecision, scores: np.ndarray, fused_low: np.ndarray) -> Goal:
        """The goal the planner flies for the policy's ``scores`` of ``decision`` (whose options are not empty):
        among the near goals on a whole floor, ranked by score, path cost and view gain, the best worth a look."""
        near = nearest_goals(decision.options, self.settings.policy_max_extra_m)
        decision = dataclasses.replace(decision, options=near)
        ranked = weighted_scores(scores, decision.options, self.settings.policy_cost_weight_per_m)
        return goal_at_cell(view, decision, best_cell_worth_a_look(view, decision, ranked, fused_low, self.settings))
