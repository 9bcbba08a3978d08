"""Goal selection as a gymnasium environment: one step per navigation goal (the paper's DRL planner, docs/design.md §6).

Each step the agent picks one of the 59 × 59 heading-up goal cells (:mod:`edge_explorer.plan.goal_grid`); the
shared planner loop flies the vehicle there through observed free space with the six motions of the training
simulator (:class:`~edge_explorer.sim.env.ExplorationEnv`), until the loop asks for the next goal — the target was
seen or predicted, the goal failed — or the episode ends. Invalid cells are masked (:meth:`GoalEnv.action_masks`,
the sb3-contrib MaskablePPO convention): a cell is valid when its goal is reachable and worth a look — a view from
it shows at least the expert's ``min_gain_cells`` unknown cells, unless no goal does
(:func:`~edge_explorer.plan.goal_policy.worth_a_look`, the deployed planner's rule) — so a collision can only come
from motion noise; a masked cell that is chosen anyway is replaced by the valid cell nearest to it (``info
["goal_replaced"]``).

* observation: the :class:`ExplorationEnv` observation at the decision (``high``, ``thres``, ``last_action``);
* action: ``Discrete(3481)``, a flat goal cell (row-major);
* reward: ``ω·[F1(M_thres) after − before] − (metres flown) − l·(collisions)``, the paper's reward per decision with
  ω, l of the :class:`~edge_explorer.sim.env.EnvConfig`;
* terminated: coverage and correct coverage reach the goal, or the planner loop has nothing left to explore;
  truncated: the simulator's step cap.

When no goal cell is valid the predictive expert's fallbacks fly on (nearest observed frontier) without asking the
agent. :meth:`GoalEnv.expert_action` is the expert's choice at the current decision (DAgger labels, evaluation).
The agent's cell is flown as chosen; the deployed planner ranks the network's scores less a path-cost term
(:func:`~edge_explorer.plan.goal_policy.weighted_scores`), whose costs :meth:`GoalEnv.action_costs_m` gives, plus a
view-gain term (:func:`~edge_explorer.plan.goal_policy.with_view_gain`), whose views
:meth:`GoalEnv.action_view_cells` gives.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from edge_explorer.mapping.observed import ObservedMaps
from edge_explorer.plan.follow import Pose
from edge_explorer.plan.frontier import Goal, View
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS
from edge_explorer.plan.goal_policy import (
    GoalDecision,
    expert_label,
    goal_at_cell,
    goal_decision,
    view_cells,
    worth_a_look_of,
)
from edge_explorer.plan.predictive import PredictiveFrontier
from edge_explorer.sim.env import EnvConfig, ExplorationEnv, Predictor
from edge_explorer.sim.episode import Episode
from edge_explorer.world.raster import PlanRaster

NUM_GOALS = GOAL_GRID_CELLS * GOAL_GRID_CELLS
_SHARED_STATE = frozenset({"table", "config", "predictive"})  # planner attributes a snapshot shares, never copies


class _DecisionNeeded(Exception):  # noqa: N818 - a signal, not an error
    """Raised inside the planner loop when it needs a goal from the agent (carries the decision's view)."""

    def __init__(self, view: View, pose: Pose, decision: GoalDecision, mask: np.ndarray, cells: np.ndarray) -> None:
        # the constructor's arguments as args: it pickles (Ray, processes)
        super().__init__(view, pose, decision, mask, cells)
        self.view, self.pose, self.decision, self.mask, self.cells = view, pose, decision, mask, cells


class _AgentGoals(PredictiveFrontier):
    """The expert's loop with the agent's goals: a pending goal is flown; without one, the loop stops to ask."""

    def __init__(self, env: ExplorationEnv) -> None:
        super().__init__(table=env.table)
        self.pending: Goal | None = None

    def select_goal(self, view: View, pose: Pose) -> Goal | None:
        if self.pending is not None:
            goal, self.pending = self.pending, None
            return goal
        fused = self.fused if self.fused is not None else view.maps.low
        decision = goal_decision(view, pose, fused, self.last_action, self.config.goal_radius_m)
        if not decision.options.mask.any():
            return super().select_goal(view, pose)  # the expert's fallbacks: nearest observed frontier, or done
        cells = view_cells(view, decision, fused, self.predictive)
        mask = worth_a_look_of(decision.options.mask, cells, self.predictive.min_gain_cells)
        raise _DecisionNeeded(view, pose, decision, mask, cells)

    def snapshot(self) -> dict[str, Any]:
        """A deep copy of the loop's state (the table and configs are immutable and shared). The loop changes its
        state on the way to the question (stall counts, dropped targets, a back-off goal); replaying the step from
        this copy with the answer pending takes exactly the benchmark's path, where the answer comes at once."""
        return {k: copy.deepcopy(v) for k, v in vars(self).items() if k not in _SHARED_STATE}

    def restore(self, state: dict[str, Any]) -> None:
        vars(self).update(state)

    def act(
        self, maps: ObservedMaps, pose: Pose, previous_action: int, fused_low: np.ndarray | None = None
    ) -> int | None:
        """The loop's next action; when it stops to ask for a goal, its state is restored to before this call first,
        so that the step is replayed with the agent's goal pending (:meth:`snapshot`)."""
        state = self.snapshot()
        try:
            return super().act(maps, pose, previous_action, fused_low)
        except _DecisionNeeded:
            self.restore(state)
            raise

    def expert_goal(self, view: View, pose: Pose) -> Goal | None:
        return super().select_goal(view, pose)


class GoalEnv(gym.Env):
    """One navigation goal per step; see the module docstring."""

    metadata = {"render_modes": []}

    def __init__(
        self, plans: Sequence[PlanRaster], config: EnvConfig | None = None, predictor: Predictor | None = None
    ) -> None:
        config = config if config is not None else EnvConfig()
        self.sim = ExplorationEnv(plans, config, predictor=predictor)
        self.config = config
        self.observation_space = self.sim.observation_space
        self.action_space = spaces.Discrete(NUM_GOALS)
        self._planner: _AgentGoals | None = None
        self._pending: _DecisionNeeded | None = None
        self._info: dict[str, Any] = {}
        self._episode: Episode | None = None
        self._done = False

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        _, self._info = self.sim.reset(seed=seed, options=options)
        self._planner = _AgentGoals(self.sim)
        self._planner.reset()
        c = self.config
        self._episode = Episode(
            self.sim, self._planner, self._info, coverage_goal=c.coverage_goal, max_steps=c.max_steps
        )
        self._done = False
        _, _, collisions = self._fly()
        return self._observation(), {**self._info, "collisions": collisions}

    def step(self, action: Any):
        if self._pending is None:
            raise gym.error.ResetNeeded("the episode has ended; call reset()")
        cell = int(action)
        if not 0 <= cell < NUM_GOALS:
            raise gym.error.InvalidAction(f"goal cell {cell} is outside 0..{NUM_GOALS - 1}")
        valid = np.flatnonzero(self._pending.mask.ravel())
        replaced = cell not in valid
        if replaced:  # a masked goal: fly the valid goal cell nearest to it instead
            rows, cols = np.divmod(valid, GOAL_GRID_CELLS)
            row, col = divmod(cell, GOAL_GRID_CELLS)
            cell = int(valid[np.argmin((rows - row) ** 2 + (cols - col) ** 2)])
        assert self._planner is not None
        self._planner.pending = goal_at_cell(self._pending.view, self._pending.decision, cell)
        f1_before, path_before = self._info["f1"], self._info["path_length_m"]
        ended, truncated, collisions = self._fly()
        c = self.config
        reward = (
            c.f1_weight * (self._info["f1"] - f1_before)
            - (self._info["path_length_m"] - path_before)
            - c.collision_penalty * collisions
        )
        info = {**self._info, "collisions": collisions, "goal_replaced": replaced}
        return self._observation(), float(reward), ended, truncated, info

    def action_masks(self) -> np.ndarray:
        """bool (3481,): the goal cells the agent may choose now (all False once the episode has ended)."""
        if self._pending is None:
            return np.zeros(NUM_GOALS, dtype=bool)
        return self._pending.mask.ravel().copy()

    def action_costs_m(self) -> np.ndarray:
        """float64 (3481,): the path cost (m) to each goal cell now, inf where masked."""
        if self._pending is None:
            return np.full(NUM_GOALS, np.inf)
        return self._pending.decision.options.cost_m.ravel()

    def action_view_cells(self) -> np.ndarray:
        """int64 (3481,): how many unknown cells a view from each valid goal cell shows now, 0 where masked (the
        deployed planner's view-gain term, :func:`~edge_explorer.plan.goal_policy.with_view_gain`)."""
        if self._pending is None:
            return np.zeros(NUM_GOALS, dtype=np.int64)
        return self._pending.cells.ravel().copy()

    def expert_action(self) -> int | None:
        """The predictive expert's goal cell at this decision (``None`` if it would fly outside the goal grid)."""
        if self._pending is None or self._planner is None:
            return None
        goal = self._planner.expert_goal(self._pending.view, self._pending.pose)
        if goal is None:
            return None
        return expert_label(goal, self._pending.pose, self._pending.view, self._pending.decision.options)

    def _fly(self) -> tuple[bool, bool, int]:
        """Fly until the loop needs a goal (sets ``_pending``) or the episode ends: (terminated, truncated,
        collisions)."""
        assert self._episode is not None
        self._pending = None
        collisions = 0
        try:
            for step in self._episode.steps():
                self._info = step.info
                collisions += int(step.collided)
        except _DecisionNeeded as decision:  # the planner is back where it was before the step (_AgentGoals.act)
            self._pending = decision
            return False, False, collisions
        truncated = self._episode.ending == "step_cap"  # else the goal, or nothing left to explore
        return not truncated, truncated, collisions

    def _observation(self) -> dict[str, np.ndarray]:
        if self._pending is not None:
            return self._pending.decision.observation
        size = self.observation_space["high"].shape
        return {
            "high": np.zeros(size, np.int8),
            "thres": np.zeros(size, np.int8),
            "last_action": np.eye(6, dtype=np.float32)[0],
        }
