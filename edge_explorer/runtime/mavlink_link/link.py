"""The daemon's MAVLink connection (:class:`MavlinkLink`): its configuration (:class:`LinkConfig`), health
(:class:`LinkStatus`), the send thread (heartbeat at 1 Hz as ``MAV_TYPE_ONBOARD_CONTROLLER``, the setpoint stream —
SET_POSITION_TARGET_LOCAL_NED, position + yaw, ``type_mask`` 2552, at ``setpoint_rate_hz`` — and the odometry
requests), commands with their acknowledgement, and the health watch (link loss: no autopilot heartbeat for
``link_lost_after_s``; stale odometry: newest sample older than ``odometry_stale_after_s``; logged on every
transition). Receiving is :mod:`.receive`, the start sequences :mod:`.autopilots`."""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from edge_explorer.runtime.mavlink_link.autopilots import AutopilotStarts
from edge_explorer.runtime.mavlink_link.errors import LinkError
from edge_explorer.runtime.mavlink_link.frames import (
    _wrap_rad,
    map_to_ned,
    yaw_map_to_ned,
)
from edge_explorer.runtime.mavlink_link.poses import Pose, _ClockSync, _PoseBuffer
from edge_explorer.runtime.mavlink_link.receive import MessageHandling
from edge_explorer.runtime.mavlink_link.signing import load_signing_key
from edge_explorer.runtime.mavlink_link.transport import (
    MavlinkEndpoint,
    TlogWriter,
    _enum_name,
    parse_connect,
)

log = logging.getLogger(__name__)


# position + yaw: ignore velocity (bits 3-5), acceleration (6-8) and yaw rate (11); use x, y, z (0-2) and yaw (10).
TYPE_MASK_POSITION_YAW = 2552
STREAM_STALL_S = 0.5  # a setpoint gap this long breaks PX4's > 2 Hz offboard rule


@dataclass(frozen=True)
class LinkConfig:
    """Where the autopilot is and how to talk to it.

    ``connect``: ``udpin:0.0.0.0:14540`` listens where PX4's onboard link sends (SITL and most companion setups);
    ``udpout:HOST:PORT`` sends to an autopilot (or router) that listens. ``signing_key``: 64 hex digits or a key
    file (see :func:`load_signing_key`); ``None`` disables signing. ``tlog_path``: where to record the link.
    """

    connect: str = "udpin:0.0.0.0:14540"
    system_id: int = 1  # companion computers share the autopilot's system id, with their own component id
    component_id: int = mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER
    autopilot_system_id: int = 1
    autopilot_component_id: int = mavlink2.MAV_COMP_ID_AUTOPILOT1
    setpoint_rate_hz: float = 20.0
    odometry_rate_hz: float = 50.0
    odometry_source: str = "local_position_ned"  # or "odometry": request and use ODOMETRY instead of LPN + ATTITUDE
    link_lost_after_s: float = 2.0
    odometry_stale_after_s: float = 0.3
    pose_horizon_s: float = 5.0
    max_extrapolation_s: float = 0.1
    command_timeout_s: float = 1.0
    command_attempts: int = 3
    signing_key: str | None = None
    tlog_path: Path | None = None

    def __post_init__(self) -> None:
        parse_connect(self.connect)
        if not self.setpoint_rate_hz >= 2.0:
            raise LinkError(
                f"setpoint_rate_hz must be ≥ 2 (PX4 leaves offboard below 2 Hz), got {self.setpoint_rate_hz}"
            )
        if not self.odometry_rate_hz > 0:
            raise LinkError(f"odometry_rate_hz must be positive, got {self.odometry_rate_hz}")
        if self.odometry_source not in ("local_position_ned", "odometry"):
            raise LinkError(f"odometry_source must be 'local_position_ned' or 'odometry', got {self.odometry_source!r}")


@dataclass(frozen=True)
class LinkStatus:
    """A snapshot of the link's health. Ages are seconds; ``None`` when nothing has been received yet."""

    connected: bool  # an autopilot heartbeat arrived within link_lost_after_s
    link_lost: bool  # the autopilot was heard before and its heartbeat has been missing since
    odometry_stale: bool  # no odometry yet, or the newest is older than odometry_stale_after_s
    armed: bool
    mode: str  # the autopilot's mode name ("OFFBOARD", "GUIDED", "LOITER", ...); "" before the first heartbeat
    heartbeat_age_s: float | None
    odometry_age_s: float | None
    setpoints_sent: int
    messages_received: int  # valid messages from the autopilot
    messages_ignored: int  # valid messages from other systems or components
    datagrams_bad: int  # malformed, truncated, CRC-failed or unknown datagrams
    signature_rejected: int  # unsigned or wrongly signed messages dropped while signing is on
    # The latest gap of at least STREAM_STALL_S between two setpoints this link sent (PX4 leaves offboard below 2 Hz):
    # (host time the stream resumed, gap in seconds); None if there was none. This process was starved of CPU.
    setpoint_stall: tuple[float, float] | None = None

    @property
    def healthy(self) -> bool:
        """Safe to fly new waypoints: the autopilot is heard and the odometry is fresh."""
        return self.connected and not self.odometry_stale


@dataclass(frozen=True)
class _Target:
    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float


class MavlinkLink(AutopilotStarts, MessageHandling):
    """The daemon's MAVLink connection. ``with MavlinkLink(config) as link: link.start_offboard(); ...``.

    Threads: one receives and parses, one sends the heartbeat and the setpoint stream. Public methods are
    thread-safe; positions and yaw are in the ``map`` frame.
    """

    def __init__(self, config: LinkConfig = LinkConfig()) -> None:
        self.config = config
        self._key = load_signing_key(config.signing_key) if config.signing_key else None
        self._lock = threading.Lock()
        self._ack = threading.Condition(self._lock)
        self._acks: dict[int, int] = {}  # command id → MAV_RESULT of its latest COMMAND_ACK
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._endpoint: MavlinkEndpoint | None = None
        self._tlog: TlogWriter | None = None
        self._start_s = time.monotonic()
        self._poses = _PoseBuffer(config.pose_horizon_s, config.max_extrapolation_s)
        self._boot_clock = _ClockSync()
        self._odometry_clock = _ClockSync()
        self._target: _Target | None = None
        self._heartbeat: mavlink2.MAVLink_heartbeat_message | None = None
        self._heartbeat_rx_s: float | None = None
        self._position_rx_s: float | None = None  # host arrival times of the newest position and attitude
        self._attitude_rx_s: float | None = None
        self._link_lost = False
        self._odometry_stale_logged = False
        self._intervals_requested_s: float | None = None
        self._setpoints_sent = 0
        self._last_setpoint_s: float | None = None
        self._setpoint_stall: tuple[float, float] | None = None
        self._messages_received = 0
        self._messages_ignored = 0

    def start(self) -> MavlinkLink:
        """Open the socket and the log, start the receive and send threads. Returns ``self``."""
        if self._endpoint is not None:
            raise LinkError("the link is already started")
        cfg = self.config
        self._tlog = TlogWriter(Path(cfg.tlog_path)) if cfg.tlog_path else None
        self._endpoint = MavlinkEndpoint(
            cfg.connect, cfg.system_id, cfg.component_id, self._key, self._tlog, peer_system_id=cfg.autopilot_system_id
        )
        self._stop.clear()
        self._threads = [
            threading.Thread(target=self._receive_loop, name="mavlink-rx", daemon=True),
            threading.Thread(target=self._send_loop, name="mavlink-tx", daemon=True),
        ]
        for thread in self._threads:
            thread.start()
        log.info("MAVLink link on %s (local %s:%d)", cfg.connect, *self._endpoint.local_address)
        return self

    def stop(self) -> None:
        """Send a hold setpoint at the current position, stop the threads, close the socket and the log."""
        if self._endpoint is None:
            return
        pose = self.latest_pose()
        if pose is not None:
            self._target = _Target(pose.x_m, pose.y_m, pose.z_m, pose.yaw_rad)
        if self._target is not None:
            self._send_setpoint(self._target)
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=2.0)
        self._endpoint.close()
        self._endpoint = None
        if self._tlog is not None:
            self._tlog.close()
        log.info("MAVLink link closed")

    def __enter__(self) -> MavlinkLink:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def local_address(self) -> tuple[str, int]:
        """(host, port) of the link's own socket (useful with ephemeral ports)."""
        return self._require_endpoint().local_address

    def set_target(self, x_m: float, y_m: float, z_m: float, yaw_rad: float) -> None:
        """Stream this position + yaw (map frame) from now on, until the next target."""
        values = (x_m, y_m, z_m, yaw_rad)
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"setpoint must be finite, got x={x_m}, y={y_m}, z={z_m}, yaw={yaw_rad}")
        self._target = _Target(float(x_m), float(y_m), float(z_m), _wrap_rad(float(yaw_rad)))

    def hold(self) -> None:
        """Stream the latest known pose as the target: stop where the vehicle is (or last was, if odometry is stale)."""
        pose = self.latest_pose()
        if pose is None:
            raise LinkError("cannot hold: no odometry received from the autopilot yet")
        self.set_target(pose.x_m, pose.y_m, pose.z_m, pose.yaw_rad)

    @property
    def target(self) -> tuple[float, float, float, float] | None:
        """The target being streamed, (x_m, y_m, z_m, yaw_rad), or None before the first one."""
        t = self._target
        return None if t is None else (t.x_m, t.y_m, t.z_m, t.yaw_rad)

    def pose_at(self, t_s: float) -> Pose | None:
        """The pose at host time ``t_s`` (``time.monotonic()``), interpolated; None outside the buffer."""
        with self._lock:
            return self._poses.pose_at(t_s)

    def latest_pose(self) -> Pose | None:
        """The newest pose for which both position and attitude are known."""
        with self._lock:
            newest = self._poses.newest_stamp_s()
            return None if newest is None else self._poses.pose_at(newest)

    def status(self) -> LinkStatus:
        now = time.monotonic()
        cfg = self.config
        endpoint = self._endpoint
        with self._lock:
            hb_age = None if self._heartbeat_rx_s is None else now - self._heartbeat_rx_s
            odo_rx = self._odometry_rx_s()
            odo_age = None if odo_rx is None else now - odo_rx
            hb = self._heartbeat
            return LinkStatus(
                connected=hb_age is not None and hb_age <= cfg.link_lost_after_s,
                link_lost=self._link_lost,
                odometry_stale=odo_age is None or odo_age > cfg.odometry_stale_after_s,
                armed=hb is not None and bool(hb.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED),
                mode="" if hb is None else mavutil.mode_string_v10(hb),
                heartbeat_age_s=hb_age,
                odometry_age_s=odo_age,
                setpoints_sent=self._setpoints_sent,
                setpoint_stall=self._setpoint_stall,
                messages_received=self._messages_received,
                messages_ignored=self._messages_ignored,
                datagrams_bad=0 if endpoint is None else endpoint.datagrams_bad,
                signature_rejected=0 if endpoint is None else endpoint.signature_rejected,
            )

    def wait_until(self, condition: Callable[[LinkStatus], bool], timeout_s: float, what: str) -> LinkStatus:
        """Poll :meth:`status` until ``condition(status)`` holds; raise :class:`LinkError` naming ``what`` if not."""
        deadline = time.monotonic() + timeout_s
        while True:
            status = self.status()
            if condition(status):
                return status
            if time.monotonic() > deadline:
                raise LinkError(f"timed out after {timeout_s:.1f} s waiting for {what} (link status: {status})")
            time.sleep(0.02)

    def command(
        self,
        command: int,
        param1: float = 0.0,
        param2: float = 0.0,
        param3: float = 0.0,
        param4: float = 0.0,
        param5: float = 0.0,
        param6: float = 0.0,
        param7: float = 0.0,
    ) -> None:
        """Send a COMMAND_LONG to the autopilot and wait for its COMMAND_ACK (retrying ``command_attempts`` times).

        Raises :class:`LinkError` naming the command and the autopilot's answer unless it is ACCEPTED.
        """
        cfg = self.config
        name = _enum_name("MAV_CMD", command)
        for attempt in range(cfg.command_attempts):
            with self._lock:
                self._acks.pop(command, None)
            self._send_command(command, attempt, (param1, param2, param3, param4, param5, param6, param7))
            deadline = time.monotonic() + cfg.command_timeout_s
            with self._ack:
                while (result := self._acks.get(command)) in (None, mavlink2.MAV_RESULT_IN_PROGRESS):
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        break
                    self._ack.wait(remaining)
            if result == mavlink2.MAV_RESULT_ACCEPTED:
                log.info("%s accepted", name)
                return
            if result is not None and result != mavlink2.MAV_RESULT_IN_PROGRESS:
                raise LinkError(f"autopilot refused {name}: {_enum_name('MAV_RESULT', result)}")
        raise LinkError(f"no COMMAND_ACK for {name} after {cfg.command_attempts} attempts")

    def _require_endpoint(self) -> MavlinkEndpoint:
        if self._endpoint is None:
            raise LinkError("the link is not started: call start() first")
        return self._endpoint

    def _boot_ms(self) -> int:
        return int((time.monotonic() - self._start_s) * 1000) & 0xFFFFFFFF

    def _send_command(self, command: int, confirmation: int, params: tuple[float, ...]) -> None:
        cfg = self.config
        endpoint = self._require_endpoint()
        msg = endpoint.mav.command_long_encode(
            cfg.autopilot_system_id, cfg.autopilot_component_id, command, confirmation, *params
        )
        endpoint.send(msg)

    def _send_setpoint(self, target: _Target) -> None:
        cfg = self.config
        endpoint = self._endpoint
        if endpoint is None:
            return
        north, east, down = map_to_ned(target.x_m, target.y_m, target.z_m)
        msg = endpoint.mav.set_position_target_local_ned_encode(
            self._boot_ms(),
            cfg.autopilot_system_id,
            cfg.autopilot_component_id,
            mavlink2.MAV_FRAME_LOCAL_NED,
            TYPE_MASK_POSITION_YAW,
            north,
            east,
            down,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            yaw_map_to_ned(target.yaw_rad),
            0.0,
        )
        if endpoint.send(msg):
            now = time.monotonic()
            with self._lock:
                self._setpoints_sent += 1
                gap_s = None if self._last_setpoint_s is None else now - self._last_setpoint_s
                self._last_setpoint_s = now
                if gap_s is not None and gap_s >= STREAM_STALL_S:
                    self._setpoint_stall = (now, gap_s)
            if gap_s is not None and gap_s >= STREAM_STALL_S:
                log.warning("setpoint stream stalled for %.2f s (this process got no CPU time)", gap_s)

    def _send_heartbeat(self) -> bool:
        endpoint = self._require_endpoint()
        return endpoint.send(
            endpoint.mav.heartbeat_encode(
                mavlink2.MAV_TYPE_ONBOARD_CONTROLLER,
                mavlink2.MAV_AUTOPILOT_INVALID,
                0,
                0,
                mavlink2.MAV_STATE_ACTIVE,
            )
        )

    def _request_odometry(self) -> None:
        """Ask for the odometry messages at ``odometry_rate_hz`` (fire and forget: the send loop must not block)."""
        interval_us = 1e6 / self.config.odometry_rate_hz
        if self.config.odometry_source == "odometry":
            message_ids = (mavlink2.MAVLINK_MSG_ID_ODOMETRY,)
        else:
            message_ids = (mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mavlink2.MAVLINK_MSG_ID_ATTITUDE)
        for message_id in message_ids:
            self._send_command(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, 0, (message_id, interval_us, 0, 0, 0, 0, 0))
        self._intervals_requested_s = time.monotonic()

    def _send_loop(self) -> None:
        period_s = 1.0 / self.config.setpoint_rate_hz
        next_tick_s = time.monotonic()
        next_heartbeat_s = next_tick_s
        while not self._stop.wait(max(0.0, next_tick_s - time.monotonic())):
            now = time.monotonic()
            try:
                if now >= next_heartbeat_s and self._send_heartbeat():  # udpin: retried until a peer is known
                    next_heartbeat_s += 1.0
                    if next_heartbeat_s <= now:
                        next_heartbeat_s = now + 1.0
                target = self._target
                if target is not None:
                    self._send_setpoint(target)
                self._check_health(now)
            except Exception:  # noqa: BLE001 - the setpoint stream must outlive any single failure
                log.exception("MAVLink send loop error")
            next_tick_s += period_s
            if next_tick_s < now - period_s:  # fell behind (e.g. the process was suspended): do not burst
                next_tick_s = now + period_s

    def _odometry_rx_s(self) -> float | None:
        """Arrival time of the older of the newest position and attitude: a full pose is as fresh as this."""
        if self._position_rx_s is None or self._attitude_rx_s is None:
            return None
        return min(self._position_rx_s, self._attitude_rx_s)

    def _check_health(self, now: float) -> None:
        cfg = self.config
        with self._lock:
            hb_rx = self._heartbeat_rx_s
            odo_rx = self._odometry_rx_s()
            if hb_rx is not None and not self._link_lost and now - hb_rx > cfg.link_lost_after_s:
                self._link_lost = True
                log.warning("MAVLink link lost: no autopilot heartbeat for %.1f s", now - hb_rx)
            stale = odo_rx is not None and now - odo_rx > cfg.odometry_stale_after_s
            if stale and not self._odometry_stale_logged:
                log.warning("odometry stale: newest sample %.2f s old", now - odo_rx)
            elif not stale and self._odometry_stale_logged:
                log.info("odometry fresh again")
            self._odometry_stale_logged = stale
            connected = hb_rx is not None and not self._link_lost
            requested = self._intervals_requested_s
        # Ask on (re)connection, and again every second while no odometry arrives (a request can be lost).
        odometry_missing = odo_rx is None or now - odo_rx > 1.0
        if connected and (requested is None or (odometry_missing and now - requested > 1.0)):
            self._request_odometry()
