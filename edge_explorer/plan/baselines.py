"""The common interface of the exploration planners the benchmark flies, and their registry.

A planner sees what the vehicle has observed and where it is — and, where a predictor runs, the fused map
(docs/design.md §5: observed cells plus the thresholded prediction treated as known) — and answers one of the six action
ids (:class:`~edge_explorer.sim.dynamics.Action`) per step, so every method flies the same vehicle and path lengths
compare. ``None`` means the planner has nothing left to explore. Planners choose *goals* (where to look next); the
shared :class:`~edge_explorer.plan.frontier.GoalPlanner` loop plans the path through observed free space and
follows it, so a prediction never makes a cell flyable.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

from edge_explorer.errors import EdgeExplorerError
from edge_explorer.mapping.observed import ObservedMaps
from edge_explorer.plan.follow import Pose
from edge_explorer.sim.dynamics import ActionTable


class Planner(Protocol):
    def reset(self) -> None:
        """Start a new flight: forget goals and anything remembered about the last one."""

    def act(
        self, maps: ObservedMaps, pose: Pose, previous_action: int, fused_low: np.ndarray | None = None
    ) -> int | None:
        """Next action id from the observed maps, the pose (x_m, y_m, yaw_rad), the previous action (the one
        whose momentum the vehicle carries: hover after a collision) and the fused 0.20 m map (``None``, or the
        observed low-res map, without a predictor); ``None`` when done."""


def _nearest_frontier(table: ActionTable | None) -> Planner:
    from edge_explorer.plan.frontier import NearestFrontier

    return NearestFrontier(table=table)


def _fuel(table: ActionTable | None) -> Planner:
    try:
        from edge_explorer.plan.fuel import FuelPlanner
    except ImportError as exc:
        raise EdgeExplorerError(
            f"the FUEL-style planner needs OR-Tools ({exc.name} is missing): pip install 'edge-explorer[bench]' "
            "or run `make venv`"
        ) from exc

    return FuelPlanner(table=table)


def _predictive(table: ActionTable | None) -> Planner:
    from edge_explorer.plan.predictive import PredictiveFrontier

    return PredictiveFrontier(table=table)


PLANNERS: dict[str, Callable[[ActionTable | None], Planner]] = {
    "frontier": _nearest_frontier,
    "fuel": _fuel,
    "predfrontier": _predictive,
}


def make_planner(name: str, table: ActionTable | None = None) -> Planner:
    """A planner by its benchmark name (``frontier``, ``fuel``, ``predfrontier``) with default settings."""
    try:
        return PLANNERS[name](table)
    except KeyError:
        raise ValueError(f"unknown planner {name!r}; known: {', '.join(PLANNERS)}") from None
