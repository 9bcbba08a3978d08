"""Every exploration planner, in one registry: bench, daemon, CLI, profiler and training tools build planners here.

A planner sees what the vehicle has observed and where it is — and, where a predictor runs, the fused map
(docs/design.md §5: observed cells plus the thresholded prediction treated as known) — and answers one of the six
action ids (:class:`~edge_explorer.vehicle.dynamics.Action`) per step, so every method flies the same vehicle and path
lengths compare. ``None`` means the planner has nothing left to explore. Planners choose *goals* (where to look
next); the shared :class:`~edge_explorer.plan.frontier.GoalPlanner` loop plans the path through observed free space
and follows it, so a prediction never makes a cell flyable.

Adding a planner is one entry in :data:`PLANNERS`: a name, a line that says what it is, whether it needs a learned
goal policy, and a builder from the shared settings (:class:`~edge_explorer.plan.frontier.PlannerConfig`: the
follower and the planning graph) and the action table to the planner.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

from edge_explorer.errors import EdgeExplorerError

if TYPE_CHECKING:  # the registry itself stays light: command lines list its names without loading a planner
    import numpy as np

    from edge_explorer.mapping.observed import ObservedMaps
    from edge_explorer.plan.follow import FollowConfig, Pose
    from edge_explorer.plan.frontier import GoalPlanner, PlannerConfig
    from edge_explorer.plan.goal_policy import GoalPolicy
    from edge_explorer.plan.window import WindowConfig, WindowedPlanner
    from edge_explorer.vehicle.dynamics import ActionTable


class Planner(Protocol):
    def reset(self) -> None:
        """Start a new flight: forget goals and anything remembered about the last one."""

    def act(
        self, maps: ObservedMaps, pose: Pose, previous_action: int, fused_low: np.ndarray | None = None
    ) -> int | None:
        """Next action id from the observed maps, the pose (x_m, y_m, yaw_rad), the previous action (the one
        whose momentum the vehicle carries: hover after a collision) and the fused 0.20 m map (``None``, or the
        observed low-res map, without a predictor); ``None`` when done."""


Builder = Callable[["PlannerConfig", "ActionTable | None", "GoalPolicy | None"], "GoalPlanner"]


@dataclass(frozen=True)
class PlannerEntry:
    """One planner of the registry: what it is, whether it flies a learned goal policy, how to build it."""

    summary: str
    needs_policy: bool
    build: Builder


def _nearest_frontier(config: PlannerConfig, table: ActionTable | None, policy: GoalPolicy | None) -> GoalPlanner:
    from edge_explorer.plan.frontier import NearestFrontier

    return NearestFrontier(config, table)


def _fuel(config: PlannerConfig, table: ActionTable | None, policy: GoalPolicy | None) -> GoalPlanner:
    try:
        from edge_explorer.plan.fuel import FuelConfig, FuelPlanner
    except ImportError as exc:
        raise EdgeExplorerError(
            f"the FUEL-style planner needs OR-Tools ({exc.name} is missing): pip install 'edge-explorer[bench]' "
            "or run `make venv`"
        ) from exc

    return FuelPlanner(FuelConfig(planner=config), table)


def _predictive(config: PlannerConfig, table: ActionTable | None, policy: GoalPolicy | None) -> GoalPlanner:
    from edge_explorer.plan.predictive import PredictiveConfig, PredictiveFrontier

    return PredictiveFrontier(PredictiveConfig(planner=config), table)


def _learned(config: PlannerConfig, table: ActionTable | None, policy: GoalPolicy | None) -> GoalPlanner:
    from edge_explorer.plan.goal_policy import GoalPolicyPlanner
    from edge_explorer.plan.predictive import PredictiveConfig

    if policy is None:
        raise EdgeExplorerError("the drl planner needs a goal policy (a model folder such as models/policy)")
    return GoalPolicyPlanner(policy, PredictiveConfig(planner=config), table)


PLANNERS: dict[str, PlannerEntry] = {
    "frontier": PlannerEntry("Nearest Frontier (Yamauchi 1997)", False, _nearest_frontier),
    "fuel": PlannerEntry("FUEL-style: frontier clusters toured by an open TSP (OR-Tools)", False, _fuel),
    "predfrontier": PlannerEntry("the predictive expert: goals scored on the fused map", False, _predictive),
    "drl": PlannerEntry("the learned goal policy, flown by the predictive expert's loop", True, _learned),
}


def build_planner(
    name: str,
    table: ActionTable | None = None,
    policy: GoalPolicy | None = None,
    follow: FollowConfig | None = None,
    window: WindowConfig | None = None,
) -> WindowedPlanner:
    """The planner registered as ``name`` with default settings, or the follower settings ``follow`` (the
    daemon's), inside the planning hierarchy (:mod:`edge_explorer.plan.window`; ``window``: its window and route
    settings), which leaves it alone on maps that fit the window; ``policy`` is the learned goal policy for the
    planners that need one (``drl``)."""
    from edge_explorer.plan.frontier import PlannerConfig
    from edge_explorer.plan.window import WindowConfig, WindowedPlanner

    entry = PLANNERS.get(name)
    if entry is None:
        raise EdgeExplorerError(f"unknown planner {name!r}; known: {', '.join(PLANNERS)}")
    config = PlannerConfig() if follow is None else PlannerConfig(follow=follow)
    return WindowedPlanner(entry.build(config, table, policy), window or WindowConfig())
