"""The 2-D exploration simulator as a gymnasium environment (docs/design.md §5–§7, the paper's training setup).

One episode: a floor plan is drawn from the plan set, the vehicle starts at a uniform position of the
reachable flight space (:func:`~edge_explorer.world.flight_space.reachable_cells`: interior cells the planners can
fly to, clear of the walls by the robot radius plus the safety margin) with a uniform heading, and explores
with the six discrete actions while the planar sensor fills the two-level observed maps.

Spaces
------
* action: ``Discrete(6)`` — :class:`~edge_explorer.vehicle.dynamics.Action` (0 hover, 1 turn right, 2 turn left,
  3 forward, 4 turn right + forward, 5 turn left + forward). Anything else raises
  ``gymnasium.error.InvalidAction``.
* observation: ``Dict`` built by :func:`edge_explorer.mapping.ego.encode_observation` (the daemon uses the same):

  - ``high``: int8 237×237, heading-up window of the inflated 0.05 m observed map (11.85 m square);
  - ``thres``: int8 237×237, heading-up window of the inflated 0.20 m map M_thres (47.4 m square) —
    observed cells plus the thresholded prediction, or the observed low-res map without a predictor;
  - ``last_action``: float32 one-hot of the action taken last step (hover at the start).

  Codes: FREE −1, UNKNOWN 0, OCCUPIED 1, NON_FLIGHT 2 (the band within the robot radius of an occupied cell).
  The heading points along +row (up when drawn with ``origin="lower"``), the vehicle's cell is (118, 118).

Motion
------
Each action moves the vehicle by the shipped action table's (previous action, action) entry
(:mod:`edge_explorer.vehicle.dynamics`, momentum included) plus Gaussian noise when ``motion_noise`` is on. After a
collision the vehicle has stopped, so its next step starts as if after hover.

Reward
------
``R = −1 + (−l if penalised else ω·[F1(M_thres, t+1) − F1(M_thres, t)])`` with ``l = collision_penalty``,
``ω = f1_weight``. An action is penalised if its motion enters OCCUPIED ∪ NON_FLIGHT of the inflated ground
truth *now* (the vehicle then does not move: it stays where it was and stops), or *next step*: the drift it cannot
avoid afterwards — hovering after this action — would enter it. F1 is docs/design.md §7's, on the 0.20 m map.

Episode end
-----------
* terminated: coverage of M_thres reaches ``coverage_goal`` (default 0.95);
* truncated: ``max_steps`` steps without reaching it.

``info`` holds ``coverage``, ``correct_coverage``, ``f1``, ``path_length_m``, ``collided``, ``penalised``,
``plan``, ``steps``. ``reset(options=…)`` accepts ``plan_index`` and ``start_pose`` (x_m, y_m, yaw_rad) for
scripted runs and benchmarks; a start pose outside the reachable flight space raises ``ValueError``, a plan
without any (no free interior cell clear of the walls) raises :class:`~edge_explorer.errors.PlanError`.

Phase 2: pass ``predictor`` — a callable from the 256×256 north-up low-res ego window (int8 codes, robot at
(128, 128)) to occupancy probabilities of the same shape — and anneal the thresholds with
:meth:`ExplorationEnv.set_thresholds`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import gymnasium as gym
import numpy as np
from gymnasium import spaces

from edge_explorer.errors import PlanError
from edge_explorer.mapping import ego
from edge_explorer.mapping.metrics import MapMetrics, map_metrics
from edge_explorer.mapping.observed import ObservedMaps
from edge_explorer.predict.predictor import PredictorRuntime
from edge_explorer.predict.thresholding import ThresholdConfig, thresholded_map
from edge_explorer.sim.episode import move, previous_after
from edge_explorer.vehicle import dynamics
from edge_explorer.vehicle.dynamics import NUM_ACTIONS, Action, ActionTable
from edge_explorer.vehicle.sensor import SensorConfig, scan
from edge_explorer.world.flight_space import FlightClearance, reachable_cells
from edge_explorer.world.grid import (
    CELL_DTYPE,
    FREE,
    HIGH_RES_M,
    LOW_RES_M,
    NON_FLIGHT,
    OCCUPIED,
    UNKNOWN,
    GridSpec,
    resolution_factor,
)
from edge_explorer.world.raster import ROBOT_RADIUS_M, PlanRaster, block_reduce_max

Predictor = Callable[[np.ndarray], np.ndarray]
STAGES: tuple[str, ...] = ("dynamics", "sensor", "map_update", "metrics_reward", "observation")


@dataclass(frozen=True)
class EnvConfig:
    """Everything that defines the training task, besides the plans and the predictor."""

    sensor: SensorConfig = SensorConfig()
    thresholds: ThresholdConfig = ThresholdConfig()
    coverage_goal: float = 0.95
    max_steps: int = 500
    collision_penalty: float = 10.0  # l
    f1_weight: float = 100.0  # ω
    robot_radius_m: float = ROBOT_RADIUS_M
    motion_noise: bool = True
    action_table_path: str | None = None  # None: the shipped edge_explorer/data/action_table.json

    def __post_init__(self) -> None:
        if not 0 < self.coverage_goal <= 1:
            raise ValueError(f"coverage_goal must be in (0, 1], got {self.coverage_goal}")
        if self.max_steps < 1:
            raise ValueError(f"max_steps must be ≥ 1, got {self.max_steps}")
        if self.collision_penalty < 0 or self.f1_weight < 0 or self.robot_radius_m < 0:
            raise ValueError("collision_penalty, f1_weight and robot_radius_m must be ≥ 0")


@dataclass(frozen=True)
class _PlanTruth:
    """What the simulator derives once per plan."""

    raster: PlanRaster
    occupied: np.ndarray  # bool, 0.05 m: what the sensor sees
    blocked: np.ndarray  # bool, 0.05 m: OCCUPIED ∪ NON_FLIGHT of the inflated truth
    can_start: np.ndarray  # bool, 0.05 m: the reachable flight space (world.flight_space.reachable_cells)
    start_cells: np.ndarray  # flat indices of the configuration space (free interior cells, not blocked)
    truth_low: np.ndarray  # int8 codes, 0.20 m
    interior_low: np.ndarray  # bool, 0.20 m: N_M
    reachable_low: np.ndarray  # bool, 0.20 m: cells holding a reachable 0.05 m cell


def _plan_truth(raster: PlanRaster, robot_radius_m: float) -> _PlanTruth:
    occupied_codes = np.where(raster.occupied, OCCUPIED, FREE).astype(CELL_DTYPE)
    blocked = ego.inflate_codes(occupied_codes, raster.grid.resolution_m, robot_radius_m) != FREE
    in_cspace = raster.interior & ~blocked
    if not in_cspace.any():
        raise PlanError(
            f"{raster.name}: no free interior cell at least {robot_radius_m} m from the walls: nowhere to start"
        )
    can_start = reachable_cells(raster, FlightClearance(robot_radius_m=robot_radius_m)) & in_cspace
    low = raster.coarsened(LOW_RES_M)
    return _PlanTruth(
        raster=raster,
        occupied=np.ascontiguousarray(raster.occupied),
        blocked=blocked,
        can_start=can_start,
        start_cells=np.flatnonzero(in_cspace),
        truth_low=low.truth_codes(),
        interior_low=low.interior,
        reachable_low=block_reduce_max(can_start, resolution_factor(HIGH_RES_M, LOW_RES_M), low.grid.shape),
    )


class ExplorationEnv(gym.Env):
    """Exploration of one floor plan per episode; see the module docstring for spaces, reward and episode end."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(
        self,
        plans: Sequence[PlanRaster],
        config: EnvConfig = EnvConfig(),
        predictor: Predictor | None = None,
        render_mode: str | None = None,
    ) -> None:
        if len(plans) == 0:
            raise ValueError("ExplorationEnv needs at least one plan")
        for p in plans:
            if abs(p.grid.resolution_m - HIGH_RES_M) > 1e-9:
                raise PlanError(f"{p.name}: plans must be rasterized at {HIGH_RES_M} m, got {p.grid.resolution_m} m")
        if render_mode not in (None, "rgb_array"):
            raise gym.error.UnsupportedMode(f"render_mode {render_mode!r} is not supported; use 'rgb_array'")
        self.plans = list(plans)
        self.config = config
        self.predictor = predictor
        self.render_mode = render_mode
        self.table: ActionTable = dynamics.load_action_table(config.action_table_path)
        self._thresholds = config.thresholds
        size = ego.OBSERVATION_WINDOW_CELLS
        self.action_space = spaces.Discrete(NUM_ACTIONS)
        self.observation_space = spaces.Dict(
            {
                "high": spaces.Box(FREE, NON_FLIGHT, (size, size), dtype=CELL_DTYPE),
                "thres": spaces.Box(FREE, NON_FLIGHT, (size, size), dtype=CELL_DTYPE),
                "last_action": spaces.Box(0.0, 1.0, (NUM_ACTIONS,), dtype=np.float32),
            }
        )
        self.stage_seconds: dict[str, float] = dict.fromkeys(STAGES, 0.0)  # accumulated, for `sim bench`
        self._truth: _PlanTruth | None = None
        self._plan_index = -1
        self._maps: ObservedMaps | None = None
        self._probabilities: np.ndarray | None = None

    # ---- public helpers ------------------------------------------------------------------------------------------
    def set_thresholds(self, thresholds: ThresholdConfig) -> None:
        """Change t_f_max / t_o from the next step on (phase-2 annealing)."""
        self._thresholds = thresholds

    @property
    def pose(self) -> tuple[float, float, float]:
        """(x_m, y_m, yaw_rad) in the plan's map frame."""
        self._require_reset()
        return self._x, self._y, self._yaw

    @property
    def maps(self) -> ObservedMaps:
        self._require_reset()
        return self._maps  # type: ignore[return-value]

    @property
    def thresholded_low(self) -> np.ndarray:
        """M_thres on the 0.20 m grid (observed ∪ thresholded prediction)."""
        self._require_reset()
        return self._thres

    @property
    def probabilities_low(self) -> np.ndarray | None:
        """The predictor's occupancy probabilities on the 0.20 m grid at the last step (NaN where its window does
        not reach); None without a predictor. The map stop rule reads them
        (:mod:`edge_explorer.predict.verification`)."""
        self._require_reset()
        return self._probabilities

    def unexplored(self) -> tuple[np.ndarray, np.ndarray]:
        """Bool masks on the 0.20 m grid: N_M cells still UNKNOWN in M_thres, and those of them holding a cell the
        vehicle can reach (the rest it could only see from elsewhere). Used to explain a run that ends short."""
        self._require_reset()
        truth = self._truth
        assert truth is not None
        unexplored = truth.interior_low & (self._thres == UNKNOWN)
        return unexplored, unexplored & truth.reachable_low

    @property
    def path_xy_m(self) -> np.ndarray:
        """(N, 2) positions visited this episode, start included."""
        self._require_reset()
        return np.asarray(self._path, dtype=np.float64)

    # ---- gymnasium API -------------------------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - {"plan_index", "start_pose"}
        if unknown:
            raise ValueError(f"unknown reset option(s) {sorted(unknown)}; allowed: plan_index, start_pose")
        index = options.get("plan_index")
        if index is None:
            index = int(self.np_random.integers(len(self.plans)))
        elif not 0 <= int(index) < len(self.plans):
            raise ValueError(f"plan_index {index} out of range 0..{len(self.plans) - 1}")
        if int(index) != self._plan_index or self._truth is None:
            self._truth = _plan_truth(self.plans[int(index)], self.config.robot_radius_m)
            self._plan_index = int(index)
        truth = self._truth
        grid = truth.raster.grid
        if options.get("start_pose") is not None:
            x, y, yaw = (float(v) for v in options["start_pose"])
            row, col = grid.cell_of(x, y)
            if not (grid.contains(row, col) and truth.can_start[row, col]):
                raise ValueError(
                    f"start pose ({x:.2f}, {y:.2f}) m of {truth.raster.name} is not in its reachable flight space "
                    "(outside the building, in a wall, too close to one, or cut off behind a passage narrower "
                    "than the vehicle can fly): pick a pose in the open part of the building"
                )
        else:
            flat = int(truth.start_cells[self.np_random.integers(len(truth.start_cells))])
            while not truth.can_start.flat[flat]:  # redraw; a reachable first draw is the pose a plain draw gives
                flat = int(truth.start_cells[self.np_random.integers(len(truth.start_cells))])
            row, col = divmod(flat, grid.shape[1])
            x0, y0 = grid.origin_xy
            x = x0 + (col + self.np_random.random()) * grid.resolution_m
            y = y0 + (row + self.np_random.random()) * grid.resolution_m
            yaw = float(self.np_random.uniform(-math.pi, math.pi))
        self._x, self._y, self._yaw = x, y, dynamics.wrap_angle_rad(yaw)
        self._motion_previous = Action.HOVER
        self._last_action = Action.HOVER
        self._steps = 0
        self._path = [(x, y)]
        self._path_length_m = 0.0
        self._maps = ObservedMaps.empty(grid, LOW_RES_M)
        self._high_inflated = ego.InflatedMap(grid.shape, grid.resolution_m, self.config.robot_radius_m)
        self._sense()
        self._metrics = self._update_thresholded()
        self._f1 = self._metrics.f1
        return self._observation(), self._info(collided=False, penalised=False)

    def step(self, action: Any) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        self._require_reset()
        a = self._check_action(action)
        truth = self._truth
        assert truth is not None
        timer = time.perf_counter
        t0 = timer()
        rng = self.np_random if self.config.motion_noise else None
        grid = truth.raster.grid
        pose = (self._x, self._y, self._yaw)
        (x, y, yaw), collided = move(self.table, truth.blocked, grid, pose, self._motion_previous, a, rng)
        if collided:  # it stopped at the obstacle
            penalised = True
        else:
            drift = dynamics.body_to_map(x, y, yaw, *self.table.mean_step(a, Action.HOVER))
            penalised = dynamics.swept_path_blocked(truth.blocked, grid, (x, y), drift[:2])
            self._path_length_m += math.hypot(x - self._x, y - self._y)
            self._x, self._y, self._yaw = x, y, yaw
        self._motion_previous = Action(previous_after(a, collided))
        self._last_action = Action(a)
        self._steps += 1
        self._path.append((self._x, self._y))
        t1 = timer()
        self.stage_seconds["dynamics"] += t1 - t0
        self._sense()
        t2 = timer()
        self._metrics = self._update_thresholded()
        f1 = self._metrics.f1
        reward = -1.0 + (-self.config.collision_penalty if penalised else self.config.f1_weight * (f1 - self._f1))
        self._f1 = f1
        terminated = self._metrics.coverage >= self.config.coverage_goal
        truncated = not terminated and self._steps >= self.config.max_steps
        t3 = timer()
        self.stage_seconds["metrics_reward"] += t3 - t2
        obs = self._observation()
        self.stage_seconds["observation"] += timer() - t3
        return obs, reward, terminated, truncated, self._info(collided=collided, penalised=penalised)

    def render(self) -> np.ndarray | None:
        """RGB image: high ego layer | thresholded ego layer | truth with the observed map and the path."""
        if self.render_mode != "rgb_array":
            return None
        self._require_reset()
        obs = self._observation()
        panels = [_colorize(obs["high"]), _colorize(obs["thres"]), self._truth_panel(obs["high"].shape[0])]
        gap = np.full((panels[0].shape[0], 4, 3), 255, dtype=np.uint8)
        return np.concatenate([panels[0], gap, panels[1], gap, panels[2]], axis=1)

    # ---- internals -----------------------------------------------------------------------------------------------
    def _require_reset(self) -> None:
        if self._maps is None:
            raise gym.error.ResetNeeded("call reset() before using the environment")

    @staticmethod
    def _check_action(action: Any) -> int:
        if isinstance(action, np.ndarray) and action.shape == ():
            action = action.item()
        if isinstance(action, (bool, np.bool_)) or not isinstance(action, (int, np.integer)):
            raise gym.error.InvalidAction(f"action must be an integer id 0..{NUM_ACTIONS - 1}, got {action!r}")
        if not 0 <= action < NUM_ACTIONS:
            raise gym.error.InvalidAction(f"unknown action id {action}; valid ids are 0..{NUM_ACTIONS - 1}")
        return int(action)

    def _sense(self) -> None:
        """Scan from the current pose and fold it into the maps (and the inflated high-res map)."""
        truth = self._truth
        maps = self._maps
        assert truth is not None and maps is not None
        t0 = time.perf_counter()
        patch = scan(truth.occupied, truth.raster.grid, self._x, self._y, self._yaw, self.config.sensor, self.np_random)
        t1 = time.perf_counter()
        changed_rows, changed_cols = maps.apply_patch(patch.row0, patch.col0, patch.codes)
        self._high_inflated.update_cells(maps.high, changed_rows, changed_cols)
        self.stage_seconds["sensor"] += t1 - t0
        self.stage_seconds["map_update"] += time.perf_counter() - t1

    def _cell(self, grid: GridSpec) -> tuple[int, int]:
        """The vehicle's (row, col) on ``grid`` (plain floats: this runs every step)."""
        x0, y0 = grid.origin_xy
        return int(math.floor((self._y - y0) / grid.resolution_m)), int(math.floor((self._x - x0) / grid.resolution_m))

    def _update_thresholded(self) -> MapMetrics:
        """Recompute M_thres (observed map, or observed ∪ thresholded prediction) and its metrics."""
        truth, maps = self._truth, self._maps
        assert truth is not None and maps is not None
        if self.predictor is None:
            self._thres = maps.low
            self._probabilities = None
            return map_metrics(maps.low, truth.truth_low, truth.interior_low)
        low_cell = self._cell(maps.low_grid)
        window = ego.pad_shift(maps.low, low_cell, ego.PREDICTOR_WINDOW_CELLS)
        # an exported predictor with a whole-floor model picks it by the whole observed map, as the daemon does
        model = self.predictor.for_map(maps.low) if isinstance(self.predictor, PredictorRuntime) else self.predictor
        probabilities = np.asarray(model(window), dtype=np.float32)
        if probabilities.shape != window.shape:
            raise ValueError(f"predictor returned shape {probabilities.shape}, expected {window.shape}")
        on_map = ego.unshift(probabilities, low_cell, maps.low.shape)
        self._probabilities = on_map
        self._thres = thresholded_map(on_map, maps.low, maps.observed_area_m2(), self._thresholds)
        return map_metrics(maps.low, truth.truth_low, truth.interior_low, self._thres)

    def _observation(self) -> dict[str, np.ndarray]:
        maps = self._maps
        assert maps is not None
        thres_inflated = ego.inflate_codes(self._thres, maps.low_grid.resolution_m, self.config.robot_radius_m)
        return ego.encode_observation(
            self._high_inflated.codes,
            thres_inflated,
            self._cell(maps.high_grid),
            self._cell(maps.low_grid),
            self._yaw,
            self._last_action,
        )

    def _info(self, collided: bool, penalised: bool) -> dict[str, Any]:
        m = self._metrics
        return {
            "coverage": m.coverage,
            "correct_coverage": m.correct_coverage,
            "f1": m.f1,
            "n_m_m2": m.n_m * LOW_RES_M**2,  # the building's N_M area: coverage × this is the area known
            "path_length_m": self._path_length_m,
            "collided": collided,
            "penalised": penalised,
            "plan": self._truth.raster.name,  # type: ignore[union-attr]
            "steps": self._steps,
        }

    def truth_image(self) -> np.ndarray:
        """RGB image of the plan, north up: truth walls grey, observed free light blue, observed occupied black,
        the path red (one pixel per 0.05 m cell)."""
        self._require_reset()
        truth = self._truth
        maps = self._maps
        assert truth is not None and maps is not None
        rgb = np.full(truth.occupied.shape + (3,), 255, dtype=np.uint8)
        rgb[truth.raster.interior] = (235, 235, 235)
        rgb[maps.high == FREE] = (170, 210, 250)
        rgb[truth.occupied] = (150, 150, 150)
        rgb[maps.high == OCCUPIED] = (20, 20, 20)
        res = truth.raster.grid.resolution_m
        x0, y0 = truth.raster.grid.origin_xy
        pts = np.floor((self.path_xy_m - (x0, y0)) / res).astype(np.int32)
        cv2.polylines(rgb, [pts.reshape(-1, 1, 2)], False, (220, 40, 40), 1)
        cv2.circle(rgb, (int(pts[-1, 0]), int(pts[-1, 1])), 3, (220, 40, 40), -1)
        return np.ascontiguousarray(rgb[::-1])  # row 0 = north edge

    def _truth_panel(self, height_px: int) -> np.ndarray:
        rgb = self.truth_image()
        width = max(int(round(rgb.shape[1] * height_px / rgb.shape[0])), 1)
        return cv2.resize(rgb, (width, height_px), interpolation=cv2.INTER_AREA)


_CODE_COLORS = np.zeros((256, 3), dtype=np.uint8)
_CODE_COLORS[UNKNOWN] = (128, 128, 128)
_CODE_COLORS[FREE & 0xFF] = (255, 255, 255)
_CODE_COLORS[OCCUPIED] = (0, 0, 0)
_CODE_COLORS[NON_FLIGHT] = (240, 170, 60)


def _colorize(codes: np.ndarray) -> np.ndarray:
    """RGB of an ego code window, heading up (rows flipped so +row is up), the vehicle marked red."""
    rgb = _CODE_COLORS[codes.view(np.uint8)][::-1].copy()
    c = codes.shape[0] // 2
    rgb[c - 1 : c + 2, c - 1 : c + 2] = (220, 40, 40)
    return rgb
