"""The quadrotor model: flight limits, tilt and collisions, stepped directly."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge_explorer.sim.quadrotor import QuadrotorModel, VehicleLimits
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan

# two_room_plan: 4 m × 3 m, inner wall faces at x = 0.1 / 3.9 and y = 0.1 / 2.9, a divider at x ∈ [1.95, 2.05]
# with a door at y ∈ [1, 2], a tall cabinet on x ∈ [0.1, 0.7], y ∈ [2.4, 2.9].
RASTER = rasterize(two_room_plan(), 0.05)
DT_S = 0.01


def fly(model: QuadrotorModel, seconds: float) -> np.ndarray:
    """Step the model; rows of (x, y, z, vx, vy, vz, yaw, yaw_rate)."""
    rows = []
    for _ in range(int(seconds / DT_S)):
        model.step(DT_S)
        rows.append([*model.position_m, *model.velocity_mps, model.yaw_rad, model.yaw_rate_rad_s])
    return np.array(rows)


def test_flight_respects_speed_acceleration_and_yaw_rate_limits() -> None:
    limits = VehicleLimits()
    model = QuadrotorModel(0.0, 0.0, 0.0, yaw_rad=0.0, limits=limits)
    model.target = (3.0, -2.0, 1.7, 3.0)
    track = fly(model, 8.0)
    velocity = track[:, 3:6]
    speed = np.linalg.norm(velocity, axis=1)
    accel = np.linalg.norm(np.diff(velocity, axis=0, prepend=np.zeros((1, 3))), axis=1) / DT_S
    assert speed.max() == pytest.approx(limits.max_speed_mps, rel=1e-6)  # it reaches cruise, never more
    assert speed.max() <= limits.max_speed_mps + 1e-9
    assert accel.max() <= limits.max_accel_mps2 + 1e-6
    assert np.abs(track[:, 7]).max() <= limits.max_yaw_rate_rad_s + 1e-9
    assert track[-1, :3] == pytest.approx([3.0, -2.0, 1.7], abs=1e-3)
    assert track[-1, 6] == pytest.approx(3.0, abs=1e-3)
    # No overshoot along the way: the distance to the target never grows.
    distance = np.linalg.norm(track[:, :3] - [3.0, -2.0, 1.7], axis=1)
    assert np.all(np.diff(distance) <= 1e-6)


def test_tilt_follows_acceleration_in_flu_convention() -> None:
    model = QuadrotorModel(1.0, 1.0, 1.0, yaw_rad=math.pi / 2)  # facing +y
    model.target = (1.0, 5.0, 1.0, math.pi / 2)  # straight ahead
    fly(model, 0.3)  # two time constants of the attitude lag
    assert model.pitch_rad > 0.05 and abs(model.roll_rad) < 1e-9  # nose down to speed up forward
    model = QuadrotorModel(1.0, 1.0, 1.0, yaw_rad=0.0)  # facing +x, so +y is to the left
    model.target = (1.0, 5.0, 1.0, 0.0)
    fly(model, 0.3)
    assert model.roll_rad < -0.05  # left side down (FLU: positive roll lowers the right side)


def test_tilt_stays_smooth_while_tracking_a_setpoint_stream() -> None:
    """A 20 Hz staircase of setpoints along a 0.5 m/s line makes the point mass's acceleration jump between
    ±a_max; the tilt must not (the 30 Hz ATTITUDE telemetry could not describe it, see QuadrotorModel)."""
    model = QuadrotorModel(0.0, 0.0, 1.7, yaw_rad=0.0)
    pitch = []
    for k in range(300):
        if k % 5 == 0:
            model.target = (min(0.5 * k * DT_S, 1.0), 0.0, 1.7, 0.0)
        model.step(DT_S)
        pitch.append(model.pitch_rad)
    steps = np.abs(np.diff(pitch))
    assert max(pitch) > math.radians(1.0)  # it does tilt to accelerate
    assert steps.max() < math.radians(0.5)  # by less than half a degree per 10 ms step


def test_collision_stops_at_the_last_free_position_and_counts_once_per_contact() -> None:
    model = QuadrotorModel(1.0, 1.5, 1.7, raster=RASTER)
    model.target = (-1.0, 1.5, 1.7, 0.0)  # through the west wall (inner face x = 0.1)
    fly(model, 3.0)
    assert model.collisions == 1 and model.in_contact
    assert 0.1 + model.radius_m <= model.position_m[0] < 0.1 + model.radius_m + 0.02
    assert model.velocity_mps == [0.0, 0.0, 0.0]
    model.target = (1.0, 1.5, 1.7, 0.0)
    fly(model, 5.0)
    assert not model.in_contact and model.position_m[0] == pytest.approx(1.0, abs=1e-3)
    model.target = (1.0, 5.0, 1.7, 0.0)  # into the north wall
    fly(model, 3.0)
    assert model.collisions == 2 and model.position_m[1] <= 2.9 - model.radius_m


def test_disc_overlap_is_exact_at_corners() -> None:
    model = QuadrotorModel(1.0, 1.5, raster=RASTER)
    # The cabinet's corner is (0.7, 2.4): a disc whose centre is 0.24 m away diagonally touches it, 0.26 m does not.
    d = 0.24 / math.sqrt(2)
    assert model.hits_obstacle(0.7 + d, 2.4 - d)
    d = 0.26 / math.sqrt(2)
    assert not model.hits_obstacle(0.7 + d, 2.4 - d)
    with pytest.raises(ValueError, match="overlaps an obstacle"):
        QuadrotorModel(0.2, 1.5, raster=RASTER)
