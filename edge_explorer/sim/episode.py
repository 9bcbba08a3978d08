"""The simulated step loop: a planner flies the simulator one action at a time (docs/design.md §5–§7).

Every simulated flight of a planner — the benchmark's runs (:mod:`edge_explorer.bench.explore`), the goal policy's
demonstrations (:mod:`edge_explorer.learn.goal_demos`), the goal environment's replay of the agent's goals
(:mod:`edge_explorer.learn.goal_env`) — runs the same loop, :class:`Episode`:

1. stop with ``"goal"`` when coverage *and* correct coverage have reached the coverage goal — or, when the loop is
   given a ``map_stop`` rule (the benchmark's ``--stop map``, issue #56), instead with ``"map_stop"`` when that rule
   says the map is verified (it reads the maps only, never the truth: :mod:`edge_explorer.predict.verification`);
2. stop with ``"step_cap"`` when the simulator has taken ``max_steps`` steps since its reset;
3. ask the planner for the next action (``act(maps, pose, previous_action, fused_low)``); stop with ``"explored"``
   when it answers ``None``, it has nothing left to explore;
4. step the simulator, and carry the action into the next step as ``previous_action`` — or hover after a
   collision (:func:`previous_after`): the vehicle stopped at the obstacle, so the momentum it carries is hover's.

The simulator's own ``terminated``/``truncated`` are not used: the loop's caller decides when a flight ends (the
benchmark sets the simulator's coverage goal to 1 and stops at its own). The predictor flights
(:class:`~edge_explorer.learn.predictor_flights.PlannerExplorer`) fly a planner without a simulator — the flight
scans, the explorer only proposes poses — so they share the loop's motion instead: :func:`move` (one action of the
action table, stopped by the walls, which :class:`~edge_explorer.sim.env.ExplorationEnv` steps with too) and
:func:`previous_after`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Literal, Protocol

import numpy as np

from edge_explorer.mapping.observed import ObservedMaps
from edge_explorer.vehicle import dynamics
from edge_explorer.vehicle.dynamics import ActionTable
from edge_explorer.world.grid import GridSpec

Pose = tuple[float, float, float]  # x_m, y_m, yaw_rad in the plan's map frame
Ending = Literal["goal", "step_cap", "explored", "map_stop"]


class Planner(Protocol):
    """What the loop flies: a planner of :mod:`edge_explorer.plan` (:class:`~edge_explorer.plan.registry.
    GoalPlanner`) or anything with its ``act``."""

    def act(
        self, maps: ObservedMaps, pose: Pose, previous_action: int, fused_low: np.ndarray | None = None
    ) -> int | None: ...


class Simulator(Protocol):
    """What the loop flies in: :class:`~edge_explorer.sim.env.ExplorationEnv`'s maps, pose, fused map and step."""

    @property
    def maps(self) -> ObservedMaps: ...

    @property
    def pose(self) -> Pose: ...

    @property
    def thresholded_low(self) -> np.ndarray: ...

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]: ...


def previous_after(action: int, collided: bool) -> int:
    """The action whose momentum the next step starts from: ``action``, or hover if it collided (the vehicle stopped
    at the obstacle). The simulator's motion and the ``previous_action`` the planner is given both follow it."""
    return int(dynamics.Action.HOVER) if collided else action


def move(
    table: ActionTable,
    blocked: np.ndarray,
    grid: GridSpec,
    pose: Pose,
    previous: int,
    action: int,
    rng: np.random.Generator | None,
) -> tuple[Pose, bool]:
    """One ``action`` from ``pose`` after ``previous`` (the action table's motion, with its noise when ``rng`` is
    given), stopped by the walls: ``(new pose, False)``, or ``(pose, True)`` when the swept path enters ``blocked``
    (bool on ``grid``: where the vehicle's centre may not be) — the vehicle does not move."""
    x, y, yaw = dynamics.step_pose(table, *pose, previous, action, rng)
    if dynamics.swept_path_blocked(blocked, grid, pose[:2], (x, y)):
        return pose, True
    return (x, y, yaw), False


@dataclass(frozen=True)
class EpisodeStep:
    """One step of the loop: the planner's action, the simulator's ``info`` after it, and whether it collided."""

    action: int
    info: dict[str, Any]
    collided: bool


class Episode:
    """A planner flying a simulator until the coverage goal, the step cap or the planner's end (module docstring).

    Create it right after ``sim.reset()`` with the reset's ``info`` (and the planner reset); iterate :meth:`steps`
    (or call :meth:`run`). The loop's state lives here, not in the iterator, so a flight can be interrupted — an
    exception from the planner leaves :attr:`info` and :attr:`previous` as they were before that step — and resumed
    with a new :meth:`steps` (the goal environment stops the loop to ask its agent for a goal).
    """

    def __init__(
        self,
        sim: Simulator,
        planner: Planner,
        info: dict[str, Any],
        *,
        coverage_goal: float,
        max_steps: int,
        previous: int = int(dynamics.Action.HOVER),
        map_stop: Callable[[], bool] | None = None,
    ) -> None:
        """``map_stop``: when given, called once before every step (and after the last); ``True`` ends the flight
        with ``"map_stop"``, and the coverage goal no longer ends it."""
        self.sim = sim
        self.planner = planner
        self.coverage_goal = coverage_goal
        self.max_steps = max_steps
        self.map_stop = map_stop
        self.info = info  # the simulator's info after the last step (the reset's before the first)
        self.previous = previous  # the previous_action of the next step
        self.collisions = 0
        self.planner_s = 0.0  # wall time spent in planner.act
        self.ending: Ending | None = None  # set when steps() stops

    def steps(self) -> Iterator[EpisodeStep]:
        """Fly, yielding after each simulator step; when it stops, :attr:`ending` says why."""
        while True:
            ending = self._ending()
            if ending is not None:
                self.ending = ending
                return
            t = time.perf_counter()
            action = self.planner.act(self.sim.maps, self.sim.pose, self.previous, self.sim.thresholded_low)
            self.planner_s += time.perf_counter() - t
            if action is None:
                self.ending = "explored"
                return
            _, _, _, _, self.info = self.sim.step(action)
            collided = bool(self.info["collided"])
            self.collisions += int(collided)
            self.previous = previous_after(action, collided)
            yield EpisodeStep(action, self.info, collided)

    def run(self) -> Ending:
        """Fly to the end; how it ended."""
        for _ in self.steps():
            pass
        assert self.ending is not None
        return self.ending

    def _ending(self) -> Ending | None:
        if self.map_stop is not None:
            if self.map_stop():
                return "map_stop"
        elif self.info["coverage"] >= self.coverage_goal and self.info["correct_coverage"] >= self.coverage_goal:
            return "goal"
        if self.info["steps"] >= self.max_steps:
            return "step_cap"
        return None
