"""The receive side of the link (:class:`MessageHandling`, part of
:class:`~edge_explorer.runtime.mavlink_link.MavlinkLink`): a thread takes each datagram's messages from the
endpoint; only those of the configured autopilot system/component are acted on (the others are counted): the
heartbeat (mode, armed, link recovery), the odometry — LOCAL_POSITION_NED + ATTITUDE, or ODOMETRY — into the pose
buffer on this host's clock, COMMAND_ACKs for the waiting command, STATUSTEXT into the log."""

from __future__ import annotations

import logging
import time

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from edge_explorer.runtime.mavlink_link.frames import (
    _euler_from_quaternion,
    _rotate_frd_to_ned,
    attitude_ned_to_map,
    ned_to_map,
)
from edge_explorer.runtime.mavlink_link.transport import (
    _enum_name,
)

log = logging.getLogger(__name__)


class MessageHandling:
    """The link's receive thread and message handlers (see the module docstring); they update the link's state
    under its lock."""

    def _receive_loop(self) -> None:
        endpoint = self._require_endpoint()
        while not self._stop.is_set():
            try:
                for msg in endpoint.receive(timeout_s=0.1):
                    self._handle(msg, time.monotonic())
            except Exception:  # noqa: BLE001 - a handler bug must not kill odometry; it is logged with its trace
                log.exception("MAVLink receive loop error")

    def _handle(self, msg: mavlink2.MAVLink_message, now: float) -> None:
        cfg = self.config
        if msg.get_srcSystem() != cfg.autopilot_system_id or msg.get_srcComponent() != cfg.autopilot_component_id:
            with self._lock:
                self._messages_ignored += 1
            return
        msg_id = msg.get_msgId()
        use_odometry_msg = cfg.odometry_source == "odometry"
        with self._lock:
            self._messages_received += 1
            if msg_id == mavlink2.MAVLINK_MSG_ID_HEARTBEAT:
                self._on_heartbeat(msg, now)
            elif msg_id == mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED and not use_odometry_msg:
                stamp = self._boot_clock.to_host(msg.time_boot_ms / 1000, now)
                self._poses.add_position(stamp, ned_to_map(msg.x, msg.y, msg.z), ned_to_map(msg.vx, msg.vy, msg.vz))
                self._position_rx_s = now
            elif msg_id == mavlink2.MAVLINK_MSG_ID_ATTITUDE and not use_odometry_msg:
                stamp = self._boot_clock.to_host(msg.time_boot_ms / 1000, now)
                self._poses.add_attitude(stamp, *attitude_ned_to_map(msg.roll, msg.pitch, msg.yaw), -msg.yawspeed)
                self._attitude_rx_s = now
            elif msg_id == mavlink2.MAVLINK_MSG_ID_ODOMETRY and use_odometry_msg:
                self._on_odometry(msg, now)
            elif msg_id == mavlink2.MAVLINK_MSG_ID_COMMAND_ACK:
                self._acks[msg.command] = msg.result
                self._ack.notify_all()
                log.debug(
                    "COMMAND_ACK %s: %s", _enum_name("MAV_CMD", msg.command), _enum_name("MAV_RESULT", msg.result)
                )
        if msg_id == mavlink2.MAVLINK_MSG_ID_STATUSTEXT:
            text = msg.text.decode(errors="replace") if isinstance(msg.text, bytes) else msg.text
            level = logging.WARNING if msg.severity <= mavlink2.MAV_SEVERITY_WARNING else logging.INFO
            log.log(level, "autopilot: %s", text)

    def _on_heartbeat(self, msg: mavlink2.MAVLink_heartbeat_message, now: float) -> None:
        previous = self._heartbeat_rx_s
        if previous is None:
            log.info(
                "autopilot %d/%d heard (%s)", msg.get_srcSystem(), msg.get_srcComponent(), mavutil.mode_string_v10(msg)
            )
        elif self._link_lost:
            log.info("MAVLink link recovered after %.1f s without heartbeat", now - previous)
            self._intervals_requested_s = None  # the autopilot may have rebooted: ask for odometry again
        self._link_lost = False
        self._heartbeat = msg
        self._heartbeat_rx_s = now

    def _on_odometry(self, msg: mavlink2.MAVLink_odometry_message, now: float) -> None:
        """ODOMETRY in a local NED-aligned frame (LOCAL_NED or LOCAL_FRD) with FRD body velocities."""
        if msg.frame_id not in (mavlink2.MAV_FRAME_LOCAL_NED, mavlink2.MAV_FRAME_LOCAL_FRD):
            return
        roll, pitch, yaw_ned = _euler_from_quaternion(msg.q)
        velocity_ned = (msg.vx, msg.vy, msg.vz)
        if msg.child_frame_id == mavlink2.MAV_FRAME_BODY_FRD:  # PX4's convention: body-frame velocity
            velocity_ned = _rotate_frd_to_ned(roll, pitch, yaw_ned, velocity_ned)
        stamp = self._odometry_clock.to_host(msg.time_usec / 1e6, now)
        self._poses.add_position(stamp, ned_to_map(msg.x, msg.y, msg.z), ned_to_map(*velocity_ned))
        self._poses.add_attitude(stamp, *attitude_ned_to_map(roll, pitch, yaw_ned), -msg.yawspeed)
        self._position_rx_s = self._attitude_rx_s = now
