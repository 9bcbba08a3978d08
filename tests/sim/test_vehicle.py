"""The simulated vehicle: the autopilot behaviour over MAVLink (collisions, offboard and hold, odometry noise)."""

from __future__ import annotations

import logging
import math
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from edge_explorer.runtime.mavlink_link import LinkConfig, LinkError, MavlinkLink
from edge_explorer.sim.quadrotor import VehicleLimits
from edge_explorer.sim.vehicle import OdometryNoise, SimulatedVehicle, VehicleConfig
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan

# two_room_plan: 4 m × 3 m, inner wall faces at x = 0.1 / 3.9 and y = 0.1 / 2.9, a divider at x ∈ [1.95, 2.05]
# with a door at y ∈ [1, 2], a tall cabinet on x ∈ [0.1, 0.7], y ∈ [2.4, 2.9].
RASTER = rasterize(two_room_plan(), 0.05)


def test_vehicle_reports_collisions_over_mavlink(caplog: pytest.LogCaptureFixture) -> None:
    config = VehicleConfig(start_xyz_m=(1.0, 1.5, 0.0), limits=VehicleLimits(2.0, 4.0))
    with (
        caplog.at_level(logging.WARNING, logger="edge_explorer.runtime.mavlink_link"),
        SimulatedVehicle(config, RASTER) as vehicle,
        MavlinkLink(LinkConfig(connect=f"udpout:127.0.0.1:{vehicle.address[1]}")) as link,
    ):
        link.start_offboard(warmup_s=0.2, timeout_s=3.0)
        link.set_target(-1.0, 1.5, 1.0, 0.0)
        deadline = time.monotonic() + 4.0
        while vehicle.state().collisions == 0 and time.monotonic() < deadline:
            time.sleep(0.02)
        time.sleep(0.1)
        assert vehicle.state().collisions == 1 and vehicle.state().in_contact
        assert vehicle.true_pose().x_m >= 0.1 + config.radius_m
    assert any("autopilot: collision at x=0.3" in m for m in caplog.messages)


def test_offboard_needs_setpoints_and_falls_back_to_hold_when_they_stop() -> None:
    with SimulatedVehicle(VehicleConfig(start_xyz_m=(1.0, 1.0, 0.0), limits=VehicleLimits(2.0, 4.0))) as vehicle:
        link = MavlinkLink(LinkConfig(connect=f"udpout:127.0.0.1:{vehicle.address[1]}")).start()
        link.wait_until(lambda s: s.healthy, 3.0, "connection")
        link.arm()
        with pytest.raises(LinkError, match="TEMPORARILY_REJECTED"):
            link.command(mavlink2.MAV_CMD_DO_SET_MODE, 1, 6, 0)  # OFFBOARD before any setpoint
        link.start_offboard(warmup_s=0.2, timeout_s=3.0)
        link.set_target(1.0, 1.0, 0.5, 0.0)
        time.sleep(1.0)
        with pytest.raises(LinkError, match="refused MAV_CMD_COMPONENT_ARM_DISARM: MAV_RESULT_DENIED"):
            link.command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0.0)  # disarm in flight
        link.stop()  # the setpoint stream ends (after one hold setpoint)
        time.sleep(0.8)
        state = vehicle.state()
        assert state.mode == "LOITER" and state.armed
        z = vehicle.true_pose().z_m
        time.sleep(0.3)
        assert vehicle.true_pose().z_m == pytest.approx(z, abs=0.01)  # holding, not falling


def test_odometry_noise_drifts_the_reported_pose_not_the_truth() -> None:
    noise = OdometryNoise(position_sigma_m=0.0, yaw_sigma_rad=0.0, position_drift_m_per_sqrt_s=0.2, seed=3)
    config = VehicleConfig(start_xyz_m=(1.0, 1.0, 0.0), odometry_noise=noise)
    with (
        SimulatedVehicle(config) as vehicle,
        MavlinkLink(LinkConfig(connect=f"udpout:127.0.0.1:{vehicle.address[1]}")) as link,
    ):
        link.wait_until(lambda s: s.healthy, 3.0, "connection")
        time.sleep(1.0)
        truth, reported = vehicle.true_pose(), link.latest_pose()
        assert (truth.x_m, truth.y_m) == (1.0, 1.0)
        assert 0.005 < math.dist((truth.x_m, truth.y_m), (reported.x_m, reported.y_m)) < 1.0
