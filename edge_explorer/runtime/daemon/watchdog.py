"""The input watchdog: whether the daemon may fly on its inputs, and which depth frames it fuses.

Every loop iteration :meth:`InputWatchdog._check_inputs` says why the daemon must hold position, or None: the
autopilot's heartbeat lost, odometry older than ``odometry_max_age_s``, a pose jump (consecutive odometry poses
farther apart than the vehicle can fly plus ``pose_jump_m``: a VIO reset or relocalisation — the maps are started
afresh, home moves by the jump and frames are not fused for ``jump_settle_s``), the autopilot out of the
external-control mode (a pilot took over: the run ends; our own stream stalled or the link was lost: re-engage).
Every depth frame goes through :func:`frame_problem` (NaN/inf, no returns, wrong shape or dtype, a timestamp not
after the last one) and the odometry lookup at its timestamp before it is fused; a dropped frame is counted per
reason and logged at most every few seconds (:class:`_ThrottledLog`). The flown footprint (see the package
docstring, "Flown space is free") is stamped here too.

The watchdog does not act on a pose jump beyond its own settling: it says so (:attr:`InputCheck.jump_xy_m`), and
the daemon starts the maps and the goal planner afresh and moves home."""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np

from edge_explorer.mapping.voxels import FusionInputError
from edge_explorer.runtime.daemon.config import AUTOPILOT_MODES, STALL_BLAME_S, DaemonConfig
from edge_explorer.runtime.daemon.record import RunRecord
from edge_explorer.runtime.daemon.report import StageTimings
from edge_explorer.runtime.daemon.state import FlightMaps, FlightState
from edge_explorer.runtime.depth_sources import DepthFrame, Recorder
from edge_explorer.runtime.mavlink_link import LinkStatus, MavlinkLink
from edge_explorer.runtime.mavlink_link import Pose as Odometry
from edge_explorer.vehicle.camera import CameraPose

log = logging.getLogger(__name__)


def frame_problem(frame: DepthFrame, last_stamp_s: float | None) -> str | None:
    """Why a depth frame must be dropped, or None. Each reason is a count in the run report.

    NaN or ±inf never come from a healthy driver (RealSense depth is integer millimetres): the whole frame is
    suspect. A frame without one return (lens covered, driver hiccup) says nothing. The stamp must be after the
    last fused frame's: the odometry lookup and the maps' update order depend on it.
    """
    depth = frame.depth_m
    if not isinstance(depth, np.ndarray) or depth.shape != frame.intrinsics.shape:
        return "wrong shape"
    if depth.dtype not in (np.float32, np.float64):
        return "wrong dtype"
    if not np.isfinite(depth).all():
        return "NaN or inf depth"
    if not (depth > 0).any():
        return "no returns (all zero)"
    if not math.isfinite(frame.stamp_s) or (last_stamp_s is not None and frame.stamp_s <= last_stamp_s):
        return "timestamp not after the last frame"
    return None


class _ThrottledLog:
    """Logs a recurring problem at most once per ``every_s`` per kind, with how often it happened meanwhile."""

    def __init__(self, every_s: float = 5.0) -> None:
        self._every_s = every_s
        self._last: dict[str, tuple[float, int]] = {}  # kind → (last logged at, occurrences since)

    def warn(self, kind: str, message: str) -> None:
        now = time.monotonic()
        logged_at, since = self._last.get(kind, (-math.inf, 0))
        if now - logged_at >= self._every_s:
            suffix = f" ({since} more since the last report)" if since else ""
            log.warning("%s%s", message, suffix)
            self._last[kind] = (now, 0)
        else:
            self._last[kind] = (logged_at, since + 1)


@dataclass(frozen=True)
class InputCheck:
    """One iteration's verdict on the inputs: why the daemon must hold now (None when every input is healthy), and
    the map frame's shift (dx, dy) when odometry just jumped (the maps, the goal planner and home must follow)."""

    hold_reason: str | None
    jump_xy_m: tuple[float, float] | None = None


class InputWatchdog:
    """The daemon's input checks and frame ingestion (see the module docstring).

    Inputs: ``config``; ``link`` (its status, odometry and pose lookup); ``speed_max_m_s``, the fastest the vehicle
    flies (a pose change beyond it is a jump); ``timings`` (stage "mavlink_io" and "fuse"); ``maps``, fused into;
    ``state``, whose stop reason it sets when a pilot takes over; ``record``, told about every frame fused or dropped;
    ``recorder``, which keeps every fused frame with its pose. Owns the last odometry pose, the jump-settling
    deadline, the last fused frame's stamp and time and the link-lost flag."""

    def __init__(
        self,
        config: DaemonConfig,
        link: MavlinkLink,
        speed_max_m_s: float,
        timings: StageTimings,
        maps: FlightMaps,
        state: FlightState,
        record: RunRecord,
        recorder: Recorder | None = None,
    ) -> None:
        self.config = config
        self.link = link
        self.speed_max_m_s = speed_max_m_s
        self.timings = timings
        self.maps = maps
        self.state = state
        self.record = record
        self.recorder = recorder
        self._throttled = _ThrottledLog()
        self._link_lost_in_control = False  # the link was lost since the autopilot was last seen in OFFBOARD
        self._last_pose: Odometry | None = None
        self._jump_until_s = -math.inf
        self._last_frame_stamp_s: float | None = None
        self._last_fused_s = math.inf  # set at take-off: the first frame has depth_timeout_s to arrive

    @property
    def last_pose(self) -> Odometry | None:
        """The odometry pose of the latest healthy check."""
        return self._last_pose

    @property
    def link_lost_in_control(self) -> bool:
        """The link was lost (or our setpoint stream stalled) since the autopilot was last seen in control: a mode
        change since is the autopilot's failsafe, and the daemon may re-engage."""
        return self._link_lost_in_control

    def frames_due_from(self, t_s: float) -> None:
        """The maps exist from ``t_s`` on: the first frame has ``depth_timeout_s`` from then to arrive."""
        self._last_fused_s = t_s

    def blind(self, now: float) -> str | None:
        """Why the daemon must hold for want of depth (no frame fused for ``depth_timeout_s``), or None."""
        if now - self._last_fused_s > self.config.depth_timeout_s:
            return f"no usable depth frame for more than {self.config.depth_timeout_s:.1f} s"
        return None

    def check(self, now: float) -> InputCheck:
        """Whether the daemon may fly on its inputs now (see :class:`InputCheck`)."""
        cfg = self.config
        with self.timings.timed("mavlink_io"):
            status = self.link.status()
            pose = self.link.latest_pose()
        if not status.connected:
            self._link_lost_in_control = True
            return InputCheck(
                f"MAVLink link lost (no autopilot heartbeat for {self.link.config.link_lost_after_s:.1f} s)"
            )
        if status.odometry_age_s is None or status.odometry_age_s > cfg.odometry_max_age_s or pose is None:
            return InputCheck(f"odometry stale (none for more than {cfg.odometry_max_age_s:.1f} s)")
        previous, self._last_pose = self._last_pose, pose
        jump_xy_m = None
        if previous is not None:
            dt = max(pose.stamp_s - previous.stamp_s, 0.0)
            jump = math.dist((pose.x_m, pose.y_m, pose.z_m), (previous.x_m, previous.y_m, previous.z_m))
            if jump > cfg.pose_jump_m + self.speed_max_m_s * dt:
                self._jump_until_s = now + cfg.jump_settle_s
                log.warning(
                    "odometry jumped %.2f m in %.2f s: the maps are in the old frame, starting new ones; frames are "
                    "not fused for %.1f s",
                    jump,
                    dt,
                    cfg.jump_settle_s,
                )
                jump_xy_m = (pose.x_m - previous.x_m, pose.y_m - previous.y_m)
        if now < self._jump_until_s:
            return InputCheck("settling after an odometry jump", jump_xy_m)
        return InputCheck(self.mode_problem(status), jump_xy_m)

    def mode_problem(self, status: LinkStatus) -> str | None:
        """Hold while the autopilot is not in the external-control mode; end the run if a pilot took over.

        The autopilot also leaves it on its own when our setpoint stream stops (PX4's offboard-loss failsafe): after
        a link loss, or when this process got no CPU time for longer than the stream may pause
        (:data:`~edge_explorer.runtime.mavlink_link.STREAM_STALL_S`). Then the daemon takes control back once the
        stream is healthy; otherwise a pilot or another failsafe acted and the run ends.
        """
        wanted = AUTOPILOT_MODES[self.config.autopilot]
        if status.armed and status.mode == wanted:
            self._link_lost_in_control = False
            return None
        if status.setpoint_stall is not None and time.monotonic() - status.setpoint_stall[0] < STALL_BLAME_S:
            self._link_lost_in_control = True
            return (
                f"autopilot in {status.mode or 'unknown mode'} after our setpoint stream stalled for "
                f"{status.setpoint_stall[1]:.1f} s: re-engaging {wanted}"
            )
        if self._link_lost_in_control:
            return f"autopilot in {status.mode or 'unknown mode'} after the link loss: re-engaging {wanted}"
        self.state.stop_reason = f"pilot took over (autopilot left {wanted} for {status.mode or 'an unknown mode'})"
        return self.state.stop_reason

    def ingest(self, frame: DepthFrame) -> None:
        """Check ``frame`` and fuse it at its pose, or drop it (counted per reason, logged at most every 5 s)."""
        problem = frame_problem(frame, self._last_frame_stamp_s)
        if problem is None and time.monotonic() < self._jump_until_s:
            problem = "odometry jump settling"
        pose = None
        if problem is None:
            with self.timings.timed("mavlink_io"):
                pose = frame.pose if frame.pose is not None else self.link.pose_at(frame.stamp_s)
            if pose is None:
                problem = "no odometry at the frame's time"
        if problem is not None:
            self._drop(problem)
            return
        voxels = self.maps.voxels
        assert pose is not None and voxels is not None
        camera = CameraPose(pose.x_m, pose.y_m, pose.z_m, pose.yaw_rad, pose.pitch_rad, pose.roll_rad)
        start = time.perf_counter()
        try:
            voxels.fuse(
                frame.depth_m, frame.intrinsics, camera.position_m, camera.rotation_map_from_optical(), frame.stamp_s
            )
        except FusionInputError as exc:
            self._drop(f"rejected by fusion ({exc})")
            return
        self.timings.add("fuse", time.perf_counter() - start)
        self._last_frame_stamp_s = frame.stamp_s
        self._last_fused_s = time.monotonic()
        self.record.frame_fused()
        if pose.z_m >= self.config.band.min_z_m:  # the footprint is stamped once the vehicle flies at band height
            self.maps.mark_flown(pose.x_m, pose.y_m, self.config.footprint_clear_m)
        if self.recorder is not None:
            self.recorder.write(frame, pose)

    def _drop(self, reason: str) -> None:
        self.record.frame_dropped(reason)
        self._throttled.warn(reason, f"depth frame dropped: {reason}")
