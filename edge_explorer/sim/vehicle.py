"""Simulated quadrotor autopilot speaking MAVLink 2 over UDP: what the daemon's embedded default and the tests fly.

:class:`SimulatedVehicle` is an autopilot stand-in around the flight physics
(:class:`~edge_explorer.sim.quadrotor.QuadrotorModel`) on its own UDP port and thread. PX4-flavoured by default
(``MAV_AUTOPILOT_PX4``, quadrotor): 1 Hz heartbeats with base/custom mode, arming and disarming by COMMAND_LONG with
COMMAND_ACK, DO_SET_MODE (OFFBOARD only while setpoints stream, as PX4 does; back to hold — AUTO.LOITER — when they
stop for more than ``offboard_timeout_s``), SET_MESSAGE_INTERVAL for LOCAL_POSITION_NED, ATTITUDE (default 30 Hz
each) and ODOMETRY (off by default), STATUSTEXT on collisions and failsafes. An ArduPilot-copter flavour (GUIDED,
NAV_TAKEOFF) exercises the link's guided start sequence.

The model works in the ``map`` frame; on the wire it speaks local NED through the link's one conversion
(:mod:`edge_explorer.runtime.mavlink_link`). The odometry it reports can carry VIO-like noise and drift
(:class:`OdometryNoise`), while :meth:`SimulatedVehicle.true_pose` gives the truth for the simulated camera.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from edge_explorer.runtime.mavlink_link import (
    MavlinkEndpoint,
    Pose,
    attitude_map_to_ned,
    load_signing_key,
    map_to_ned,
    ned_to_map,
    yaw_ned_to_map,
)
from edge_explorer.sim.quadrotor import QuadrotorModel, VehicleLimits
from edge_explorer.vehicle.dynamics import wrap_angle_rad
from edge_explorer.world.raster import ROBOT_RADIUS_M, PlanRaster

log = logging.getLogger(__name__)

FORCE_DISARM_MAGIC = 21196  # COMPONENT_ARM_DISARM param2 that disarms in flight (PX4 and ArduPilot)
LANDED_BELOW_M = 0.1
THREAD_NAME = "sim-vehicle"  # the physics loop's thread: `edge-explorer run` and the profiler meter its CPU apart
HOLD_MODE = "LOITER"  # PX4 AUTO.LOITER ("Hold") and ArduPilot LOITER: keep the current position
_STREAMED = {
    mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED: "LOCAL_POSITION_NED",
    mavlink2.MAVLINK_MSG_ID_ATTITUDE: "ATTITUDE",
    mavlink2.MAVLINK_MSG_ID_ODOMETRY: "ODOMETRY",
}


@dataclass(frozen=True)
class OdometryNoise:
    """VIO-like odometry error: white noise on each report plus a random-walk drift (per √s) of position and yaw."""

    position_sigma_m: float = 0.01
    yaw_sigma_rad: float = 0.005
    position_drift_m_per_sqrt_s: float = 0.01
    yaw_drift_rad_per_sqrt_s: float = 0.002
    seed: int = 0


@dataclass(frozen=True)
class VehicleConfig:
    """The simulated autopilot. ``connect``: ``udpin:127.0.0.1:0`` listens on an ephemeral port (see
    :attr:`SimulatedVehicle.address`) and answers whoever speaks first; ``udpout:HOST:PORT`` sends to a fixed peer
    (as PX4 SITL does)."""

    connect: str = "udpin:127.0.0.1:0"
    flavour: str = "px4"  # or "ardupilot"
    system_id: int = 1
    component_id: int = mavlink2.MAV_COMP_ID_AUTOPILOT1
    start_xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    start_yaw_rad: float = 0.0
    limits: VehicleLimits = field(default_factory=VehicleLimits)
    radius_m: float = ROBOT_RADIUS_M
    physics_rate_hz: float = 100.0
    default_stream_rate_hz: float = 30.0
    offboard_timeout_s: float = 0.5
    odometry_noise: OdometryNoise | None = None
    signing_key: str | None = None

    def __post_init__(self) -> None:
        if self.flavour not in ("px4", "ardupilot"):
            raise ValueError(f"flavour must be 'px4' or 'ardupilot', got {self.flavour!r}")


@dataclass(frozen=True)
class VehicleState:
    """What the autopilot knows about itself (for tests and the bench, not sent anywhere)."""

    armed: bool
    mode: str
    collisions: int
    in_contact: bool
    setpoints_received: int
    setpoint_rate_hz: float  # measured over the last second of received setpoints
    companion_heartbeats: int
    stream_rates_hz: dict[str, float]
    datagrams_bad: int


class SimulatedVehicle:
    """A MAVLink autopilot stand-in on its own thread. ``with SimulatedVehicle(cfg, raster) as vehicle: ...``."""

    def __init__(self, config: VehicleConfig = VehicleConfig(), raster: PlanRaster | None = None) -> None:
        self.config = config
        x, y, z = config.start_xyz_m
        self._model = QuadrotorModel(x, y, z, config.start_yaw_rad, config.limits, raster, config.radius_m)
        self._key = load_signing_key(config.signing_key) if config.signing_key else None
        self._endpoint = MavlinkEndpoint(config.connect, config.system_id, config.component_id, self._key)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._boot_s = time.monotonic()
        self._state_stamp_s = self._boot_s  # time of the model's current state
        self._armed = False
        self._mode = HOLD_MODE
        self._hold_target: tuple[float, float, float, float] | None = None
        self._setpoint: tuple[float, float, float, float] | None = None
        self._setpoint_rx: deque[float] = deque(maxlen=256)
        self._setpoints_received = 0
        self._companion_heartbeats = 0
        self._stream_interval_s: dict[int, float | None] = {
            mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 1.0 / config.default_stream_rate_hz,
            mavlink2.MAVLINK_MSG_ID_ATTITUDE: 1.0 / config.default_stream_rate_hz,
            mavlink2.MAVLINK_MSG_ID_ODOMETRY: None,
        }
        self._stream_due_s: dict[int, float] = dict.fromkeys(self._stream_interval_s, 0.0)
        noise = config.odometry_noise
        self._rng = np.random.default_rng(noise.seed if noise else 0)
        self._drift = [0.0, 0.0, 0.0, 0.0]  # x, y, z, yaw random walk of the reported odometry

    # -- lifecycle and truth --------------------------------------------------------------------------------

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) the vehicle listens on."""
        return self._endpoint.local_address

    def start(self) -> SimulatedVehicle:
        self._thread = threading.Thread(target=self._run, name=THREAD_NAME, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self._endpoint.close()

    def __enter__(self) -> SimulatedVehicle:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def true_pose(self) -> Pose:
        """The exact pose, stamped with the ``time.monotonic()`` of the physics step that produced it (≤ one
        step old): what the simulated depth camera renders from."""
        with self._lock:
            return self._model.pose(self._state_stamp_s)

    def state(self) -> VehicleState:
        now = time.monotonic()
        with self._lock:
            recent = [t for t in self._setpoint_rx if t > now - 1.0]
            rate = (len(recent) - 1) / (recent[-1] - recent[0]) if len(recent) > 2 else 0.0
            return VehicleState(
                armed=self._armed,
                mode=self._mode,
                collisions=self._model.collisions,
                in_contact=self._model.in_contact,
                setpoints_received=self._setpoints_received,
                setpoint_rate_hz=rate,
                companion_heartbeats=self._companion_heartbeats,
                stream_rates_hz={
                    _STREAMED[i]: (0.0 if s is None else 1.0 / s) for i, s in self._stream_interval_s.items()
                },
                datagrams_bad=self._endpoint.datagrams_bad,
            )

    # -- flavour ------------------------------------------------------------------------------------------------

    @property
    def _px4(self) -> bool:
        return self.config.flavour == "px4"

    @property
    def _external_mode(self) -> str:
        """The mode in which the companion's setpoints fly the vehicle."""
        return "OFFBOARD" if self._px4 else "GUIDED"

    def _mode_numbers(self) -> tuple[int, int]:
        """(base_mode, custom_mode) of the heartbeat for the current mode and arming state."""
        armed = mavlink2.MAV_MODE_FLAG_SAFETY_ARMED if self._armed else 0
        if self._px4:
            base, main, sub = mavutil.px4_map[self._mode]
            return base | armed, (main << 16) | (sub << 24)
        number = next(n for n, name in mavutil.mode_mapping_acm.items() if name == self._mode)
        return mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | armed, number

    def _mode_from_command(self, param2: float, param3: float) -> str | None:
        """The mode a DO_SET_MODE asks for, if this vehicle has it."""
        if self._px4:
            wanted = (int(param2), int(param3))
            for name in (HOLD_MODE, "OFFBOARD"):
                if mavutil.px4_map[name][1:] == wanted:
                    return name
            return None
        name = mavutil.mode_mapping_acm.get(int(param2))
        return name if name in (HOLD_MODE, "GUIDED") else None

    # -- the loop ---------------------------------------------------------------------------------------------

    def _run(self) -> None:
        period_s = 1.0 / self.config.physics_rate_hz
        last_s = next_tick_s = time.monotonic()
        next_heartbeat_s = last_s
        while not self._stop.is_set():
            while (remaining := next_tick_s - time.monotonic()) > 0:
                for msg in self._endpoint.receive(remaining):
                    self._handle(msg)
            now = time.monotonic()
            collided = self._step(now, min(now - last_s, 0.1))
            last_s = now
            if collided:
                x, y, _ = self._model.position_m
                self._statustext(
                    mavlink2.MAV_SEVERITY_WARNING, f"collision at x={x:.2f} y={y:.2f} (#{self._model.collisions})"
                )
            if now >= next_heartbeat_s and self._send_heartbeat():  # retried each tick until a peer is known
                next_heartbeat_s = _next_period(next_heartbeat_s, 1.0, now)
            self._publish(now)
            next_tick_s += period_s
            if next_tick_s < now:
                next_tick_s = now + period_s

    def _step(self, now: float, dt_s: float) -> bool:
        with self._lock:
            model = self._model
            if self._mode == "OFFBOARD" and (
                not self._setpoint_rx or now - self._setpoint_rx[-1] > self.config.offboard_timeout_s
            ):
                self._enter_hold()
                self._statustext(mavlink2.MAV_SEVERITY_WARNING, "offboard setpoints lost: holding position")
            if not self._armed:
                model.target = None
            elif self._mode == self._external_mode and self._setpoint is not None:
                model.target = self._setpoint
            else:
                model.target = self._hold_target
            collided = model.step(dt_s)
            self._state_stamp_s = now
            noise = self.config.odometry_noise
            if noise is not None:
                walk = self._rng.standard_normal(4) * math.sqrt(dt_s)
                for i in range(3):
                    self._drift[i] += noise.position_drift_m_per_sqrt_s * walk[i]
                self._drift[3] += noise.yaw_drift_rad_per_sqrt_s * walk[3]
            return collided

    def _enter_hold(self) -> None:
        model = self._model
        self._mode = HOLD_MODE
        self._hold_target = (*model.position_m, model.yaw_rad)

    def _reported_pose(self, now: float) -> Pose:
        """The odometry the vehicle reports: the truth plus drift and white noise when configured."""
        truth = self._model.pose(now)
        noise = self.config.odometry_noise
        if noise is None:
            return truth
        white = self._rng.standard_normal(4)
        return Pose(
            now,
            truth.x_m + self._drift[0] + noise.position_sigma_m * white[0],
            truth.y_m + self._drift[1] + noise.position_sigma_m * white[1],
            truth.z_m + self._drift[2] + noise.position_sigma_m * white[2],
            wrap_angle_rad(truth.yaw_rad + self._drift[3] + noise.yaw_sigma_rad * white[3]),
            truth.pitch_rad,
            truth.roll_rad,
            truth.vx_mps,
            truth.vy_mps,
            truth.vz_mps,
        )

    # -- sending ------------------------------------------------------------------------------------------------

    def _send(self, msg: mavlink2.MAVLink_message) -> bool:
        return self._endpoint.send(msg)

    def _boot_ms(self, now: float) -> int:
        return int((now - self._boot_s) * 1000) & 0xFFFFFFFF

    def _send_heartbeat(self) -> bool:
        with self._lock:
            base_mode, custom_mode = self._mode_numbers()
            status = mavlink2.MAV_STATE_ACTIVE if self._armed else mavlink2.MAV_STATE_STANDBY
        autopilot = mavlink2.MAV_AUTOPILOT_PX4 if self._px4 else mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA
        return self._send(
            self._endpoint.mav.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, autopilot, base_mode, custom_mode, status)
        )

    def _statustext(self, severity: int, text: str) -> None:
        log.log(logging.WARNING if severity <= mavlink2.MAV_SEVERITY_WARNING else logging.INFO, "vehicle: %s", text)
        self._send(self._endpoint.mav.statustext_encode(severity, text.encode()[:50]))

    def _publish(self, now: float) -> None:
        mav = self._endpoint.mav
        due = []
        for msg_id, interval_s in self._stream_interval_s.items():
            if interval_s is not None and now >= self._stream_due_s[msg_id]:
                due.append(msg_id)
                self._stream_due_s[msg_id] = _next_period(self._stream_due_s[msg_id], interval_s, now)
        if not due:
            return
        with self._lock:
            pose = self._reported_pose(now)
            yaw_rate = self._model.yaw_rate_rad_s
        boot_ms = self._boot_ms(now)
        north, east, down = map_to_ned(pose.x_m, pose.y_m, pose.z_m)
        vn, ve, vd = map_to_ned(pose.vx_mps, pose.vy_mps, pose.vz_mps)
        roll, pitch, yaw = attitude_map_to_ned(pose.roll_rad, pose.pitch_rad, pose.yaw_rad)
        for msg_id in due:
            if msg_id == mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
                msg = mav.local_position_ned_encode(boot_ms, north, east, down, vn, ve, vd)
            elif msg_id == mavlink2.MAVLINK_MSG_ID_ATTITUDE:
                msg = mav.attitude_encode(boot_ms, roll, pitch, yaw, 0.0, 0.0, -yaw_rate)
            else:
                # Pose in LOCAL_NED; the velocity (child frame) in LOCAL_NED too.
                msg = mav.odometry_encode(
                    boot_ms * 1000,
                    mavlink2.MAV_FRAME_LOCAL_NED,
                    mavlink2.MAV_FRAME_LOCAL_NED,
                    north,
                    east,
                    down,
                    _quaternion_from_euler(roll, pitch, yaw),
                    vn,
                    ve,
                    vd,
                    0.0,
                    0.0,
                    -yaw_rate,
                    [math.nan] * 21,
                    [math.nan] * 21,
                )
            self._send(msg)

    def _ack(self, command: int, result: int) -> None:
        self._send(self._endpoint.mav.command_ack_encode(command, result))

    # -- receiving ----------------------------------------------------------------------------------------------

    def _handle(self, msg: mavlink2.MAVLink_message) -> None:
        msg_id = msg.get_msgId()
        if msg_id == mavlink2.MAVLINK_MSG_ID_HEARTBEAT:
            if msg.type == mavlink2.MAV_TYPE_ONBOARD_CONTROLLER:
                with self._lock:
                    self._companion_heartbeats += 1
        elif msg_id == mavlink2.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED:
            self._on_setpoint(msg)
        elif msg_id == mavlink2.MAVLINK_MSG_ID_COMMAND_LONG and msg.target_system in (0, self.config.system_id):
            self._on_command(msg)

    def _on_setpoint(self, msg: mavlink2.MAVLink_set_position_target_local_ned_message) -> None:
        """Position (+ yaw unless masked) targets in LOCAL_NED addressed to this system; anything else is ignored."""
        position_used = (msg.type_mask & 0b111) == 0
        values = (msg.x, msg.y, msg.z, msg.yaw)
        if (
            msg.target_system not in (0, self.config.system_id)
            or msg.coordinate_frame != mavlink2.MAV_FRAME_LOCAL_NED
            or not position_used
            or not all(math.isfinite(v) for v in values)
        ):
            return
        x, y, z = ned_to_map(msg.x, msg.y, msg.z)
        with self._lock:
            yaw = (
                self._model.yaw_rad
                if msg.type_mask & mavlink2.POSITION_TARGET_TYPEMASK_YAW_IGNORE
                else yaw_ned_to_map(msg.yaw)
            )
            self._setpoint = (x, y, z, yaw)
            self._setpoint_rx.append(time.monotonic())
            self._setpoints_received += 1

    def _on_command(self, msg: mavlink2.MAVLink_command_long_message) -> None:
        command = msg.command
        if command == mavlink2.MAV_CMD_COMPONENT_ARM_DISARM:
            result = self._arm_disarm(msg.param1 >= 0.5, int(msg.param2) == FORCE_DISARM_MAGIC)
        elif command == mavlink2.MAV_CMD_DO_SET_MODE:
            result = self._set_mode(msg.param2, msg.param3)
        elif command == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL:
            result = self._set_interval(int(msg.param1), msg.param2)
        elif command == mavlink2.MAV_CMD_NAV_TAKEOFF and not self._px4:
            result = self._takeoff(msg.param7)
        else:
            result = mavlink2.MAV_RESULT_UNSUPPORTED
        self._ack(command, result)

    def _arm_disarm(self, arm: bool, force: bool) -> int:
        with self._lock:
            model = self._model
            if arm:
                if not self._armed:
                    self._armed = True
                    self._hold_target = (*model.position_m, model.yaw_rad)
                return mavlink2.MAV_RESULT_ACCEPTED
            if model.position_m[2] > LANDED_BELOW_M and not force:
                return mavlink2.MAV_RESULT_DENIED  # in flight: only a forced disarm (the motors stop, it drops)
            self._armed = False
            model.position_m[2] = 0.0
            return mavlink2.MAV_RESULT_ACCEPTED

    def _set_mode(self, param2: float, param3: float) -> int:
        mode = self._mode_from_command(param2, param3)
        if mode is None:
            return mavlink2.MAV_RESULT_UNSUPPORTED
        with self._lock:
            if mode == "OFFBOARD":
                fresh = self._setpoint_rx and time.monotonic() - self._setpoint_rx[-1] <= self.config.offboard_timeout_s
                if not fresh:
                    return mavlink2.MAV_RESULT_TEMPORARILY_REJECTED  # PX4: stream setpoints first
            if mode == HOLD_MODE:
                self._enter_hold()
            self._mode = mode
        return mavlink2.MAV_RESULT_ACCEPTED

    def _set_interval(self, msg_id: int, interval_us: float) -> int:
        if msg_id not in self._stream_interval_s:
            return mavlink2.MAV_RESULT_DENIED
        if interval_us < 0:
            interval_s = None
        elif interval_us == 0:
            interval_s = 1.0 / self.config.default_stream_rate_hz
        else:
            interval_s = max(interval_us / 1e6, 1.0 / self.config.physics_rate_hz)
        self._stream_interval_s[msg_id] = interval_s
        return mavlink2.MAV_RESULT_ACCEPTED

    def _takeoff(self, altitude_m: float) -> int:
        with self._lock:
            if not (self._armed and self._mode == "GUIDED" and math.isfinite(altitude_m) and altitude_m > 0):
                return mavlink2.MAV_RESULT_DENIED
            x, y, _ = self._model.position_m
            self._setpoint = (x, y, altitude_m, self._model.yaw_rad)
        return mavlink2.MAV_RESULT_ACCEPTED


def _next_period(due_s: float, period_s: float, now_s: float) -> float:
    """The next due time of a periodic event: one period on, or one period from now if that is already past."""
    due_s += period_s
    return due_s if due_s > now_s else now_s + period_s


def _quaternion_from_euler(roll: float, pitch: float, yaw: float) -> list[float]:
    """MAVLink quaternion (w, x, y, z) of ZYX Euler angles."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return [
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    ]
