"""Action dynamics: the (previous action, action) → motion table shared by the simulator and the daemon.

Six discrete actions (docs/design.md §6). Each lasts one step (default 1 s) and asks the vehicle for a forward motion
(0 or one forward step, 0.5 m) and a turn (0 or ±30°, left = counter-clockwise = positive yaw). What the vehicle
actually does depends on the speed it carries from the previous action (momentum), so the effect of an action is
tabulated per (previous action, action) pair.

Vehicle model (one axis for speed along the heading, one for yaw rate; :class:`VehicleModel`):

* every action ends its step at a *cruise* state that depends only on the action: forward speed
  ``forward_step_m / step_s`` (0.5 m/s) for the forward actions, 0 otherwise; yaw rate ``±turn_step_rad / step_s``
  (±30°/s) for the turning actions, 0 otherwise. So the start state of a step is the end state of the previous
  action, and the table needs only the pair. (After a collision the vehicle has stopped: the simulator then uses
  ``hover`` as the previous action.)
* within the step each axis follows a trapezoidal profile — ramp at the acceleration limit from the start speed to
  a level, hold it, ramp to the cruise speed at the end — whose level is chosen so that the displacement is as close
  as the limits allow to the nominal one (0.5 m / ±30° / 0); speed stays in [0, v_max] (the vehicle never flies
  backwards into space its camera has not seen), yaw rate in [−ω_max, ω_max].
* the position is integrated along the resulting curved path, giving Δx (forward), Δy (left) in the body frame of
  the start pose, and Δyaw.

With the defaults (v_max 1 m/s, a_max 1 m/s², ω_max 60°/s, yaw acceleration 120°/s²): forward after forward moves
0.5 m, forward after hover only 0.4375 m (it must first accelerate), and hover after forward still drifts 0.125 m
(it must brake); turning left right after turning right reaches only 22.5°.

Noise: the simulator adds zero-mean Gaussian noise per step with standard deviations
``pos_std = pos_noise_floor_m + pos_noise_frac·|Δxy|`` (each body axis) and
``yaw_std = yaw_noise_floor_rad + yaw_noise_frac·|Δyaw|``, also stored in the table.

The table lives in one data file, ``edge_explorer/data/action_table.json`` (format ``edge-explorer/action-table``,
with a version and the model parameters). Regenerate it with :func:`write_action_table` after changing the model;
a test checks the shipped file equals the regenerated one.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields
from enum import IntEnum
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numba import njit

from edge_explorer.errors import EdgeExplorerError
from edge_explorer.world.grid import GridSpec

TABLE_FORMAT = "edge-explorer/action-table"
TABLE_VERSION = 1
_DECIMALS = 6  # stored precision (µm, µrad): regenerating on any machine gives the same file


class Action(IntEnum):
    """The policy's discrete actions (ids are the network's output indices)."""

    HOVER = 0
    TURN_RIGHT = 1
    TURN_LEFT = 2
    FORWARD = 3
    TURN_RIGHT_FORWARD = 4
    TURN_LEFT_FORWARD = 5


NUM_ACTIONS = len(Action)

# (forward steps, turn direction) each action asks for; turn +1 = left (counter-clockwise).
_ACTION_INTENT: dict[Action, tuple[int, int]] = {
    Action.HOVER: (0, 0),
    Action.TURN_RIGHT: (0, -1),
    Action.TURN_LEFT: (0, 1),
    Action.FORWARD: (1, 0),
    Action.TURN_RIGHT_FORWARD: (1, -1),
    Action.TURN_LEFT_FORWARD: (1, 1),
}


@dataclass(frozen=True)
class VehicleModel:
    """Velocity- and acceleration-limited vehicle from which the action table is derived."""

    step_s: float = 1.0
    forward_step_m: float = 0.5
    turn_step_rad: float = math.radians(30.0)
    speed_max_m_s: float = 1.0
    accel_max_m_s2: float = 1.0
    yaw_rate_max_rad_s: float = math.radians(60.0)
    yaw_accel_max_rad_s2: float = math.radians(120.0)
    pos_noise_floor_m: float = 0.01
    pos_noise_frac: float = 0.05
    yaw_noise_floor_rad: float = math.radians(0.5)
    yaw_noise_frac: float = 0.05

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"VehicleModel.{f.name} must be a finite number ≥ 0, got {value}")
        for name in ("step_s", "accel_max_m_s2", "yaw_accel_max_rad_s2"):
            if getattr(self, name) <= 0:
                raise ValueError(f"VehicleModel.{name} must be positive")
        if self.forward_step_m / self.step_s > self.speed_max_m_s:
            raise ValueError("cruise speed forward_step_m / step_s exceeds speed_max_m_s")
        if self.turn_step_rad / self.step_s > self.yaw_rate_max_rad_s:
            raise ValueError("cruise yaw rate turn_step_rad / step_s exceeds yaw_rate_max_rad_s")


@dataclass(frozen=True)
class ActionTable:
    """Mean motion and noise per (previous action, action); arrays are 6×6, indexed [previous][action]."""

    model: VehicleModel
    dx_body_m: np.ndarray  # forward
    dy_body_m: np.ndarray  # left
    dyaw_rad: np.ndarray  # counter-clockwise
    pos_std_m: np.ndarray  # per body axis
    yaw_std_rad: np.ndarray

    def mean_step(self, previous: int, action: int) -> tuple[float, float, float]:
        """(Δx_body, Δy_body, Δyaw) of ``action`` after ``previous``."""
        return (
            float(self.dx_body_m[previous, action]),
            float(self.dy_body_m[previous, action]),
            float(self.dyaw_rad[previous, action]),
        )


# ---- derivation -------------------------------------------------------------------------------------------------
def _trapezoid_times(v0: float, level: float, v1: float, duration_s: float, accel: float) -> tuple[float, float, float]:
    t_up = abs(level - v0) / accel
    t_down = abs(v1 - level) / accel
    return t_up, duration_s - t_up - t_down, t_down


def _trapezoid_distance(v0: float, level: float, v1: float, duration_s: float, accel: float) -> float:
    t_up, t_hold, t_down = _trapezoid_times(v0, level, v1, duration_s, accel)
    return 0.5 * (v0 + level) * t_up + level * t_hold + 0.5 * (level + v1) * t_down


def _profile_level(
    v0: float, v1: float, target: float, duration_s: float, accel: float, v_lo: float, v_hi: float
) -> float:
    """Level of the trapezoid v0 → level → v1 whose displacement is closest to ``target``.

    The displacement grows with the level (its derivative is the hold time ≥ 0), so bisection finds it.
    """
    if abs(v1 - v0) > accel * duration_s + 1e-12:
        raise ValueError(f"cannot change speed from {v0} to {v1} within {duration_s} s at {accel}/s²")
    lo = max(v_lo, 0.5 * (v0 + v1 - accel * duration_s))
    hi = min(v_hi, 0.5 * (v0 + v1 + accel * duration_s))
    if _trapezoid_distance(v0, lo, v1, duration_s, accel) >= target:
        return lo
    if _trapezoid_distance(v0, hi, v1, duration_s, accel) <= target:
        return hi
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if _trapezoid_distance(v0, mid, v1, duration_s, accel) < target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def _trapezoid_samples(
    v0: float, level: float, v1: float, duration_s: float, accel: float, t: np.ndarray
) -> np.ndarray:
    t_up, t_hold, _ = _trapezoid_times(v0, level, v1, duration_s, accel)
    up = v0 + np.sign(level - v0) * accel * t
    down = level + np.sign(v1 - level) * accel * (t - t_up - t_hold)
    return np.where(t < t_up, up, np.where(t < t_up + t_hold, level, down))


def _cumtrapz(y: np.ndarray, dt: float) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(0.5 * (y[1:] + y[:-1]) * dt)])


def _step_motion(model: VehicleModel, previous: Action, action: Action) -> tuple[float, float, float]:
    """Integrate one step of ``action`` starting from the cruise state of ``previous``."""
    cruise_speed = model.forward_step_m / model.step_s
    cruise_rate = model.turn_step_rad / model.step_s
    fwd0, turn0 = _ACTION_INTENT[previous]
    fwd1, turn1 = _ACTION_INTENT[action]
    speed_level = _profile_level(
        fwd0 * cruise_speed,
        fwd1 * cruise_speed,
        fwd1 * model.forward_step_m,
        model.step_s,
        model.accel_max_m_s2,
        0.0,
        model.speed_max_m_s,
    )
    rate_level = _profile_level(
        turn0 * cruise_rate,
        turn1 * cruise_rate,
        turn1 * model.turn_step_rad,
        model.step_s,
        model.yaw_accel_max_rad_s2,
        -model.yaw_rate_max_rad_s,
        model.yaw_rate_max_rad_s,
    )
    t = np.linspace(0.0, model.step_s, 20001)
    dt = float(t[1] - t[0])
    speed = _trapezoid_samples(
        fwd0 * cruise_speed, speed_level, fwd1 * cruise_speed, model.step_s, model.accel_max_m_s2, t
    )
    rate = _trapezoid_samples(
        turn0 * cruise_rate, rate_level, turn1 * cruise_rate, model.step_s, model.yaw_accel_max_rad_s2, t
    )
    yaw = _cumtrapz(rate, dt)
    x = _cumtrapz(speed * np.cos(yaw), dt)
    y = _cumtrapz(speed * np.sin(yaw), dt)
    return float(x[-1]), float(y[-1]), float(yaw[-1])


def derive_action_table(model: VehicleModel = VehicleModel()) -> ActionTable:
    """Integrate the vehicle model for every (previous, action) pair; values rounded to the stored precision."""
    shape = (NUM_ACTIONS, NUM_ACTIONS)
    dx, dy, dyaw = np.zeros(shape), np.zeros(shape), np.zeros(shape)
    for previous in Action:
        for action in Action:
            dx[previous, action], dy[previous, action], dyaw[previous, action] = _step_motion(model, previous, action)
    pos_std = model.pos_noise_floor_m + model.pos_noise_frac * np.hypot(dx, dy)
    yaw_std = model.yaw_noise_floor_rad + model.yaw_noise_frac * np.abs(dyaw)
    arrays = (np.round(a, _DECIMALS) + 0.0 for a in (dx, dy, dyaw, pos_std, yaw_std))  # + 0.0: no "-0.0"
    return ActionTable(model, *arrays)


# ---- the data file ----------------------------------------------------------------------------------------------
def default_table_path() -> Path:
    return Path(str(resources.files("edge_explorer") / "data" / "action_table.json"))


def action_table_to_dict(table: ActionTable) -> dict[str, Any]:
    return {
        "format": TABLE_FORMAT,
        "version": TABLE_VERSION,
        "model": asdict(table.model),
        "actions": [a.name.lower() for a in Action],
        "frame": "body frame of the pose at the start of the step: x forward, y left, yaw counter-clockwise (rad)",
        "index": "[previous action][action]",
        "dx_body_m": table.dx_body_m.tolist(),
        "dy_body_m": table.dy_body_m.tolist(),
        "dyaw_rad": table.dyaw_rad.tolist(),
        "pos_std_m": table.pos_std_m.tolist(),
        "yaw_std_rad": table.yaw_std_rad.tolist(),
    }


def write_action_table(path: str | Path | None = None, model: VehicleModel = VehicleModel()) -> Path:
    """Derive the table from ``model`` and write it (default: the shipped data file)."""
    path = Path(path) if path is not None else default_table_path()
    path.write_text(_table_json(action_table_to_dict(derive_action_table(model))))
    return path


def _table_json(data: dict[str, Any]) -> str:
    """JSON with one line per key and per table row, so the file reads as a table."""
    lines = []
    for key, value in data.items():
        if isinstance(value, list) and value and isinstance(value[0], list):
            rows = ",\n  ".join(json.dumps(row) for row in value)
            text = f"[\n  {rows}\n ]"
        else:
            text = json.dumps(value)
        lines.append(f" {json.dumps(key)}: {text}")
    return "{\n" + ",\n".join(lines) + "\n}\n"


def load_action_table(path: str | Path | None = None) -> ActionTable:
    """Read and validate an action table file (default: the shipped one)."""
    path = Path(path) if path is not None else default_table_path()
    try:
        data = json.loads(path.read_text())
    except OSError as exc:
        raise EdgeExplorerError(f"{path}: cannot read the action table ({exc.strerror})") from exc
    except json.JSONDecodeError as exc:
        raise EdgeExplorerError(f"{path}: not valid JSON (line {exc.lineno}: {exc.msg})") from exc
    if not isinstance(data, dict) or data.get("format") != TABLE_FORMAT:
        raise EdgeExplorerError(f"{path}: not an action table (format must be {TABLE_FORMAT!r})")
    if data.get("version") != TABLE_VERSION:
        raise EdgeExplorerError(f"{path}: unsupported action table version {data.get('version')!r}")
    try:
        model = VehicleModel(**data["model"])
        arrays = [
            np.asarray(data[k], dtype=np.float64)
            for k in ("dx_body_m", "dy_body_m", "dyaw_rad", "pos_std_m", "yaw_std_rad")
        ]
    except (KeyError, TypeError, ValueError) as exc:
        raise EdgeExplorerError(f"{path}: malformed action table ({exc})") from exc
    for a in arrays:
        if a.shape != (NUM_ACTIONS, NUM_ACTIONS) or not np.isfinite(a).all():
            raise EdgeExplorerError(f"{path}: every table must be {NUM_ACTIONS}×{NUM_ACTIONS} finite numbers")
    return ActionTable(model, *arrays)


# ---- applying an action -----------------------------------------------------------------------------------------
def wrap_angle_rad(angle_rad: float) -> float:
    """Angle in [−π, π)."""
    return (angle_rad + math.pi) % (2 * math.pi) - math.pi


def body_to_map(
    x_m: float, y_m: float, yaw_rad: float, dx_body_m: float, dy_body_m: float, dyaw_rad: float
) -> tuple[float, float, float]:
    """The pose reached by a body-frame displacement from (x_m, y_m, yaw_rad) in the map frame."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return x_m + c * dx_body_m - s * dy_body_m, y_m + s * dx_body_m + c * dy_body_m, wrap_angle_rad(yaw_rad + dyaw_rad)


def step_pose(
    table: ActionTable,
    x_m: float,
    y_m: float,
    yaw_rad: float,
    previous: int,
    action: int,
    rng: np.random.Generator | None = None,
) -> tuple[float, float, float]:
    """Pose after ``action`` (preceded by ``previous``): the table's mean, plus Gaussian noise if ``rng`` is given."""
    dx, dy, dyaw = table.mean_step(previous, action)
    if rng is not None:
        pos_std = table.pos_std_m[previous, action]
        noise = rng.normal(0.0, 1.0, 3)
        dx += pos_std * noise[0]
        dy += pos_std * noise[1]
        dyaw += table.yaw_std_rad[previous, action] * noise[2]
    return body_to_map(x_m, y_m, yaw_rad, dx, dy, dyaw)


def swept_path_blocked(
    blocked: np.ndarray, grid: GridSpec, start_xy_m: tuple[float, float], end_xy_m: tuple[float, float]
) -> bool:
    """True if the straight motion from start to end enters a blocked cell (or leaves the grid).

    ``blocked`` (bool, on ``grid``) marks the cells where the vehicle's centre may not be: OCCUPIED ∪ NON_FLIGHT
    of the inflated ground truth, so the test accounts for the robot radius. The segment is sampled at most one
    cell apart, both ends included.
    """
    x0, y0 = grid.origin_xy
    res = grid.resolution_m
    return bool(
        _segment_blocked(
            blocked,
            (start_xy_m[0] - x0) / res,
            (start_xy_m[1] - y0) / res,
            (end_xy_m[0] - x0) / res,
            (end_xy_m[1] - y0) / res,
        )
    )


@njit(cache=True)
def _segment_blocked(blocked, x0_c, y0_c, x1_c, y1_c):
    """Sample the segment (cell units) at ≤ 1 cell spacing; True at the first blocked or off-grid sample."""
    n = int(math.ceil(math.hypot(x1_c - x0_c, y1_c - y0_c))) + 1
    for k in range(n + 1):
        s = k / n
        i = int(math.floor(y0_c + s * (y1_c - y0_c)))
        j = int(math.floor(x0_c + s * (x1_c - x0_c)))
        if not (0 <= i < blocked.shape[0] and 0 <= j < blocked.shape[1]) or blocked[i, j]:
            return True
    return False
