"""Minimum-jerk trajectories between decisions (docs/design.md §8).

Each decision turns an action into a waypoint; the daemon then flies a quintic (minimum-jerk) segment per axis —
x, y, z and unwrapped yaw — from the current commanded state to the waypoint over one step period, ending at the
action's cruise velocity so that consecutive segments join smoothly (position, velocity and acceleration
continuous), as the action table's vehicle model assumes. The setpoint stream samples the active segment.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

AXES = 4  # x_m, y_m, z_m, yaw_rad


@dataclass(frozen=True)
class TrajectoryState:
    """Position (x, y, z, yaw) and its first two derivatives, in the map frame."""

    position: np.ndarray  # (4,)
    velocity: np.ndarray  # (4,)
    acceleration: np.ndarray  # (4,)

    @staticmethod
    def at_rest(x_m: float, y_m: float, z_m: float, yaw_rad: float) -> TrajectoryState:
        return TrajectoryState(np.array([x_m, y_m, z_m, yaw_rad], float), np.zeros(AXES), np.zeros(AXES))


@dataclass(frozen=True)
class MinJerkSegment:
    """A quintic polynomial per axis over ``duration_s``; coefficients are ordered by power (c0 … c5)."""

    coeffs: np.ndarray  # (AXES, 6)
    duration_s: float

    def state_at(self, t_s: float) -> TrajectoryState:
        """The state ``t_s`` seconds into the segment (clamped to its ends)."""
        t = min(max(t_s, 0.0), self.duration_s)
        powers = t ** np.arange(6)
        d_powers = np.array([0.0, 1.0, 2 * t, 3 * t**2, 4 * t**3, 5 * t**4])
        dd_powers = np.array([0.0, 0.0, 2.0, 6 * t, 12 * t**2, 20 * t**3])
        return TrajectoryState(self.coeffs @ powers, self.coeffs @ d_powers, self.coeffs @ dd_powers)

    def sample_positions(self, dt_s: float) -> np.ndarray:
        """(N, AXES) positions every ``dt_s`` seconds, both ends included — for safety checks and plots."""
        times = np.append(np.arange(0.0, self.duration_s, dt_s), self.duration_s)
        return np.stack([self.state_at(float(t)).position for t in times])

    def peak_speed_m_s(self, dt_s: float = 0.02) -> float:
        times = np.append(np.arange(0.0, self.duration_s, dt_s), self.duration_s)
        return max(float(np.hypot(*self.state_at(float(t)).velocity[:2])) for t in times)


def min_jerk_segment(start: TrajectoryState, end: TrajectoryState, duration_s: float) -> MinJerkSegment:
    """The quintic that matches position, velocity and acceleration at both ends.

    Yaw is interpolated along the shorter way round: the end yaw is unwrapped to within π of the start yaw.
    """
    if not (duration_s > 0 and math.isfinite(duration_s)):
        raise ValueError(f"duration_s must be positive, got {duration_s}")
    p0, v0, a0 = start.position, start.velocity, start.acceleration
    p1 = end.position.copy()
    p1[3] = p0[3] + (p1[3] - p0[3] + math.pi) % (2 * math.pi) - math.pi
    v1, a1 = end.velocity, end.acceleration
    if not all(np.isfinite(v).all() for v in (p0, v0, a0, p1, v1, a1)):
        raise ValueError("trajectory end states must be finite")
    T = duration_s
    dp = p1 - p0
    c3 = (20 * dp - (8 * v1 + 12 * v0) * T - (3 * a0 - a1) * T**2) / (2 * T**3)
    c4 = (-30 * dp + (14 * v1 + 16 * v0) * T + (3 * a0 - 2 * a1) * T**2) / (2 * T**4)
    c5 = (12 * dp - 6 * (v1 + v0) * T - (a0 - a1) * T**2) / (2 * T**5)
    coeffs = np.stack([p0, v0, a0 / 2, c3, c4, c5], axis=1)
    return MinJerkSegment(coeffs, T)
