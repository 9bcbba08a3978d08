"""A real ground station accepts the link's stream: the simulated vehicle ↔ MAVProxy ↔ the link, on loopback.

MAVProxy is the router in the middle (``--master`` is the vehicle, ``--out`` the link), as on a drone whose
companion computer reaches the autopilot through it. Its own telemetry log must show the link's heartbeats (an
onboard controller) and position targets, and the vehicle must fly to the link's target through it.

Install for this test (kept out of the full install, which pulls a GUI stack):
``pip install --no-deps mavproxy && pip install pyserial``.
"""

from __future__ import annotations

import importlib.util
import math
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from edge_explorer.runtime.mavlink_link import LinkConfig, MavlinkLink, Pose
from edge_explorer.sim.quadrotor import VehicleLimits
from edge_explorer.sim.vehicle import SimulatedVehicle, VehicleConfig

pytestmark = pytest.mark.slow


def mavproxy_script() -> str | None:
    """The mavproxy.py entry script of this interpreter's environment, if MAVProxy and pyserial are installed."""
    if importlib.util.find_spec("MAVProxy") is None or importlib.util.find_spec("serial") is None:
        return None
    script = Path(sys.executable).parent / "mavproxy.py"
    return str(script) if script.exists() else shutil.which("mavproxy.py")


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.skipif(
    mavproxy_script() is None,
    reason="MAVProxy is not installed: pip install --no-deps mavproxy && pip install pyserial",
)
def test_mavproxy_routes_and_logs_the_links_heartbeats_and_position_targets(tmp_path: Path) -> None:
    master_port, out_port = free_udp_port(), free_udp_port()
    tlog = tmp_path / "mavproxy.tlog"
    command = [
        sys.executable,
        mavproxy_script(),
        f"--master=udpin:127.0.0.1:{master_port}",
        f"--out=udpout:127.0.0.1:{out_port}",
        "--daemon",
        "--nowait",
        f"--state-basedir={tmp_path}",
        f"--logfile={tlog}",
    ]
    limits = VehicleLimits(2.0, 4.0)
    mavproxy = subprocess.Popen(command, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        with (
            SimulatedVehicle(VehicleConfig(connect=f"udpout:127.0.0.1:{master_port}", limits=limits)) as vehicle,
            MavlinkLink(LinkConfig(connect=f"udpin:127.0.0.1:{out_port}")) as link,
        ):
            link.start_offboard(warmup_s=0.5, timeout_s=15.0)  # MAVProxy takes a few seconds to start
            link.set_target(0.5, -0.5, 1.0, 1.0)
            deadline = time.monotonic() + 5.0
            while math.dist(_xyz(vehicle.true_pose()), (0.5, -0.5, 1.0)) > 0.02 and time.monotonic() < deadline:
                time.sleep(0.05)
            assert math.dist(_xyz(vehicle.true_pose()), (0.5, -0.5, 1.0)) <= 0.02
            time.sleep(1.5)  # MAVProxy writes its log from a queue
    finally:
        mavproxy.send_signal(signal.SIGINT)
        try:
            output, _ = mavproxy.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            mavproxy.kill()
            output, _ = mavproxy.communicate()

    counts = {"onboard_heartbeat": 0, "position_target": 0}
    log = mavutil.mavlink_connection(str(tlog))
    while (msg := log.recv_match()) is not None:
        from_link = msg.get_srcComponent() == mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER
        if from_link and msg.get_type() == "HEARTBEAT" and msg.type == mavlink2.MAV_TYPE_ONBOARD_CONTROLLER:
            counts["onboard_heartbeat"] += 1
        if from_link and msg.get_type() == "SET_POSITION_TARGET_LOCAL_NED":
            counts["position_target"] += 1
    assert counts["onboard_heartbeat"] >= 2, output
    assert counts["position_target"] >= 20, output


def _xyz(pose: Pose) -> tuple[float, float, float]:
    return (pose.x_m, pose.y_m, pose.z_m)
