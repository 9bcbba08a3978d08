"""The flight-phase state machine: take-off → exploring → returning → home → done, and holding position.

**Take-off**: wait for the autopilot's heartbeat and odometry, engage OFFBOARD (PX4) or GUIDED with a take-off
(ArduPilot), start the voxel maps around the take-off point (home) and climb to flight height on a minimum-jerk
segment. **Exploring** until the coverage goal, the time limit, or the frontier planner has nothing left
(:meth:`FlightPhases._finish_exploring`). **Returning**: along a path home over observed free space, with the same
six actions, until there or ``return_time_limit_s``. **Home**: hover for ``home_hover_s``, then done.

**Holding** (:meth:`FlightPhases._enter_hold`): on any input problem the watchdog reports, the setpoint stream
stops and the link holds the latest odometry pose; the daemon resumes when the input is back (restarting the climb
when it held during take-off), ends the flight after ``max_hold_s``, and re-engages OFFBOARD when PX4 left it
because our setpoints stopped reaching it (ArduPilot keeps GUIDED through a link loss: if it left, its failsafe
acted and the run ends)."""

from __future__ import annotations

import logging
import time

import numpy as np

from edge_explorer.mapping.observed import ObservedMaps
from edge_explorer.mapping.voxels import VoxelMaps, VoxelRegion
from edge_explorer.plan.follow import FreeSpace, choose_action
from edge_explorer.plan.trajectory import TrajectoryState, min_jerk_segment
from edge_explorer.plan.waypoint import path_home
from edge_explorer.runtime.daemon.config import band_z_range_m
from edge_explorer.runtime.mavlink_link import LinkError
from edge_explorer.vehicle.dynamics import Action

log = logging.getLogger(__name__)


class FlightPhases:
    """The daemon's phases, holds and the way home (see the module docstring). Owns the phase, the stop reason and
    the ending, home and the exploration times, the current hold; reads the daemon's ``link``, ``config``,
    ``_feeder`` and ``table``."""

    def _init_phases(self) -> None:
        self._stop_reason: str | None = None
        self._ending: str | None = None
        self._phase = "takeoff"  # takeoff → exploring → returning → home → done
        self._home_xy: tuple[float, float] | None = None
        self._home_since_s: float | None = None
        self._explore_start_s: float | None = None
        self._explore_end_s: float | None = None
        self._hold_reason: str | None = None
        self._hold_since_s = 0.0

    def _enter_hold(self, reason: str) -> None:
        if self._hold_reason is None:
            log.warning("holding position: %s", reason)
            self._hold_since_s = time.monotonic()
            self._feeder.clear()
            self._hold_position()
            self._holds.append({"t_s": self._hold_since_s - self._t0_s, "reason": reason, "duration_s": None})
        elif reason != self._hold_reason:
            log.warning("still holding position: %s", reason)
        self._hold_reason = reason
        if time.monotonic() - self._hold_since_s > self.config.max_hold_s:
            self._stop_reason = f"held position for more than {self.config.max_hold_s:.0f} s ({reason})"
        if self._link_lost_in_control and reason.startswith("autopilot in"):
            self._try_reengage()

    def _leave_hold(self) -> None:
        held_s = time.monotonic() - self._hold_since_s
        log.info("inputs healthy again after %.1f s (%s): resuming", held_s, self._hold_reason)
        self._holds[-1]["duration_s"] = held_s
        self._hold_reason = None
        self._previous_action = int(Action.HOVER)  # the step restarts at rest where the vehicle is
        if self._phase == "takeoff":
            self._climb()

    def _hold_position(self) -> None:
        try:
            self.link.hold()
        except LinkError as exc:  # no odometry ever: the last target keeps streaming
            log.warning("cannot hold at the current pose (%s); the last target keeps streaming", exc)

    def _try_reengage(self) -> None:
        """PX4 left OFFBOARD because our setpoints stopped reaching it: take control back (it streams a hold
        first). ArduPilot keeps GUIDED through a link loss, so if it left, its failsafe acted: end the run."""
        if self.config.autopilot != "px4":
            self._stop_reason = "autopilot left GUIDED during the link loss (its failsafe acted)"
            return
        log.info("re-engaging OFFBOARD after the link loss")
        try:
            self.link.start_offboard(warmup_s=self.config.offboard_warmup_s, timeout_s=3.0)
        except LinkError as exc:
            log.warning("could not re-engage OFFBOARD yet: %s", exc)

    def _take_off(self) -> None:
        cfg = self.config
        self.link.wait_until(lambda s: s.connected and not s.odometry_stale, 15.0, "autopilot heartbeat and odometry")
        if cfg.autopilot == "px4":
            self.link.start_offboard(warmup_s=cfg.offboard_warmup_s)
        else:
            self.link.start_guided(cfg.flight_height_m)
        pose = self.link.latest_pose()
        assert pose is not None
        self._home_xy = (pose.x_m, pose.y_m)
        if self._region is None:
            z_min_m, z_max_m = band_z_range_m(self.config.band)
            self._region = VoxelRegion((pose.x_m - 12.0, pose.y_m - 7.0, z_min_m), (24.0, 14.0, z_max_m - z_min_m))
        self._new_maps()
        self._last_fused_s = time.monotonic()
        log.info(
            "maps: %.1f × %.1f m at %.2f / %.2f m (%.0f MB); home (%.2f, %.2f)",
            *self._region.size_xyz_m[:2],
            self.maps.high.resolution_m,
            self.maps.low.resolution_m,
            (self.maps.high.log_odds.nbytes + self.maps.low.log_odds.nbytes) * 2 / 1e6,
            *self._home_xy,
        )
        self._climb()

    def _new_maps(self) -> None:
        """Empty voxel maps over the region, and no flown footprint."""
        assert self._region is not None
        self.maps = VoxelMaps(self._region, self.config.fusion)
        self._flown_grid = self.maps.high.grid
        self._flown = np.zeros(self._flown_grid.shape, dtype=np.uint8)

    def _climb(self) -> None:
        """Fly from the current pose to flight height above it (at the start, and after a hold during take-off)."""
        pose = self.link.latest_pose()
        assert pose is not None
        climb_m = abs(self.config.flight_height_m - pose.z_m)
        start = TrajectoryState.at_rest(pose.x_m, pose.y_m, pose.z_m, pose.yaw_rad)
        end = TrajectoryState.at_rest(pose.x_m, pose.y_m, self.config.flight_height_m, pose.yaw_rad)
        duration_s = max(1.0, climb_m / self.config.takeoff_speed_mps)
        self._feeder.follow(min_jerk_segment(start, end, duration_s), time.monotonic())
        log.info("climbing from %.2f m to %.2f m in %.1f s", pose.z_m, self.config.flight_height_m, duration_s)

    def _check_takeoff_done(self) -> None:
        pose = self._last_pose
        end_s = self._feeder.end_s
        if pose is None or end_s is None or time.monotonic() < end_s:
            return
        if abs(pose.z_m - self.config.flight_height_m) < 0.15:
            self._phase = "exploring"
            self._explore_start_s = time.monotonic()
            log.info("at flight height: exploring with the %s planner", self.planner_name)

    def _finish_exploring(self, why: str) -> None:
        self._ending = why
        self._explore_end_s = time.monotonic()
        log.info("exploration ended: %s", why)
        self._phase = "returning" if self.config.return_home else "home"
        if self._phase == "home":
            self._home_since_s = time.monotonic()

    def _decision_due(self, now: float) -> bool:
        if self._phase == "home":
            if self._home_since_s is not None and now - self._home_since_s >= self.config.home_hover_s:
                self._phase = "done"
            return False
        end_s = self._feeder.end_s
        return end_s is None or now >= end_s - self.config.decision_lead_s

    def _check_end_of_exploration(self, now: float) -> None:
        assert self._explore_start_s is not None
        if self._metrics is not None and self._metrics.coverage >= self.config.coverage_goal:
            self._finish_exploring("coverage goal")
        elif now - self._explore_start_s >= self.config.time_limit_s:
            self._finish_exploring("time limit")

    def _home_action(self, maps: ObservedMaps, pose: tuple[float, float, float]) -> int | None:
        """The next action along a path home over observed free space; None (and hovering) once there."""
        assert self._home_xy is not None and self._explore_end_s is not None
        cfg = self.config
        free = FreeSpace.from_codes(maps.high, maps.high_grid)
        path = path_home(free, pose[:2], self._home_xy, cfg.follow.safe_distance_m)
        action = None
        if path is not None:
            action = choose_action(self.table, pose, self._previous_action, path, free, cfg.follow)
        arrived = path is not None and action is None
        timed_out = time.monotonic() - self._explore_end_s > cfg.return_time_limit_s
        if arrived or timed_out:
            if timed_out and not arrived:
                log.warning("no way home within %.0f s: hovering here", cfg.return_time_limit_s)
            else:
                log.info("home: hovering for %.0f s", cfg.home_hover_s)
            self._phase = "home"
            self._home_since_s = time.monotonic()
            return None
        return action
