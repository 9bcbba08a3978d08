"""Flight physics of the simulated quadrotor, without networking: what :mod:`edge_explorer.sim.vehicle` flies.

:class:`QuadrotorModel` is a point mass in the ``map`` frame that tracks a position + yaw target under speed,
acceleration and yaw-rate limits (:class:`VehicleLimits`; defaults 1 m/s, 1 m/s², 60°/s), tilts as a quadrotor does
to accelerate, and collides with the floor plan (a disc of ``radius_m`` against ``PlanRaster.occupied``: on contact
it stops at the last free position). Deterministic; tests step it directly. It is kept apart from the MAVLink
autopilot stand-in (:class:`~edge_explorer.sim.vehicle.SimulatedVehicle`), which owns one, so the dynamics can be
read and tested without threads, sockets or the wire protocol.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from edge_explorer.runtime.mavlink_link import Pose
from edge_explorer.vehicle.dynamics import wrap_angle_rad
from edge_explorer.world.raster import ROBOT_RADIUS_M, PlanRaster

GRAVITY_MPS2 = 9.81
CONTACT_RELEASE_M = 0.05


@dataclass(frozen=True)
class VehicleLimits:
    """Flight envelope: 3-D speed and acceleration, yaw rate."""

    max_speed_mps: float = 1.0
    max_accel_mps2: float = 1.0
    max_yaw_rate_rad_s: float = math.radians(60.0)


class QuadrotorModel:
    """Kinematic quadrotor in the ``map`` frame: tracks a target within :class:`VehicleLimits`, stops at walls.

    Speed toward the target follows min(v_max, √(a_max·d), 2·d): the braking profile of half the acceleration limit
    blended with a linear approach, so it arrives without overshoot while every velocity change stays within
    a_max·dt. Pitch and roll are the tilt a quadrotor needs for the applied acceleration (FLU: nose down to go
    forward, left side down to go left), through the first-order lag of an attitude loop (``TILT_TIME_CONSTANT_S``):
    the point mass's acceleration jumps between ±a_max from one physics step to the next while it tracks a setpoint
    stream, and a body cannot follow that — an instantaneous tilt would swing by ±6° at 100 Hz, which the 30 Hz
    ATTITUDE telemetry cannot describe, so a depth camera rendered at the true attitude and fused with the reported
    one would put the ceiling 4 m away half a metre too low.
    """

    APPROACH_GAIN_PER_S = 2.0
    YAW_GAIN_PER_S = 3.0
    TILT_TIME_CONSTANT_S = 0.15

    def __init__(
        self,
        x_m: float,
        y_m: float,
        z_m: float = 0.0,
        yaw_rad: float = 0.0,
        limits: VehicleLimits = VehicleLimits(),
        raster: PlanRaster | None = None,
        radius_m: float = ROBOT_RADIUS_M,
    ) -> None:
        self.limits = limits
        self.radius_m = radius_m
        self._raster = raster
        self._occupied = None if raster is None else raster.occupied
        self.position_m = [float(x_m), float(y_m), max(0.0, float(z_m))]
        self.velocity_mps = [0.0, 0.0, 0.0]
        self.yaw_rad = float(yaw_rad)
        self.yaw_rate_rad_s = 0.0
        self.pitch_rad = 0.0
        self.roll_rad = 0.0
        self._tilt_accel_mps2 = (0.0, 0.0)  # the lagged horizontal acceleration the tilt stands for
        self.target: tuple[float, float, float, float] | None = None
        self.collisions = 0
        self.in_contact = False
        if self.hits_obstacle(x_m, y_m):
            raise ValueError(f"start position ({x_m:.2f}, {y_m:.2f}) overlaps an obstacle of the plan")

    def hits_obstacle(self, x_m: float, y_m: float, radius_m: float | None = None) -> bool:
        """Whether a disc (default: the vehicle's) at (x, y) overlaps an occupied cell; outside the grid is free."""
        if self._occupied is None:
            return False
        radius_m = self.radius_m if radius_m is None else radius_m
        grid = self._raster.grid
        r = grid.resolution_m
        x0, y0 = grid.origin_xy
        rows, cols = self._occupied.shape
        c0 = max(int(math.floor((x_m - radius_m - x0) / r)), 0)
        c1 = min(int(math.floor((x_m + radius_m - x0) / r)) + 1, cols)
        r0 = max(int(math.floor((y_m - radius_m - y0) / r)), 0)
        r1 = min(int(math.floor((y_m + radius_m - y0) / r)) + 1, rows)
        if c0 >= c1 or r0 >= r1:
            return False
        window = self._occupied[r0:r1, c0:c1]
        if not window.any():
            return False
        # Distance from the disc centre to the nearest point of each occupied cell's square.
        cell_x0 = x0 + np.arange(c0, c1) * r
        cell_y0 = y0 + np.arange(r0, r1) * r
        dx = np.maximum(np.maximum(cell_x0 - x_m, x_m - (cell_x0 + r)), 0.0)
        dy = np.maximum(np.maximum(cell_y0 - y_m, y_m - (cell_y0 + r)), 0.0)
        dist2 = dy[:, None] ** 2 + dx[None, :] ** 2
        return bool((dist2[window] < radius_m**2).any())

    def step(self, dt_s: float) -> bool:
        """Advance ``dt_s`` seconds toward the target; True if this step started a collision."""
        lim = self.limits
        if self.target is None or dt_s <= 0:
            self.velocity_mps = [0.0, 0.0, 0.0]
            self.pitch_rad = self.roll_rad = self.yaw_rate_rad_s = 0.0
            self._tilt_accel_mps2 = (0.0, 0.0)
            return False
        tx, ty, tz, tyaw = self.target
        px, py, pz = self.position_m
        error = (tx - px, ty - py, max(tz, 0.0) - pz)
        distance = math.sqrt(sum(e * e for e in error))
        speed = min(lim.max_speed_mps, math.sqrt(lim.max_accel_mps2 * distance), self.APPROACH_GAIN_PER_S * distance)
        desired = [e / distance * speed for e in error] if distance > 1e-9 else [0.0, 0.0, 0.0]
        dv = [d - v for d, v in zip(desired, self.velocity_mps, strict=True)]
        dv_norm = math.sqrt(sum(d * d for d in dv))
        max_dv = lim.max_accel_mps2 * dt_s
        if dv_norm > max_dv:
            dv = [d * max_dv / dv_norm for d in dv]
        old_velocity = self.velocity_mps
        new_velocity = [v + d for v, d in zip(old_velocity, dv, strict=True)]
        new_position = [
            p + 0.5 * (v0 + v1) * dt_s for p, v0, v1 in zip(self.position_m, old_velocity, new_velocity, strict=True)
        ]
        new_position[2] = max(new_position[2], 0.0)

        yaw_error = wrap_angle_rad(tyaw - self.yaw_rad)
        self.yaw_rate_rad_s = max(-lim.max_yaw_rate_rad_s, min(lim.max_yaw_rate_rad_s, self.YAW_GAIN_PER_S * yaw_error))
        self.yaw_rad = wrap_angle_rad(self.yaw_rad + self.yaw_rate_rad_s * dt_s)

        if self.hits_obstacle(new_position[0], new_position[1]):
            started = not self.in_contact
            self.in_contact = True
            self.collisions += started
            self.velocity_mps = [0.0, 0.0, 0.0]
            self.pitch_rad = self.roll_rad = 0.0
            self._tilt_accel_mps2 = (0.0, 0.0)
            return started
        # A contact ends once the vehicle is clear of the obstacle by CONTACT_RELEASE_M, so pressing on against
        # a wall counts as one collision, not one per step.
        self.in_contact = self.in_contact and self.hits_obstacle(*new_position[:2], self.radius_m + CONTACT_RELEASE_M)
        self.position_m = new_position
        self.velocity_mps = new_velocity
        blend = 1.0 - math.exp(-dt_s / self.TILT_TIME_CONSTANT_S)
        ax, ay = (f + blend * (d / dt_s - f) for f, d in zip(self._tilt_accel_mps2, dv[:2], strict=True))
        self._tilt_accel_mps2 = (ax, ay)
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        self.pitch_rad = math.atan2(c * ax + s * ay, GRAVITY_MPS2)
        self.roll_rad = -math.atan2(-s * ax + c * ay, GRAVITY_MPS2)
        return False

    def pose(self, stamp_s: float) -> Pose:
        x, y, z = self.position_m
        vx, vy, vz = self.velocity_mps
        return Pose(stamp_s, x, y, z, self.yaw_rad, self.pitch_rad, self.roll_rad, vx, vy, vz)
