"""The frame conventions of the link: the only place where the ``map`` frame (x east, y north, z up, yaw
counter-clockwise from +x, FLU body) meets MAVLink's local NED and FRD body (docs/design.md §3). The simulated vehicle
calls these same functions."""

from __future__ import annotations

import math


def map_to_ned(x_m: float, y_m: float, z_m: float) -> tuple[float, float, float]:
    """A map-frame point or vector (x east, y north, z up) as local NED (north, east, down)."""
    return y_m, x_m, -z_m


def ned_to_map(north_m: float, east_m: float, down_m: float) -> tuple[float, float, float]:
    """A local-NED point or vector as map frame (x, y, z)."""
    return east_m, north_m, -down_m


def yaw_map_to_ned(yaw_rad: float) -> float:
    """Map yaw (counter-clockwise from east) → NED yaw (clockwise from north), wrapped to [−π, π)."""
    return _wrap_rad(math.pi / 2 - yaw_rad)


def yaw_ned_to_map(yaw_ned_rad: float) -> float:
    """NED yaw (clockwise from north) → map yaw (counter-clockwise from east), wrapped to [−π, π)."""
    return _wrap_rad(math.pi / 2 - yaw_ned_rad)


def attitude_ned_to_map(roll_rad: float, pitch_rad: float, yaw_ned_rad: float) -> tuple[float, float, float]:
    """MAVLink attitude (FRD body in NED: pitch up positive) → map (roll, pitch, yaw) of a FLU body.

    FLU pitch is positive nose *down* (rotation about body +y, which points left), FRD pitch positive nose up, so
    pitch changes sign; both conventions lower the right side for positive roll, so roll is unchanged.
    """
    return roll_rad, -pitch_rad, yaw_ned_to_map(yaw_ned_rad)


def attitude_map_to_ned(roll_rad: float, pitch_rad: float, yaw_rad: float) -> tuple[float, float, float]:
    """Map FLU (roll, pitch, yaw) → MAVLink (roll, pitch, yaw) of an FRD body in NED."""
    return roll_rad, -pitch_rad, yaw_map_to_ned(yaw_rad)


def _wrap_rad(angle_rad: float) -> float:
    return (angle_rad + math.pi) % (2 * math.pi) - math.pi


def _euler_from_quaternion(q: list[float]) -> tuple[float, float, float]:
    """(roll, pitch, yaw) of a MAVLink quaternion (w, x, y, z), ZYX convention."""
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def _rotate_frd_to_ned(roll: float, pitch: float, yaw: float, v: tuple[float, float, float]) -> tuple[float, ...]:
    """Body-FRD vector → NED with R = Rz(yaw)·Ry(pitch)·Rx(roll)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    x, y, z = v
    return (
        cy * cp * x + (cy * sp * sr - sy * cr) * y + (cy * sp * cr + sy * sr) * z,
        sy * cp * x + (sy * sp * sr + cy * cr) * y + (sy * sp * cr - cy * sr) * z,
        -sp * x + cp * sr * y + cp * cr * z,
    )
