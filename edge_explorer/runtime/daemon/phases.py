"""The flight-phase state machine: take-off → exploring → returning → home → done, and holding position.

**Take-off**: wait for the autopilot's heartbeat and odometry, engage OFFBOARD (PX4) or GUIDED with a take-off
(ArduPilot), start the voxel maps around the take-off point (home) and climb to flight height on a minimum-jerk
segment. **Exploring** until the coverage goal (with a plan of the building), the map stop rule (without one: the
maps' unverified area below ``stop_threshold_m2``, :mod:`edge_explorer.predict.verification`), the time limit, or
the frontier planner has nothing left (:meth:`FlightPhases.finish_exploring`). **Returning**: along a path home
over observed free space, with the same six actions, until there or out of time (``return_time_limit_s``, or twice
the reserve for the way home where that is longer). **Home**: hover for
``home_hover_s``, then done.

**Holding** (:meth:`FlightPhases.enter_hold`): on any input problem the watchdog reports, the setpoint stream
stops and the link holds the latest odometry pose; the daemon resumes when the input is back (restarting the climb
when it held during take-off), ends the flight after ``max_hold_s``, and re-engages OFFBOARD when PX4 left it
because our setpoints stopped reaching it (ArduPilot keeps GUIDED through a link loss: if it left, its failsafe
acted and the run ends).

Where the flight stands (phase, home, stop reason, ending) is the shared :class:`~.state.FlightState`; the voxel
maps the take-off starts are the shared :class:`~.state.FlightMaps`; holds go into the :class:`~.record.RunRecord`.
What the phases need from the other parts (the latest odometry, the coverage, the previous action, whether the link
was lost while in control) comes in as method arguments."""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from edge_explorer.mapping.observed import ObservedMaps
from edge_explorer.plan.follow import FreeSpace, choose_action
from edge_explorer.plan.trajectory import TrajectoryState, min_jerk_segment
from edge_explorer.plan.waypoint import path_home
from edge_explorer.plan.window import crop_maps, known_window, place_window
from edge_explorer.runtime.daemon.config import DaemonConfig
from edge_explorer.runtime.daemon.record import RunRecord
from edge_explorer.runtime.daemon.setpoints import SetpointFeeder
from edge_explorer.runtime.daemon.state import FlightMaps, FlightState
from edge_explorer.runtime.mavlink_link import LinkError, MavlinkLink
from edge_explorer.runtime.mavlink_link import Pose as Odometry
from edge_explorer.vehicle.dynamics import Action, ActionTable

log = logging.getLogger(__name__)
MAP_STOP_ENDING = "map says verified"  # the ending of an exploration the map stop rule ended (issue #56)
HOME_REACHED_M = 1.0  # a return that ends this close to home reached it (the report's returned_home)
# The return has arrived this close to home: a forward step is ~0.5 m, and the follower cannot close the last few
# decimetres to its path's end by steps of that size (session 45: a 15-minute flight of the 271 m floor turned in
# place 0.31 m from home, its path's end 0.05 m beyond the follower's 0.25 m goal tolerance, until the return's
# time ran out).
HOME_ARRIVAL_M = 0.5
# The return's follower reads this square around the vehicle: its two-step motions end within ~1.5 m and it reads
# clearances up to its comfort distance, so it answers as on the whole map (the safety check's window, decisions.py).
FOLLOW_WINDOW_M = 8.0
# The way home is planned on the known cells of the maps and this much around them: more than the 1 m ring beyond the
# known cells within which the follower's free space measures distances (plan/follow.py, FreeSpace.from_codes).
HOME_CROP_MARGIN_M = 2.0


class FlightPhases:
    """The daemon's phases, holds and the way home (see the module docstring).

    Inputs: ``config``; ``link`` (start sequence, hold, re-engage); ``table``, the actions the way home flies;
    ``feeder``, the setpoint stream (the climb's segment; cleared on a hold); ``state``, moved along; ``maps``,
    started at take-off; ``record``, told about every hold. Owns the current hold (its reason and start), the
    exploration's start and end and when the vehicle arrived home."""

    def __init__(
        self,
        config: DaemonConfig,
        link: MavlinkLink,
        table: ActionTable,
        feeder: SetpointFeeder,
        state: FlightState,
        maps: FlightMaps,
        record: RunRecord,
    ) -> None:
        self.config = config
        self.link = link
        self.table = table
        self.feeder = feeder
        self.state = state
        self.maps = maps
        self.record = record
        self._home_since_s: float | None = None
        self._explore_start_s: float | None = None
        self._explore_end_s: float | None = None
        self._hold_reason: str | None = None
        self._hold_since_s = 0.0
        self._way_home: tuple[float, tuple[float, float]] | None = None  # (path home m, measured from xy m)
        self._way_home_s: float | None = None  # when it was measured
        self._return_limit_s: float | None = None  # how long the return may take, set on its first step
        self._home_path: np.ndarray | None = None  # the return's path home, planned at _home_path_s
        self._home_path_s: float | None = None

    @property
    def phase(self) -> str:
        """``takeoff``, ``exploring``, ``returning``, ``home`` or ``done``."""
        return self.state.phase

    @property
    def hold_reason(self) -> str | None:
        """Why the daemon holds position now; None while it flies."""
        return self._hold_reason

    def exploration_s(self) -> float | None:
        """How long it explored (so far); None before it started."""
        if self._explore_start_s is None:
            return None
        return (self._explore_end_s or time.monotonic()) - self._explore_start_s

    def enter_hold(self, reason: str, link_lost_in_control: bool = False) -> None:
        """Hold position for ``reason`` (or go on holding); end the run after ``max_hold_s``; re-engage the
        autopilot's external-control mode when it left it after ``link_lost_in_control``."""
        if self._hold_reason is None:
            log.warning("holding position: %s", reason)
            self._hold_since_s = time.monotonic()
            self.feeder.clear()
            self.hold_position()
            self.record.hold_began(self._hold_since_s, reason)
        elif reason != self._hold_reason:
            log.warning("still holding position: %s", reason)
        self._hold_reason = reason
        if time.monotonic() - self._hold_since_s > self.config.max_hold_s:
            self.state.stop_reason = f"held position for more than {self.config.max_hold_s:.0f} s ({reason})"
        if link_lost_in_control and reason.startswith("autopilot in"):
            self._try_reengage()

    def leave_hold(self) -> None:
        """The inputs are healthy again: resume (restarting the climb when it held during take-off). The next step
        starts at rest where the vehicle is (the decision pipeline's :meth:`restart_at_rest`)."""
        held_s = time.monotonic() - self._hold_since_s
        log.info("inputs healthy again after %.1f s (%s): resuming", held_s, self._hold_reason)
        self.record.hold_ended(held_s)
        self._hold_reason = None
        if self.state.phase == "takeoff":
            self.climb()

    def hold_position(self) -> None:
        try:
            self.link.hold()
        except LinkError as exc:  # no odometry ever: the last target keeps streaming
            log.warning("cannot hold at the current pose (%s); the last target keeps streaming", exc)

    def _try_reengage(self) -> None:
        """PX4 left OFFBOARD because our setpoints stopped reaching it: take control back (it streams a hold
        first). ArduPilot keeps GUIDED through a link loss, so if it left, its failsafe acted: end the run."""
        if self.config.autopilot != "px4":
            self.state.stop_reason = "autopilot left GUIDED during the link loss (its failsafe acted)"
            return
        log.info("re-engaging OFFBOARD after the link loss")
        try:
            self.link.start_offboard(warmup_s=self.config.offboard_warmup_s, timeout_s=3.0)
        except LinkError as exc:
            log.warning("could not re-engage OFFBOARD yet: %s", exc)

    def take_off(self) -> float:
        """Engage the autopilot, start the maps around home and climb; returns when the maps were started."""
        cfg = self.config
        self.link.wait_until(lambda s: s.connected and not s.odometry_stale, 15.0, "autopilot heartbeat and odometry")
        if cfg.autopilot == "px4":
            self.link.start_offboard(warmup_s=cfg.offboard_warmup_s)
        else:
            self.link.start_guided(cfg.flight_height_m)
        pose = self.link.latest_pose()
        assert pose is not None
        self.state.home_xy = (pose.x_m, pose.y_m)
        self.maps.start(pose.x_m, pose.y_m, cfg.band)
        maps_started_s = time.monotonic()
        voxels, region = self.maps.voxels, self.maps.region
        assert voxels is not None and region is not None
        log.info(
            "maps: %.1f × %.1f m at %.2f / %.2f m (%.0f MB); home (%.2f, %.2f)",
            *region.size_xyz_m[:2],
            voxels.high.resolution_m,
            voxels.low.resolution_m,
            (voxels.high.log_odds.nbytes + voxels.low.log_odds.nbytes) * 2 / 1e6,
            *self.state.home_xy,
        )
        self.climb()
        return maps_started_s

    def climb(self) -> None:
        """Fly from the current pose to flight height above it (at the start, and after a hold during take-off)."""
        pose = self.link.latest_pose()
        assert pose is not None
        climb_m = abs(self.config.flight_height_m - pose.z_m)
        start = TrajectoryState.at_rest(pose.x_m, pose.y_m, pose.z_m, pose.yaw_rad)
        end = TrajectoryState.at_rest(pose.x_m, pose.y_m, self.config.flight_height_m, pose.yaw_rad)
        duration_s = max(1.0, climb_m / self.config.takeoff_speed_mps)
        self.feeder.follow(min_jerk_segment(start, end, duration_s), time.monotonic())
        log.info("climbing from %.2f m to %.2f m in %.1f s", pose.z_m, self.config.flight_height_m, duration_s)

    def check_takeoff_done(self, pose: Odometry | None, planner_name: str) -> None:
        """Start exploring (with ``planner_name``) once the climb's segment ended at flight height (``pose``)."""
        end_s = self.feeder.end_s
        if pose is None or end_s is None or time.monotonic() < end_s:
            return
        if abs(pose.z_m - self.config.flight_height_m) < 0.15:
            self.state.phase = "exploring"
            self._explore_start_s = time.monotonic()
            log.info("at flight height: exploring with the %s planner", planner_name)

    def finish_exploring(self, why: str) -> None:
        self.state.ending = why
        self._explore_end_s = time.monotonic()
        log.info("exploration ended: %s", why)
        self.state.phase = "returning" if self.config.return_home else "home"
        if self.state.phase == "home":
            self._home_since_s = time.monotonic()

    def decision_due(self, now: float) -> bool:
        """Whether to decide now: when the reference is about to reach its waypoint (never once home, where the
        hover ends the flight after ``home_hover_s``)."""
        if self.state.phase == "home":
            if self._home_since_s is not None and now - self._home_since_s >= self.config.home_hover_s:
                self.state.phase = "done"
            return False
        end_s = self.feeder.end_s
        return end_s is None or now >= end_s - self.config.decision_lead_s

    def check_end_of_exploration(
        self,
        now: float,
        coverage: float | None,
        unverified_m2: float | None = None,
        xy_m: tuple[float, float] | None = None,
    ) -> None:
        """End exploration at the coverage goal (``coverage``: the latest, None without a plan), by the map stop rule
        when there is no plan (``unverified_m2``: the latest unverified area, below ``stop_threshold_m2``: "map says
        verified") or when the time left in the flight budget is the reserve to fly home from ``xy_m``."""
        assert self._explore_start_s is not None
        if coverage is not None and coverage >= self.config.coverage_goal:
            self.finish_exploring("coverage goal")
        elif coverage is None and unverified_m2 is not None and unverified_m2 < self.config.stop_threshold_m2:
            self.finish_exploring(MAP_STOP_ENDING)
        elif now - self._explore_start_s + self.home_reserve_s(xy_m) >= self.config.time_limit_s:
            self.finish_exploring("time limit")

    def home_reserve_s(self, xy_m: tuple[float, float] | None) -> float:
        """The time kept in the flight budget to fly home from ``xy_m`` at cruise speed, plus the hover at home and a
        margin (none without a return home). The way home is the last measured path home (:meth:`measure_way_home`)
        plus the straight line from where it was measured to ``xy_m``, × ``home_path_slack``; before the first
        measurement, the straight line home × ``home_detour_factor``. Never less than the straight line."""
        cfg = self.config
        if not cfg.return_home or xy_m is None or self.state.home_xy is None:
            return 0.0
        cruise_m_s = self.table.model.forward_step_m / self.table.model.step_s
        straight_m = math.dist(xy_m, self.state.home_xy)
        if self._way_home is None:
            way_m = straight_m * cfg.home_detour_factor
        else:
            path_m, measured_at = self._way_home
            way_m = max(straight_m, (path_m + math.dist(xy_m, measured_at)) * cfg.home_path_slack)
        return way_m / cruise_m_s + cfg.home_hover_s + cfg.home_reserve_margin_s

    def _path_home(self, maps: ObservedMaps, xy_m: tuple[float, float]) -> np.ndarray | None:
        """The way home from ``xy_m`` over the whole observed map (:func:`~edge_explorer.plan.waypoint.path_home`)."""
        assert self.state.home_xy is not None
        # On the known part of the maps only (the same path: it crosses known cells, and the free space is measured
        # at most the follower's ring beyond them): a whole floor's maps hold tens of metres of unknown slack ahead of
        # the flight, and this plan's transient was the daemon's peak memory (303 MB on a 271 m floor, bound 300).
        near = crop_maps(maps, known_window(maps, (xy_m, self.state.home_xy), HOME_CROP_MARGIN_M))
        free = FreeSpace.from_codes(near.high, near.high_grid)
        return path_home(free, xy_m, self.state.home_xy, self.config.follow.safe_distance_m)

    def _plan_home(self, maps: ObservedMaps, pose: tuple[float, float, float], now: float) -> None:
        self._home_path, self._home_path_s = self._path_home(maps, pose[:2]), now

    def replan_home(self, maps: ObservedMaps, pose: tuple[float, float, float], now: float) -> None:
        """While returning, plan the path home again from ``pose`` over ``maps`` when the last plan is
        ``home_path_every_s`` old: run after the decision's waypoint is out (a plan over the whole observed map costs
        ~0.1–0.2 s on a 271 m floor, ten decisions' latency budget), so the next decisions follow the new path."""
        if self.state.phase != "returning" or self._home_path_s is None:
            return
        if now - self._home_path_s >= self.config.home_path_every_s:
            self._plan_home(maps, pose, now)

    def measure_way_home(self, maps: ObservedMaps, xy_m: tuple[float, float], now: float) -> None:
        """Measure the path home from ``xy_m`` over the observed map — the path the return would fly now
        (:func:`~edge_explorer.plan.waypoint.path_home`) — for the reserve, at most every ``home_path_every_s``
        (about 0.2 s on a 271 m floor, so it runs after the decision's waypoint is out). A path that ends short of
        home counts the rest as a straight line; no path (the vehicle's cell has no way out) keeps the last one."""
        cfg = self.config
        if not cfg.return_home or self.state.home_xy is None:
            return
        if self._way_home_s is not None and now - self._way_home_s < cfg.home_path_every_s:
            return
        self._way_home_s = now
        path = self._path_home(maps, xy_m)
        if path is None:
            return
        path_m = float(np.hypot(*np.diff(path, axis=0).T).sum()) + math.dist(path[-1], self.state.home_xy)
        self._way_home = (path_m + math.dist(xy_m, path[0]), xy_m)

    def home_action(self, maps: ObservedMaps, pose: tuple[float, float, float], previous: int) -> int | None:
        """The next action along a path home over observed free space (after action ``previous``); None (and
        hovering) once there.

        The path is planned over the whole observed map at the first step home, again every ``home_path_every_s``
        after a decision's waypoint is out (:meth:`replan_home`: about 0.2 s on a 271 m floor), and here whenever
        the follower would hover along an older one (a wall seen since may block it); each step's follower reads only
        a ``FOLLOW_WINDOW_M`` square around the vehicle, so a step home costs the same on any floor."""
        assert self.state.home_xy is not None and self._explore_end_s is not None
        cfg = self.config
        now = time.monotonic()
        fresh = self._home_path_s is None
        if fresh:
            self._plan_home(maps, pose, now)
        near = crop_maps(maps, place_window(maps.low_grid, pose[:2], FOLLOW_WINDOW_M))
        free = FreeSpace.from_codes(near.high, near.high_grid)
        path = self._home_path
        action = None if path is None else choose_action(self.table, pose, previous, path, free, cfg.follow)
        if not fresh and action == Action.HOVER:  # the old path may be blocked now: plan again before hovering
            self._plan_home(maps, pose, now)
            path = self._home_path
            action = None if path is None else choose_action(self.table, pose, previous, path, free, cfg.follow)
        arrived = (path is not None and action is None) or math.dist(pose[:2], self.state.home_xy) <= HOME_ARRIVAL_M
        if self._return_limit_s is None:  # the first step home: a long way home gets twice its reserve to fly it
            self._return_limit_s = max(cfg.return_time_limit_s, 2.0 * self.home_reserve_s(pose[:2]))
        timed_out = time.monotonic() - self._explore_end_s > self._return_limit_s
        if arrived or timed_out:
            off_m = math.dist(pose[:2], self.state.home_xy)
            self.state.reached_home = arrived and off_m <= HOME_REACHED_M
            if timed_out and not arrived:
                log.warning("no way home within %.0f s, %.1f m from home: hovering here", self._return_limit_s, off_m)
            elif not self.state.reached_home:
                log.warning("the observed map leads no nearer home than %.1f m: hovering here", off_m)
            else:
                log.info("home: hovering for %.0f s", cfg.home_hover_s)
            self.state.phase = "home"
            self._home_since_s = time.monotonic()
            return None
        return action
