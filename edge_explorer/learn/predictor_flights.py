"""Flights that record partial maps for the map predictor: explorers flying the true floor plans with the sensor.

:func:`fly` explores one plan with the planar sensor (docs/design.md §6, noise on): an :class:`Explorer` proposes sensor
poses, each pose is scanned into the two-level :class:`~edge_explorer.mapping.observed.ObservedMaps`, and every step
yields the observed-only coverage. The training data (:mod:`edge_explorer.learn.predictor_data`) is recorded from these
flights, and the evaluation (:mod:`edge_explorer.learn.eval_predictor`) flies the same way.

An :class:`Explorer` is anything with a ``name`` and a ``poses(scene, maps, start, rng)`` generator that yields the
next pose after the caller has folded the previous scan into ``maps``, so it can decide from the growing map. The
mix that records the training data (:data:`DEFAULT_EXPLORERS`, one drawn per plan):

* :class:`RandomGoalWalk` with ``greedy_prob`` 0.8 and 0.2 — shortest paths through the true configuration space
  to random goals, facing the motion with jitter, a partial spin at each goal; the greedy walk prefers goals near
  unexplored parts of the building and reaches high coverage, the other lingers. (Goals only *visible* from the
  current position, a straight-segment walk, rarely find the doors: it stalls in the first rooms.)
* :class:`PlannerExplorer` — the benchmark's Nearest Frontier and FUEL-style planners (:mod:`edge_explorer.plan`)
  flying the six actions with the action table's dynamics, so the predictor sees the partial maps it will see in
  ``frontier+pred`` and ``fuel+pred``. Other planners (the learned policy) join the same way.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numba import njit

from edge_explorer.errors import EdgeExplorerError
from edge_explorer.mapping.metrics import map_metrics
from edge_explorer.mapping.observed import ObservedMaps
from edge_explorer.sim.episode import move, previous_after
from edge_explorer.vehicle import dynamics
from edge_explorer.vehicle.dynamics import wrap_angle_rad
from edge_explorer.vehicle.sensor import SensorConfig, scan
from edge_explorer.world.grid import LOW_RES_M, UNKNOWN, GridSpec
from edge_explorer.world.raster import ROBOT_RADIUS_M, PlanRaster, configuration_space

Pose = tuple[float, float, float]  # x_m, y_m, yaw_rad in the plan's map frame


# ---- one building, as the flights see it ------------------------------------------------------------------------
@dataclass(frozen=True)
class Scene:
    """The ground truth of one plan, derived once: what the sensor sees, where the robot may be, the 0.20 m truth."""

    name: str
    grid: GridSpec  # 0.05 m
    occupied: np.ndarray  # bool on grid: what the sensor sees
    blocked: np.ndarray  # bool on grid: where the robot's centre may not be (outside the configuration space)
    low_grid: GridSpec  # 0.20 m, same origin
    truth_low: np.ndarray  # int8 codes on low_grid: OCCUPIED / FREE inside, UNKNOWN outside the building
    interior_low: np.ndarray  # bool on low_grid

    @classmethod
    def from_raster(cls, raster: PlanRaster, robot_radius_m: float = ROBOT_RADIUS_M) -> Scene:
        low = raster.coarsened(LOW_RES_M)
        return cls(
            name=raster.name,
            grid=raster.grid,
            occupied=np.ascontiguousarray(raster.occupied),
            blocked=~configuration_space(raster, robot_radius_m),
            low_grid=low.grid,
            truth_low=low.truth_codes(),
            interior_low=low.interior,
        )

    def random_start(self, rng: np.random.Generator) -> Pose:
        """A uniform pose of the configuration space with a uniform heading."""
        free = np.flatnonzero(~self.blocked)
        if free.size == 0:
            raise EdgeExplorerError(f"{self.name}: no cell of the configuration space to start from")
        row, col = divmod(int(free[rng.integers(free.size)]), self.grid.shape[1])
        x0, y0 = self.grid.origin_xy
        res = self.grid.resolution_m
        return x0 + (col + rng.random()) * res, y0 + (row + rng.random()) * res, float(rng.uniform(-math.pi, math.pi))

    def low_cell(self, x_m: float, y_m: float) -> tuple[int, int]:
        """(row, col) of the 0.20 m cell holding (x_m, y_m)."""
        row, col = self.low_grid.cell_of(x_m, y_m)
        return int(row), int(col)


# ---- explorers ---------------------------------------------------------------------------------------------------
class Explorer(Protocol):
    """Proposes sensor poses; ``maps`` holds every scan up to the last pose yielded."""

    @property
    def name(self) -> str: ...

    def poses(self, scene: Scene, maps: ObservedMaps, start: Pose, rng: np.random.Generator) -> Iterator[Pose]: ...


@njit(cache=True)
def _bfs_parents(blocked, start):
    """Breadth-first search over the 8-connected unblocked cells from flat index ``start``: each reached cell's
    predecessor (the start's is itself), −1 where unreachable."""
    n_rows, n_cols = blocked.shape
    parent = np.full(blocked.size, -1, np.int64)
    queue = np.empty(blocked.size, np.int64)
    parent[start] = start
    queue[0] = start
    head, tail = 0, 1
    while head < tail:
        cell = queue[head]
        head += 1
        row, col = cell // n_cols, cell % n_cols
        for dr in range(-1, 2):
            for dc in range(-1, 2):
                r, c = row + dr, col + dc
                if 0 <= r < n_rows and 0 <= c < n_cols and not blocked[r, c] and parent[r * n_cols + c] < 0:
                    parent[r * n_cols + c] = cell
                    queue[tail] = r * n_cols + c
                    tail += 1
    return parent


@dataclass(frozen=True)
class RandomGoalWalk:
    """Flights along shortest paths of the true configuration space to random goals; see the module docstring.

    Each goal is one of ``candidates`` random reachable cells. With probability ``greedy_prob`` the candidate with
    the most unknown interior cells within ``sensor_range_m`` wins (a frontier-seeking walk), otherwise the first
    (a uniform walk). The walk scans every ``step_m`` along the path, facing the motion ± Gaussian
    ``heading_jitter_rad``; at the goal it turns on the spot (30° per scan) for a uniform 0–``max_spin_scans`` scans.
    The path uses the ground truth (the collector knows the plan); what it records is only what the sensor saw.
    """

    greedy_prob: float = 0.7
    step_m: float = 0.5
    heading_jitter_rad: float = 0.3
    candidates: int = 24
    max_spin_scans: int = 6
    sensor_range_m: float = 4.5

    @property
    def name(self) -> str:
        return f"random-goal(greedy={self.greedy_prob:g})"

    def poses(self, scene: Scene, maps: ObservedMaps, start: Pose, rng: np.random.Generator) -> Iterator[Pose]:
        x, y, yaw = start
        grid = scene.grid
        stride = max(1, round(self.step_m / grid.resolution_m))
        while True:
            row, col = (int(v) for v in grid.cell_of(x, y))
            parent = _bfs_parents(scene.blocked, row * grid.shape[1] + col)
            path = self._path_to_goal(scene, maps, parent, rng)
            for k in range(stride, len(path) + stride - 1, stride):
                r, c = divmod(int(path[min(k, len(path) - 1)]), grid.shape[1])
                nx, ny = (float(v) for v in grid.center_of(r, c))
                heading = math.atan2(ny - y, nx - x)
                x, y = nx, ny
                yaw = wrap_angle_rad(heading + rng.normal(0.0, self.heading_jitter_rad))
                yield x, y, yaw
            turn = math.radians(30) * (1 if rng.random() < 0.5 else -1)
            for _ in range(int(rng.integers(self.max_spin_scans + 1)) if len(path) > 1 else 12):
                yaw = wrap_angle_rad(yaw + turn)
                yield x, y, yaw

    def _path_to_goal(
        self, scene: Scene, maps: ObservedMaps, parent: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        """Flat cell indices from the robot's cell to the chosen goal (just the robot's cell if none is reachable)."""
        reachable = np.flatnonzero(parent >= 0)
        goals = reachable[rng.integers(reachable.size, size=self.candidates)]
        goal = int(goals[0])
        if rng.random() < self.greedy_prob:
            unknown = np.cumsum(np.cumsum((maps.low == UNKNOWN) & scene.interior_low, 0), 1)
            radius = int(round(self.sensor_range_m / maps.low_grid.resolution_m))
            factor = maps.factor
            cols = scene.grid.shape[1]
            scores = [_box_sum(unknown, (g // cols) // factor, (g % cols) // factor, radius) for g in goals]
            goal = int(goals[int(np.argmax(scores))])
        path = [goal]
        while parent[path[-1]] != path[-1]:
            path.append(int(parent[path[-1]]))
        return np.array(path[::-1], dtype=np.int64)


@dataclass(frozen=True)
class PlannerExplorer:
    """A benchmark planner of :mod:`edge_explorer.plan` (``frontier``, ``fuel``) flown with the action dynamics.

    Each step the planner picks one of the six actions from the observed maps; the pose follows the shipped action
    table with its motion noise, as in :class:`~edge_explorer.sim.env.ExplorationEnv`. A motion that would leave the
    configuration space is not executed (the vehicle stops: its next step starts as after hover).
    """

    planner: str = "frontier"

    @property
    def name(self) -> str:
        return self.planner

    def poses(self, scene: Scene, maps: ObservedMaps, start: Pose, rng: np.random.Generator) -> Iterator[Pose]:
        from edge_explorer.plan.registry import build_planner

        table = dynamics.load_action_table()
        planner = build_planner(self.planner, table)
        planner.reset()
        pose, previous = start, int(dynamics.Action.HOVER)
        while (action := planner.act(maps, pose, previous)) is not None:
            pose, collided = move(table, scene.blocked, scene.grid, pose, previous, action, rng)
            previous = previous_after(action, collided)
            yield pose


def _box_sum(cumulative: np.ndarray, row: int, col: int, radius: int) -> int:
    """Sum over the square of half-side ``radius`` around (row, col) from a 2-D cumulative sum (clipped)."""
    r0, c0 = max(row - radius, 0) - 1, max(col - radius, 0) - 1
    r1, c1 = min(row + radius, cumulative.shape[0] - 1), min(col + radius, cumulative.shape[1] - 1)
    total = cumulative[r1, c1]
    if r0 >= 0:
        total -= cumulative[r0, c1]
    if c0 >= 0:
        total -= cumulative[r1, c0]
    if r0 >= 0 and c0 >= 0:
        total += cumulative[r0, c0]
    return int(total)


DEFAULT_EXPLORERS: tuple[Explorer, ...] = (
    RandomGoalWalk(greedy_prob=0.8),
    RandomGoalWalk(greedy_prob=0.2),
    PlannerExplorer("frontier"),
    PlannerExplorer("fuel"),
)


# ---- flying ------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FlightStep:
    """The state after one scan. ``maps`` is the flight's live map: copy what you keep."""

    step: int  # 0 = the scan at the start pose
    pose: Pose
    maps: ObservedMaps
    coverage: float  # observed-only coverage of the interior (docs/design.md §7)


@dataclass(frozen=True)
class FlightLimits:
    """When a flight stops: after ``max_steps`` scans, or when the coverage has not grown for ``stall_steps``."""

    max_steps: int = 2000
    stall_steps: int = 150


DEFAULT_LIMITS = FlightLimits()
DEFAULT_SENSOR = SensorConfig()  # the training simulator's: 87° field of view, 4.5 m range, occupied noise 0.1


def fly(
    scene: Scene,
    explorer: Explorer,
    rng: np.random.Generator,
    sensor: SensorConfig = DEFAULT_SENSOR,
    limits: FlightLimits = DEFAULT_LIMITS,
    start: Pose | None = None,
) -> Iterator[FlightStep]:
    """Explore ``scene``: scan at the start, then at each pose the explorer proposes, yielding after every scan.

    Ends when the explorer stops proposing poses or at ``limits``.
    """
    maps = ObservedMaps.empty(scene.grid, LOW_RES_M)
    pose = scene.random_start(rng) if start is None else start
    poses = explorer.poses(scene, maps, pose, rng)
    best, best_step = -1.0, 0
    for step in range(limits.max_steps):
        if step > 0:
            pose = next(poses, None)
            if pose is None:  # the explorer has nothing left to explore
                return
        patch = scan(scene.occupied, scene.grid, pose[0], pose[1], pose[2], sensor, rng)
        maps.apply_patch(patch.row0, patch.col0, patch.codes)
        coverage = map_metrics(maps.low, scene.truth_low, scene.interior_low).coverage
        yield FlightStep(step, pose, maps, coverage)
        if coverage > best:
            best, best_step = coverage, step
        elif step - best_step >= limits.stall_steps:
            return
