"""MAVLink 2 link between the on-device daemon and the autopilot (PX4 offboard or ArduPilot guided), over UDP.

What it does, and why:

* **Heartbeat** at 1 Hz as ``MAV_TYPE_ONBOARD_CONTROLLER`` / ``MAV_COMP_ID_ONBOARD_COMPUTER``, so the autopilot and
  any ground station see a companion computer on the link.
* **Odometry in**: asks the autopilot for LOCAL_POSITION_NED + ATTITUDE (or ODOMETRY) with
  ``MAV_CMD_SET_MESSAGE_INTERVAL`` and keeps a timestamped pose buffer; :meth:`MavlinkLink.pose_at` interpolates
  it at a depth frame's timestamp. Stamps are on this host's ``time.monotonic()`` clock: the autopilot's
  ``time_boot_ms`` is mapped onto it by a minimum-latency offset estimate (:class:`_ClockSync`), so samples keep
  the autopilot's own spacing instead of the jitter of their arrival.
* **Setpoints out**: a thread streams SET_POSITION_TARGET_LOCAL_NED (position + yaw, ``type_mask`` 2552) at
  ``setpoint_rate_hz`` (default 20 Hz; PX4 leaves offboard below 2 Hz) with the latest target.
* **Start sequences**: PX4 offboard (stream setpoints, switch to OFFBOARD, arm) and ArduPilot guided (GUIDED, arm,
  take off, then stream).
* **Frames**: everything outside this module speaks the ``map`` frame (x east, y north, z up, yaw counter-clockwise
  from +x, FLU body). The ENU↔NED conversion lives here and nowhere else (DESIGN.md §3): :func:`map_to_ned`,
  :func:`ned_to_map`, :func:`yaw_map_to_ned`, :func:`yaw_ned_to_map`, :func:`attitude_ned_to_map`,
  :func:`attitude_map_to_ned`. The simulated vehicle calls these same functions.
* **Health**: link loss (no autopilot heartbeat for ``link_lost_after_s``), stale odometry (newest sample older
  than ``odometry_stale_after_s``) — reported by :meth:`MavlinkLink.status` and logged on every transition.
* **Robustness**: only messages from the configured autopilot system/component are acted on; every datagram is
  parsed on its own, and malformed, truncated, CRC-failed or unknown datagrams are counted and dropped. Optional
  MAVLink 2 signing (a 32-byte key): unsigned or wrongly signed messages are dropped and counted.
* **Telemetry log**: every message sent and received goes to a ``.tlog`` (8-byte big-endian microsecond UNIX
  timestamp + the raw MAVLink bytes), readable by ``mavlogdump.py`` and ``mavutil.mavlink_connection(path)``.
  pymavlink's own logging stays empty over UDP, hence :class:`TlogWriter`.

The transport is UDP only (``udpin:HOST:PORT`` listens, ``udpout:HOST:PORT`` sends first). A serial autopilot is
bridged with mavlink-router or MAVProxy (``--master=/dev/ttyACM0 --out=udpout:127.0.0.1:14540``).
"""

from __future__ import annotations

import bisect
import logging
import math
import re
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from edge_explorer.errors import EdgeExplorerError

log = logging.getLogger(__name__)

# position + yaw: ignore velocity (bits 3-5), acceleration (6-8) and yaw rate (11); use x, y, z (0-2) and yaw (10).
TYPE_MASK_POSITION_YAW = 2552
PX4_OFFBOARD_MODE = "OFFBOARD"
STREAM_STALL_S = 0.5  # a setpoint gap this long breaks PX4's > 2 Hz offboard rule
ARDUPILOT_GUIDED_MODE = "GUIDED"
_SIGNING_EPOCH_UNIX_S = 1420070400  # MAVLink signing timestamps count 10 µs units from 2015-01-01
_MAX_DATAGRAM_BYTES = 65535


class LinkError(EdgeExplorerError):
    """The MAVLink link cannot do what was asked: bad configuration, no autopilot, or a command refused."""


# ---------------------------------------------------------------------------------------------------------------
# Frame conversion: the only place where map (ENU / FLU) meets MAVLink's local NED / FRD.
# ---------------------------------------------------------------------------------------------------------------


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


# ---------------------------------------------------------------------------------------------------------------
# Poses
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Pose:
    """Vehicle pose in the ``map`` frame at ``stamp_s`` (host ``time.monotonic()`` seconds); FLU attitude.

    The attitude fields match :class:`edge_explorer.sim.camera.CameraPose` (positive pitch = nose down).
    """

    stamp_s: float
    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float
    pitch_rad: float = 0.0
    roll_rad: float = 0.0
    vx_mps: float = 0.0
    vy_mps: float = 0.0
    vz_mps: float = 0.0


class _ClockSync:
    """Maps a remote clock (e.g. the autopilot's ``time_boot_ms``) onto this host's monotonic clock.

    The offset is the smallest ``arrival − remote`` seen: the sample with the least transport delay. It may creep
    up by ``drift_s_per_s`` to follow clock drift, and starts over when the remote clock jumps back (a reboot) or
    the delay it implies exceeds ``reset_after_s``.
    """

    def __init__(self, drift_s_per_s: float = 1e-4, reset_after_s: float = 1.0) -> None:
        self._offset_s: float | None = None
        self._last_remote_s = 0.0
        self._last_arrival_s = 0.0
        self._drift = drift_s_per_s
        self._reset_after_s = reset_after_s

    def to_host(self, remote_s: float, arrival_s: float) -> float:
        sample = arrival_s - remote_s
        jumped_back = remote_s < self._last_remote_s - self._reset_after_s
        if self._offset_s is None or jumped_back or sample - self._offset_s > self._reset_after_s:
            self._offset_s = sample
        else:
            allowed = self._offset_s + self._drift * (arrival_s - self._last_arrival_s)
            self._offset_s = min(sample, allowed)
        self._last_remote_s = remote_s
        self._last_arrival_s = arrival_s
        return remote_s + self._offset_s


class _PoseBuffer:
    """Timestamped position and attitude samples (they arrive in separate messages), interpolated on demand."""

    def __init__(self, horizon_s: float, max_extrapolation_s: float) -> None:
        self._horizon_s = horizon_s
        self._max_extrapolation_s = max_extrapolation_s
        # (stamp, x, y, z, vx, vy, vz) and (stamp, roll, pitch, yaw, yaw_rate), map frame, sorted by stamp.
        self._positions: list[tuple[float, ...]] = []
        self._attitudes: list[tuple[float, ...]] = []
        self.out_of_order = 0

    def add_position(self, stamp_s: float, xyz: tuple[float, float, float], vxyz: tuple[float, float, float]) -> None:
        self._append(self._positions, (stamp_s, *xyz, *vxyz))

    def add_attitude(self, stamp_s: float, roll: float, pitch: float, yaw: float, yaw_rate: float) -> None:
        self._append(self._attitudes, (stamp_s, roll, pitch, yaw, yaw_rate))

    def _append(self, samples: list[tuple[float, ...]], sample: tuple[float, ...]) -> None:
        if samples and sample[0] <= samples[-1][0]:
            self.out_of_order += 1
            return
        samples.append(sample)
        cutoff = sample[0] - self._horizon_s
        if samples[0][0] < cutoff:
            del samples[: bisect.bisect_left(samples, (cutoff,))]

    def newest_stamp_s(self) -> float | None:
        if not self._positions or not self._attitudes:
            return None
        return min(self._positions[-1][0], self._attitudes[-1][0])

    def pose_at(self, t_s: float) -> Pose | None:
        pos = _interpolate(self._positions, t_s, self._max_extrapolation_s, velocity_cols=(4, 5, 6))
        att = _interpolate(self._attitudes, t_s, self._max_extrapolation_s, velocity_cols=(None, None, 4), angle=3)
        if pos is None or att is None:
            return None
        return Pose(t_s, pos[1], pos[2], pos[3], att[3], att[2], att[1], pos[4], pos[5], pos[6])


def _interpolate(
    samples: list[tuple[float, ...]],
    t_s: float,
    max_extrapolation_s: float,
    velocity_cols: tuple[int | None, ...],
    angle: int | None = None,
) -> tuple[float, ...] | None:
    """Linear interpolation of the sample tuples at ``t_s`` (column ``angle`` along the shortest arc).

    Past the newest sample, columns 1-3 are extrapolated with the rates in ``velocity_cols`` for at most
    ``max_extrapolation_s``; up to that long before the oldest sample, the oldest is held (position and attitude
    arrive at slightly different times); earlier than that there is nothing to say.
    """
    if not samples or t_s < samples[0][0] - max_extrapolation_s:
        return None
    if t_s <= samples[0][0]:
        return samples[0]
    newest = samples[-1]
    if t_s >= newest[0]:
        dt = t_s - newest[0]
        if dt > max_extrapolation_s:
            return None
        out = list(newest)
        for col, rate_col in zip((1, 2, 3), velocity_cols, strict=True):
            if rate_col is not None:
                out[col] += newest[rate_col] * dt
        if angle is not None:
            out[angle] = _wrap_rad(out[angle])
        return tuple(out)
    i = bisect.bisect_right(samples, (t_s, math.inf))
    a, b = samples[i - 1], samples[i]
    w = (t_s - a[0]) / (b[0] - a[0])
    out = [av + w * (bv - av) for av, bv in zip(a, b, strict=True)]
    if angle is not None:
        out[angle] = _wrap_rad(a[angle] + w * _wrap_rad(b[angle] - a[angle]))
    return tuple(out)


# ---------------------------------------------------------------------------------------------------------------
# Transport: telemetry log and one UDP MAVLink 2 endpoint
# ---------------------------------------------------------------------------------------------------------------


class TlogWriter:
    """Appends MAVLink messages to a ``.tlog``: per message an 8-byte big-endian UNIX timestamp in µs + raw bytes."""

    def __init__(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self._file = open(path, "wb")  # noqa: SIM115 - closed by close(); lives as long as the link
        self._lock = threading.Lock()
        self._last_flush_s = time.monotonic()

    def write(self, raw: bytes) -> None:
        stamp = struct.pack(">Q", int(time.time() * 1e6))
        with self._lock:
            if self._file.closed:
                return
            self._file.write(stamp + raw)
            if time.monotonic() - self._last_flush_s > 1.0:  # a crash loses at most a second of log
                self._file.flush()
                self._last_flush_s = time.monotonic()

    def close(self) -> None:
        with self._lock:
            self._file.close()


def parse_connect(connect: str) -> tuple[str, str, int]:
    """``udpin:HOST:PORT`` / ``udp:HOST:PORT`` (listen) or ``udpout:HOST:PORT`` (send first) → (mode, host, port)."""
    match = re.fullmatch(r"(udpin|udpout|udp):([^:]+|\[[0-9a-fA-F:]+\]):(\d+)", connect.strip())
    if not match:
        raise LinkError(
            f"unsupported MAVLink connection {connect!r}: use udpin:HOST:PORT (listen) or udpout:HOST:PORT (send); "
            "bridge a serial autopilot with mavlink-router or MAVProxy (--master=/dev/ttyACM0 "
            "--out=udpout:127.0.0.1:14540)"
        )
    scheme, host, port = match.groups()
    return ("udpout" if scheme == "udpout" else "udpin"), host.strip("[]"), int(port)


def load_signing_key(spec: str) -> bytes:
    """A 32-byte MAVLink 2 signing key from 64 hex digits, or from a file holding 32 raw bytes or 64 hex digits."""
    text = spec.strip()
    if re.fullmatch(r"[0-9a-fA-F]{64}", text):
        return bytes.fromhex(text)
    path = Path(text)
    if not path.is_file():
        raise LinkError(f"signing key {spec!r}: not 64 hex digits and no such file")
    data = path.read_bytes()
    if len(data) == 32:
        return data
    stripped = data.strip()
    if re.fullmatch(rb"[0-9a-fA-F]{64}", stripped):
        return bytes.fromhex(stripped.decode())
    raise LinkError(f"signing key file {path}: expected 32 raw bytes or 64 hex digits, found {len(data)} bytes")


class MavlinkEndpoint:
    """One MAVLink 2 UDP endpoint: packs and sends messages, receives and parses one datagram at a time.

    Each datagram is parsed by a fresh parser, so a truncated datagram can never corrupt the next one; datagrams
    that yield no known, CRC-valid message (or leave bytes over) count in ``datagrams_bad``. With ``udpin`` the
    reply address follows the latest valid message from ``peer_system_id`` (any valid message when it is None), so
    garbage from another port cannot steal the link. Thread-safe: ``send`` and ``receive`` may run on different threads.
    """

    def __init__(
        self,
        connect: str,
        system_id: int,
        component_id: int,
        signing_key: bytes | None = None,
        tlog: TlogWriter | None = None,
        peer_system_id: int | None = None,
    ) -> None:
        mode, host, port = parse_connect(connect)
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        self._learns_remote = mode == "udpin"
        if self._learns_remote:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._sock.bind((host, port))
            self._remote: tuple | None = None
        else:
            self._sock.bind(("::" if family == socket.AF_INET6 else "0.0.0.0", 0))
            self._remote = socket.getaddrinfo(host, port, family, socket.SOCK_DGRAM)[0][4]
        self._lock = threading.Lock()
        self._tlog = tlog
        self._peer_system_id = peer_system_id
        self._signing = mavlink2.MAVLinkSigning()
        if signing_key is not None:
            if len(signing_key) != 32:
                raise LinkError(f"MAVLink 2 signing keys are 32 bytes, got {len(signing_key)}")
            self._signing.secret_key = signing_key
            self._signing.sign_outgoing = True
            self._signing.timestamp = int((time.time() - _SIGNING_EPOCH_UNIX_S) * 100_000)
        self.mav = mavlink2.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self.mav.signing = self._signing
        self.datagrams_bad = 0
        self.signature_rejected = 0
        self.send_errors = 0

    @property
    def local_address(self) -> tuple[str, int]:
        host, port = self._sock.getsockname()[:2]
        return host, port

    def send(self, msg: mavlink2.MAVLink_message) -> bool:
        """Pack (and sign) ``msg`` and send it; False when no peer is known yet (udpin before the first message)."""
        with self._lock:
            if self._remote is None:
                return False
            raw = bytes(msg.pack(self.mav))
            self.mav.seq = (self.mav.seq + 1) % 256
            try:
                self._sock.sendto(raw, self._remote)
            except OSError as exc:
                self.send_errors += 1
                log.debug("MAVLink send to %s failed: %s", self._remote, exc)
                return False
        if self._tlog is not None:
            self._tlog.write(raw)
        return True

    def receive(self, timeout_s: float) -> list[mavlink2.MAVLink_message]:
        """Messages of the next datagram (waits up to ``timeout_s``); [] on timeout or for a bad datagram."""
        self._sock.settimeout(timeout_s)
        try:
            data, address = self._sock.recvfrom(_MAX_DATAGRAM_BYTES)
        except (TimeoutError, BlockingIOError):
            return []
        except OSError as exc:  # e.g. ICMP port unreachable surfacing on some platforms
            log.debug("MAVLink receive error: %s", exc)
            return []
        with self._lock:
            messages, bad = self._parse(data)
            if bad:
                self.datagrams_bad += 1
            if self._learns_remote and self._is_peer(messages):
                self._remote = address
        if self._tlog is not None:
            for msg in messages:
                self._tlog.write(bytes(msg.get_msgbuf()))
        return messages

    def _parse(self, data: bytes) -> tuple[list[mavlink2.MAVLink_message], bool]:
        parser = mavlink2.MAVLink(None)
        parser.signing = self._signing
        parser.robust_parsing = True
        try:
            parsed = parser.parse_buffer(data) or []
        except Exception:  # noqa: BLE001 - pymavlink raises assorted errors on hostile input; the datagram is bad
            return [], True
        good = []
        bad = parser.buf_len() > 0  # a truncated trailing message
        for msg in parsed:
            if isinstance(msg, mavlink2.MAVLink_bad_data):
                bad = True
                if msg.reason == "Invalid signature":
                    self.signature_rejected += 1
            elif isinstance(msg, mavlink2.MAVLink_unknown):
                bad = True
            else:
                good.append(msg)
        return good, bad or not good

    def _is_peer(self, messages: list[mavlink2.MAVLink_message]) -> bool:
        """Whether valid ``messages`` come from the peer whose address replies go to (udpin only)."""
        if self._peer_system_id is None:
            return bool(messages)
        return any(m.get_srcSystem() == self._peer_system_id for m in messages)

    def close(self) -> None:
        self._sock.close()


# ---------------------------------------------------------------------------------------------------------------
# The link
# ---------------------------------------------------------------------------------------------------------------


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


class MavlinkLink:
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

    # -- lifecycle -------------------------------------------------------------------------------------------

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

    # -- targets -----------------------------------------------------------------------------------------------

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

    # -- poses and health -----------------------------------------------------------------------------------

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

    # -- start sequences and commands ----------------------------------------------------------------------

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

    # -- internals: sending ---------------------------------------------------------------------------------

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

    # -- internals: receiving -------------------------------------------------------------------------------

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


def _enum_name(enum: str, value: int) -> str:
    entry = mavlink2.enums.get(enum, {}).get(value)
    return entry.name if entry is not None else f"{enum} {value}"
