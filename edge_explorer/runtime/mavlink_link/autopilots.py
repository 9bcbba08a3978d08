"""The autopilots' start sequences and mode conventions (:class:`AutopilotStarts`, part of
:class:`~edge_explorer.runtime.mavlink_link.MavlinkLink`): PX4 offboard — stream setpoints, switch to OFFBOARD, arm
(PX4 accepts OFFBOARD only once setpoints stream, and leaves it when they stop for 0.5 s) — and ArduPilot guided —
GUIDED, arm, take off, then stream."""

from __future__ import annotations

import logging
import time

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from edge_explorer.runtime.mavlink_link.errors import LinkError

log = logging.getLogger(__name__)


PX4_OFFBOARD_MODE = "OFFBOARD"
ARDUPILOT_GUIDED_MODE = "GUIDED"


class AutopilotStarts:
    """The start sequences of :class:`~edge_explorer.runtime.mavlink_link.MavlinkLink` (see the module docstring);
    they use the link's ``wait_until``, ``hold``, ``command``, ``latest_pose`` and ``set_target``."""

    def start_offboard(self, warmup_s: float = 1.0, timeout_s: float = 10.0) -> None:
        """PX4: hold the current pose as the target, stream it for ``warmup_s``, switch to OFFBOARD, arm.

        PX4 accepts OFFBOARD only once setpoints stream, and leaves it when they stop; returns when the autopilot's
        heartbeat reports armed and OFFBOARD.
        """
        self.wait_until(lambda s: s.connected and not s.odometry_stale, timeout_s, "autopilot heartbeat and odometry")
        self.hold()
        time.sleep(warmup_s)
        base_mode, main_mode, sub_mode = mavutil.px4_map[PX4_OFFBOARD_MODE]
        self.command(mavlink2.MAV_CMD_DO_SET_MODE, base_mode, main_mode, sub_mode)
        self.arm()
        self.wait_until(lambda s: s.armed and s.mode == PX4_OFFBOARD_MODE, timeout_s, "armed in OFFBOARD")
        log.info("PX4 offboard control active")

    def start_guided(self, takeoff_altitude_m: float, timeout_s: float = 30.0) -> None:
        """ArduPilot copter: GUIDED, arm, take off to ``takeoff_altitude_m`` above home, then hold there.

        Returns once the vehicle is within 10 % of the altitude; from then on setpoints stream.
        """
        self.wait_until(lambda s: s.connected and not s.odometry_stale, timeout_s, "autopilot heartbeat and odometry")
        custom_mode = next(n for n, name in mavutil.mode_mapping_acm.items() if name == ARDUPILOT_GUIDED_MODE)
        self.command(mavlink2.MAV_CMD_DO_SET_MODE, mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom_mode)
        self.wait_until(lambda s: s.mode == ARDUPILOT_GUIDED_MODE, timeout_s, "GUIDED mode")
        self.arm()
        self.command(mavlink2.MAV_CMD_NAV_TAKEOFF, param7=takeoff_altitude_m)
        deadline = time.monotonic() + timeout_s
        while (pose := self.latest_pose()) is None or pose.z_m < 0.9 * takeoff_altitude_m:
            if time.monotonic() > deadline:
                raise LinkError(f"take-off to {takeoff_altitude_m} m did not complete in {timeout_s:.0f} s")
            time.sleep(0.05)
        self.set_target(pose.x_m, pose.y_m, takeoff_altitude_m, pose.yaw_rad)
        log.info("ArduPilot guided control active at %.2f m", takeoff_altitude_m)

    def arm(self) -> None:
        """Arm the motors (COMPONENT_ARM_DISARM); raises :class:`LinkError` if the autopilot refuses."""
        self.command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
