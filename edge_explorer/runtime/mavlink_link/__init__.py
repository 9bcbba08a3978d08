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
  from +x, FLU body). The ENU↔NED conversion lives here and nowhere else (docs/design.md §3): :func:`map_to_ned`,
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

Where each part lives (one module each, read :mod:`.link` first): :mod:`.link` — :class:`MavlinkLink`, its
configuration, health, send thread and commands; :mod:`.receive` — the receive thread and message handlers;
:mod:`.autopilots` — the PX4 / ArduPilot start sequences and modes; :mod:`.transport` — the UDP endpoint, message
parsing and the telemetry log; :mod:`.signing` — MAVLink 2 signing; :mod:`.frames` — the ENU↔NED conventions;
:mod:`.poses` — poses, clock mapping and the pose buffer; :mod:`.errors` — :class:`LinkError`.

The transport is UDP only (``udpin:HOST:PORT`` listens, ``udpout:HOST:PORT`` sends first). A serial autopilot is
bridged with mavlink-router or MAVProxy (``--master=/dev/ttyACM0 --out=udpout:127.0.0.1:14540``).
"""

from __future__ import annotations

from edge_explorer.runtime.mavlink_link.autopilots import ARDUPILOT_GUIDED_MODE, PX4_OFFBOARD_MODE
from edge_explorer.runtime.mavlink_link.errors import LinkError
from edge_explorer.runtime.mavlink_link.frames import (
    _euler_from_quaternion,
    _rotate_frd_to_ned,
    attitude_map_to_ned,
    attitude_ned_to_map,
    map_to_ned,
    ned_to_map,
    yaw_map_to_ned,
    yaw_ned_to_map,
)
from edge_explorer.runtime.mavlink_link.link import (
    STREAM_STALL_S,
    TYPE_MASK_POSITION_YAW,
    LinkConfig,
    LinkStatus,
    MavlinkLink,
)
from edge_explorer.runtime.mavlink_link.poses import Pose
from edge_explorer.runtime.mavlink_link.signing import load_signing_key
from edge_explorer.runtime.mavlink_link.transport import MavlinkEndpoint, TlogWriter, parse_connect

__all__ = [
    "ARDUPILOT_GUIDED_MODE",
    "LinkConfig",
    "LinkError",
    "LinkStatus",
    "MavlinkEndpoint",
    "MavlinkLink",
    "PX4_OFFBOARD_MODE",
    "Pose",
    "STREAM_STALL_S",
    "TYPE_MASK_POSITION_YAW",
    "TlogWriter",
    "_euler_from_quaternion",
    "_rotate_frd_to_ned",
    "attitude_map_to_ned",
    "attitude_ned_to_map",
    "load_signing_key",
    "map_to_ned",
    "ned_to_map",
    "parse_connect",
    "yaw_map_to_ned",
    "yaw_ned_to_map",
]
