"""The MAVLink link against the simulated vehicle over real UDP on 127.0.0.1 (ephemeral ports)."""

from __future__ import annotations

import logging
import math
import socket
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from edge_explorer.runtime.mavlink_link import (
    LinkConfig,
    LinkError,
    MavlinkLink,
    Pose,
    _euler_from_quaternion,
    _rotate_frd_to_ned,
    attitude_map_to_ned,
    attitude_ned_to_map,
    map_to_ned,
    ned_to_map,
    yaw_map_to_ned,
    yaw_ned_to_map,
)
from edge_explorer.sim.quadrotor import VehicleLimits
from edge_explorer.sim.vehicle import SimulatedVehicle, VehicleConfig, _quaternion_from_euler
from edge_explorer.vehicle.camera import body_rotation

FAST = VehicleLimits(max_speed_mps=2.0, max_accel_mps2=4.0, max_yaw_rate_rad_s=math.radians(180))
START = (1.0, 2.0, 0.0)
KEY_HEX = "00112233445566778899aabbccddeeff00112233445566778899aabbccddeeff"


def vehicle_config(**overrides: object) -> VehicleConfig:
    return VehicleConfig(**{"start_xyz_m": START, "start_yaw_rad": 0.3, "limits": FAST, **overrides})


def link_config(vehicle: SimulatedVehicle, **overrides: object) -> LinkConfig:
    return LinkConfig(**{"connect": f"udpout:127.0.0.1:{vehicle.address[1]}", **overrides})


@pytest.fixture
def vehicle() -> Iterator[SimulatedVehicle]:
    with SimulatedVehicle(vehicle_config()) as v:
        yield v


@pytest.fixture
def link(vehicle: SimulatedVehicle, tmp_path: Path) -> Iterator[MavlinkLink]:
    with MavlinkLink(link_config(vehicle, odometry_rate_hz=40.0, tlog_path=tmp_path / "link.tlog")) as lk:
        lk.wait_until(lambda s: s.connected and not s.odometry_stale, 5.0, "connection")
        yield lk


def wait_for(condition: Callable[[], bool], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.02)
    return condition()


def test_enu_ned_conventions() -> None:
    # Positions and vectors: north = y, east = x, down = −z, and back.
    assert map_to_ned(1.0, 2.0, 3.0) == (2.0, 1.0, -3.0)
    assert ned_to_map(*map_to_ned(1.0, 2.0, 3.0)) == (1.0, 2.0, 3.0)
    # Yaw: facing east is 0 in map and π/2 in NED; facing north is π/2 in map and 0 in NED.
    assert yaw_map_to_ned(0.0) == pytest.approx(math.pi / 2)
    assert yaw_map_to_ned(math.pi / 2) == pytest.approx(0.0)
    assert yaw_ned_to_map(yaw_map_to_ned(2.5)) == pytest.approx(2.5)
    # Full attitude: R_map_flu = T · R_ned_frd · F, with T swapping NED→ENU axes and F flipping FLU→FRD.
    enu_from_ned = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    frd_from_flu = np.diag([1.0, -1.0, -1.0])
    rng = np.random.default_rng(0)
    for roll, pitch, yaw in rng.uniform(-1.2, 1.2, size=(20, 3)):
        r_ned_frd = body_rotation(*attitude_map_to_ned(roll, pitch, yaw)[::-1])
        np.testing.assert_allclose(enu_from_ned @ r_ned_frd @ frd_from_flu, body_rotation(yaw, pitch, roll), atol=1e-12)
        assert attitude_ned_to_map(*attitude_map_to_ned(roll, pitch, yaw)) == pytest.approx((roll, pitch, yaw))


def test_odometry_body_velocity_and_quaternion_helpers() -> None:
    # PX4 sends ODOMETRY velocities in the body FRD frame: facing east (NED yaw π/2), forward is east.
    assert _rotate_frd_to_ned(0.0, 0.0, math.pi / 2, (1.0, 0.0, 0.0)) == pytest.approx((0.0, 1.0, 0.0), abs=1e-12)
    assert _rotate_frd_to_ned(0.0, math.pi / 2, 0.0, (1.0, 0.0, 0.0)) == pytest.approx((0.0, 0.0, -1.0), abs=1e-12)
    q = _quaternion_from_euler(0.1, -0.2, 2.5)
    assert _euler_from_quaternion(q) == pytest.approx((0.1, -0.2, 2.5), abs=1e-12)


def test_heartbeats_both_ways_and_requested_odometry_rate(vehicle: SimulatedVehicle, link: MavlinkLink) -> None:
    assert wait_for(lambda: vehicle.state().companion_heartbeats >= 1, 2.0)
    status = link.status()
    assert status.connected and not status.link_lost and status.mode == "LOITER" and not status.armed
    assert wait_for(lambda: vehicle.state().stream_rates_hz["LOCAL_POSITION_NED"] == 40.0, 2.0)
    assert vehicle.state().stream_rates_hz["ATTITUDE"] == 40.0
    before, t0 = link.status().messages_received, time.monotonic()
    time.sleep(1.0)
    per_s = (link.status().messages_received - before) / (time.monotonic() - t0)
    assert 70 <= per_s <= 90  # LOCAL_POSITION_NED + ATTITUDE at 40 Hz each, plus a heartbeat


def test_offboard_flight_converges_with_ned_on_the_wire(
    vehicle: SimulatedVehicle, link: MavlinkLink, tmp_path: Path
) -> None:
    link.start_offboard(warmup_s=0.3, timeout_s=3.0)
    status = link.status()
    assert status.armed and status.mode == "OFFBOARD"
    target = (1.8, 1.4, 1.0, 2.0)  # east and south of the start, climbing, yaw ≈ 115° (north-west)
    link.set_target(*target)
    assert wait_for(lambda: near(link, target[:3], 0.02), 5.0)
    time.sleep(0.3)
    pose, truth = link.latest_pose(), vehicle.true_pose()
    assert _xyz(pose) == pytest.approx(target[:3], abs=0.02) and pose.yaw_rad == pytest.approx(target[3], abs=0.02)
    assert _xyz(truth) == pytest.approx(target[:3], abs=0.02) and truth.yaw_rad == pytest.approx(target[3], abs=0.02)
    rate_hz = vehicle.state().setpoint_rate_hz
    assert rate_hz >= 10.0
    link.stop()

    # Read the wire back from the .tlog: the vehicle's NED odometry and the link's NED setpoints.
    log = mavutil.mavlink_connection(str(tmp_path / "link.tlog"))
    last: dict[str, object] = {}
    counts: dict[str, int] = {}
    while (msg := log.recv_match()) is not None:
        last[msg.get_type()] = msg
        counts[msg.get_type()] = counts.get(msg.get_type(), 0) + 1
    assert counts["HEARTBEAT"] >= 2 and counts["SET_POSITION_TARGET_LOCAL_NED"] >= 10
    setpoint, lpn, att = last["SET_POSITION_TARGET_LOCAL_NED"], last["LOCAL_POSITION_NED"], last["ATTITUDE"]
    assert (setpoint.x, setpoint.y, setpoint.z) == pytest.approx((truth.y_m, truth.x_m, -truth.z_m), abs=0.03)
    assert setpoint.type_mask == 2552 and setpoint.coordinate_frame == mavlink2.MAV_FRAME_LOCAL_NED
    assert (lpn.x, lpn.y, lpn.z) == pytest.approx((1.4, 1.8, -1.0), abs=0.02)  # north, east, down
    assert att.yaw == pytest.approx(math.pi / 2 - 2.0, abs=0.02)  # clockwise from north


def test_pose_at_aligns_odometry_with_host_time(vehicle: SimulatedVehicle, link: MavlinkLink) -> None:
    link.start_offboard(warmup_s=0.3, timeout_s=3.0)
    link.set_target(8.0, 2.0, 0.0, 0.3)  # a long straight run at up to 2 m/s
    time.sleep(0.8)
    truths = []
    for _ in range(10):
        truths.append(vehicle.true_pose())
        time.sleep(0.013)
    time.sleep(0.1)  # let the odometry after the last sample arrive
    errors = [math.dist(_xyz(link.pose_at(t.stamp_s)), _xyz(t)) for t in truths]
    assert max(errors) < 0.01  # 1 cm at 2 m/s: odometry and host stamps agree within 5 ms (measured: < 1 mm)
    assert link.pose_at(time.monotonic() - 60.0) is None  # older than the buffer
    assert link.pose_at(time.monotonic() + 1.0) is None  # beyond the extrapolation limit


def test_garbage_datagrams_are_counted_and_dropped(vehicle: SimulatedVehicle, link: MavlinkLink) -> None:
    rng = np.random.default_rng(7)
    packer = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    valid = bytes(packer.heartbeat_encode(2, 12, 0, 0, 4).pack(packer))
    datagrams = []
    for i in range(10_000):
        kind = i % 4
        if kind == 0:  # random bytes
            datagrams.append(rng.integers(0, 256, size=int(rng.integers(1, 300)), dtype=np.uint8).tobytes())
        elif kind == 1:  # a valid heartbeat cut short
            datagrams.append(valid[: int(rng.integers(1, len(valid)))])
        elif kind == 2:  # a valid heartbeat with one byte changed (bad magic, length, id or CRC)
            data = bytearray(valid)
            data[int(rng.integers(0, len(data)))] ^= int(rng.integers(1, 256))
            datagrams.append(bytes(data))
        else:  # a MAVLink 2 start byte followed by noise
            datagrams.append(b"\xfd" + rng.integers(0, 256, size=int(rng.integers(1, 60)), dtype=np.uint8).tobytes())
    port = link.local_address[1]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as fuzzer:
        for start in range(0, len(datagrams), 500):
            for data in datagrams[start : start + 500]:
                fuzzer.sendto(data, ("127.0.0.1", port))
            assert wait_for(lambda n=start + 500: link.status().datagrams_bad >= n, 3.0)
    status = link.status()
    assert status.datagrams_bad == 10_000
    assert status.connected and not status.odometry_stale  # still flying on good data
    received = status.messages_received
    assert wait_for(lambda: link.status().messages_received > received + 20, 2.0)


def test_heartbeat_loss_and_stale_odometry_are_detected_and_recovered(
    vehicle: SimulatedVehicle, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    config = link_config(vehicle, link_lost_after_s=1.0, odometry_stale_after_s=0.3)
    with caplog.at_level(logging.INFO, logger="edge_explorer.runtime.mavlink_link"), MavlinkLink(config) as link:
        link.wait_until(lambda s: s.healthy, 3.0, "connection")
        port = vehicle.address[1]
        vehicle.stop()  # the autopilot goes silent
        stale = link.wait_until(lambda s: s.odometry_stale, 1.0, "stale odometry")
        assert stale.connected and not stale.link_lost and not stale.healthy  # stale after 0.3 s, before the loss
        lost = link.wait_until(lambda s: s.link_lost, 2.0, "link loss")
        assert not lost.connected and lost.heartbeat_age_s > 1.0
        time.sleep(0.5)
        with SimulatedVehicle(vehicle_config(connect=f"udpin:127.0.0.1:{port}")):  # back (rebooted) on its port
            recovered = link.wait_until(lambda s: s.healthy and not s.link_lost, 3.0, "recovery")
            assert recovered.connected
            assert link.latest_pose() is not None and abs(link.latest_pose().stamp_s - time.monotonic()) < 0.2
    assert any("link lost" in m for m in caplog.messages)
    assert any("odometry stale" in m for m in caplog.messages)
    assert any("link recovered" in m for m in caplog.messages)


def test_a_process_stall_shows_as_a_setpoint_stream_stall(link: MavlinkLink, caplog: pytest.LogCaptureFixture) -> None:
    """When this process gets no CPU time (here: one thread keeps the GIL for 0.8 s), the setpoint stream pauses
    past PX4's 2 Hz rule; the link says so, with the gap, in its status and its log."""
    link.wait_until(lambda s: s.healthy, 3.0, "connection")
    link.set_target(1.0, 1.0, 1.7, 0.0)
    assert wait_for(lambda: link.status().setpoints_sent > 5, 2.0)
    assert link.status().setpoint_stall is None
    interval = sys.getswitchinterval()
    sys.setswitchinterval(5.0)
    try:
        end = time.monotonic() + 0.8
        while time.monotonic() < end:  # holds the GIL: no other thread of the process runs
            pass
    finally:
        sys.setswitchinterval(interval)
    with caplog.at_level(logging.WARNING, logger="edge_explorer.runtime.mavlink_link"):
        assert wait_for(lambda: link.status().setpoint_stall is not None, 2.0)
    resumed_s, gap_s = link.status().setpoint_stall
    assert 0.5 <= gap_s < 2.0 and time.monotonic() - resumed_s < 2.0
    assert any("setpoint stream stalled" in m for m in caplog.messages)


def test_signing_both_sides_and_unsigned_peer_ignored() -> None:
    with SimulatedVehicle(vehicle_config(signing_key=KEY_HEX)) as vehicle:
        with MavlinkLink(link_config(vehicle, signing_key=KEY_HEX)) as link:
            status = link.wait_until(lambda s: s.healthy, 3.0, "signed connection")
            assert status.signature_rejected == 0
            assert wait_for(lambda: vehicle.state().companion_heartbeats >= 1, 2.0)
    with SimulatedVehicle(vehicle_config()) as unsigned_vehicle:
        with MavlinkLink(link_config(unsigned_vehicle, signing_key=KEY_HEX)) as link:
            assert wait_for(lambda: link.status().signature_rejected >= 3, 3.0)
            status = link.status()
            assert not status.connected and status.messages_received == 0
            # The unsigned vehicle decodes the signed heartbeats (it has no key to check) but the link hears nothing.


def test_signed_vehicle_ignores_an_unsigned_link() -> None:
    with SimulatedVehicle(vehicle_config(signing_key=KEY_HEX)) as vehicle, MavlinkLink(link_config(vehicle)) as link:
        time.sleep(1.5)
        assert vehicle.state().companion_heartbeats == 0
        assert not link.status().connected


def test_guided_start_sequence_on_an_ardupilot_vehicle() -> None:
    with (
        SimulatedVehicle(vehicle_config(flavour="ardupilot")) as vehicle,
        MavlinkLink(link_config(vehicle)) as link,
    ):
        link.start_guided(takeoff_altitude_m=1.0, timeout_s=5.0)
        status = link.status()
        assert status.armed and status.mode == "GUIDED"
        assert vehicle.true_pose().z_m >= 0.9
        link.set_target(1.5, 2.0, 1.0, 0.3)
        assert wait_for(lambda: abs(vehicle.true_pose().x_m - 1.5) < 0.02, 3.0)


def test_odometry_message_source(vehicle: SimulatedVehicle) -> None:
    with MavlinkLink(link_config(vehicle, odometry_source="odometry", odometry_rate_hz=30.0)) as link:
        link.wait_until(lambda s: s.healthy, 3.0, "odometry")
        assert wait_for(lambda: vehicle.state().stream_rates_hz["ODOMETRY"] == pytest.approx(30.0), 2.0)
        pose, truth = link.latest_pose(), vehicle.true_pose()
        assert _xyz(pose) == pytest.approx(_xyz(truth), abs=1e-3) and pose.yaw_rad == pytest.approx(0.3, abs=1e-3)


def test_refused_commands_and_bad_configuration_raise_clear_errors(link: MavlinkLink) -> None:
    with pytest.raises(LinkError, match="autopilot refused MAV_CMD_DO_SET_MODE: MAV_RESULT_TEMPORARILY_REJECTED"):
        base, main, sub = mavutil.px4_map["OFFBOARD"]
        link.command(mavlink2.MAV_CMD_DO_SET_MODE, base, main, sub)  # no setpoints streaming yet
    with pytest.raises(ValueError, match="finite"):
        link.set_target(0.0, math.nan, 1.0, 0.0)
    with pytest.raises(LinkError, match="unsupported MAVLink connection"):
        LinkConfig(connect="/dev/ttyACM0:921600")
    with pytest.raises(LinkError, match="not 64 hex digits and no such file"):
        MavlinkLink(LinkConfig(signing_key="no-such-key-file"))


def _xyz(pose: Pose) -> tuple[float, float, float]:
    return (pose.x_m, pose.y_m, pose.z_m)


def near(link: MavlinkLink, xyz: tuple[float, ...], tolerance_m: float) -> bool:
    pose = link.latest_pose()
    return pose is not None and math.dist(_xyz(pose), xyz) < tolerance_m
