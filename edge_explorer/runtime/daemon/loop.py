"""The daemon's loop (:class:`Daemon`): per iteration, the next depth frame, the input checks, the frame's fusion,
then either a hold, the take-off's progress or — when one is due — a decision.

The daemon composes its parts, each a plain object built from explicit inputs, one module each: the input watchdog
and frame ingestion (:class:`~.watchdog.InputWatchdog`), the flight phases and holds
(:class:`~.phases.FlightPhases`), the decision pipeline (:class:`~.decisions.DecisionPipeline`), the setpoint
stream (:class:`~.setpoints.SetpointFeeder`) and the run record (:class:`~.record.RunRecord`). What several of them
share is explicit too (:mod:`.state`): where the flight stands (:class:`~.state.FlightState`) and the maps
(:class:`~.state.FlightMaps`)."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

from edge_explorer.mapping.growing import GrowingMaps
from edge_explorer.plan.frontier import GoalPlanner
from edge_explorer.plan.policy import PolicyRuntime
from edge_explorer.predict.predictor import PredictorRuntime
from edge_explorer.runtime.daemon.config import DaemonConfig
from edge_explorer.runtime.daemon.decisions import DecisionPipeline
from edge_explorer.runtime.daemon.phases import FlightPhases
from edge_explorer.runtime.daemon.record import RunRecord
from edge_explorer.runtime.daemon.report import CoverageTruth, DecisionView, Progress, RunReport, StageTimings
from edge_explorer.runtime.daemon.setpoints import SetpointFeeder
from edge_explorer.runtime.daemon.state import FlightMaps, FlightState
from edge_explorer.runtime.daemon.watchdog import InputWatchdog
from edge_explorer.runtime.depth_sources import DepthSource, Recorder
from edge_explorer.runtime.mavlink_link import MavlinkLink
from edge_explorer.vehicle.dynamics import ActionTable, load_action_table

log = logging.getLogger(__name__)


class Daemon:
    """The closed loop of one flight. Build it, :meth:`run` it; :meth:`request_stop` may come from a signal.

    ``link`` must be started (and connected) by the caller, who also stops it afterwards (that sends the final hold
    setpoint and closes the telemetry log). ``truth`` (a plan of the building) enables coverage and the coverage
    goal, nothing else: the maps start around the take-off point and grow as the vehicle observes
    (:class:`~.state.FlightMaps`), never sized from the plan. ``recorder`` keeps every fused frame with its pose,
    for replay.
    """

    def __init__(
        self,
        config: DaemonConfig,
        link: MavlinkLink,
        source: DepthSource,
        policy: PolicyRuntime | None = None,
        predictor: PredictorRuntime | None = None,
        truth: CoverageTruth | None = None,
        table: ActionTable | None = None,
        recorder: Recorder | None = None,
    ) -> None:
        self.config = config
        self.link = link
        self.source = source
        self.truth = truth
        self.table = table if table is not None else load_action_table()
        self.recorder = recorder
        self.timings = StageTimings()
        self.state = FlightState()
        self.flight_maps = FlightMaps(config.fusion, config.map_growth)
        self.record = RunRecord(config.coverage_goal, self.timings, truth)
        self.feeder = SetpointFeeder(link, config.setpoint_rate_hz, self.timings)
        self.phases = FlightPhases(config, link, self.table, self.feeder, self.state, self.flight_maps, self.record)
        self.watchdog = InputWatchdog(
            config,
            link,
            self.table.model.speed_max_m_s,
            self.timings,
            self.flight_maps,
            self.state,
            self.record,
            recorder,
        )
        self.decisions = DecisionPipeline(
            config,
            link,
            self.table,
            self.timings,
            self.feeder,
            self.flight_maps,
            self.phases,
            self.record,
            policy,
            predictor,
        )

    # ---- what the rest of the code reads ----------------------------------------------------------------------

    @property
    def phase(self) -> str:
        """``takeoff``, ``exploring``, ``returning``, ``home`` or ``done``."""
        return self.state.phase

    @property
    def home_xy_m(self) -> tuple[float, float] | None:
        return self.state.home_xy

    @property
    def maps(self) -> GrowingMaps | None:
        """The voxel maps (None before take-off; new ones after a pose jump)."""
        return self.flight_maps.voxels

    @property
    def view(self) -> DecisionView | None:
        """The latest decision's maps."""
        return self.decisions.view

    @property
    def policy(self) -> PolicyRuntime | None:
        """The learned goal policy; None without one, or once it failed in flight."""
        return self.decisions.policy

    @property
    def predictor(self) -> PredictorRuntime | None:
        """The predictor; None without one, or once it failed in flight."""
        return self.decisions.predictor

    @property
    def frontier(self) -> GoalPlanner:
        """The goal planner that explores."""
        return self.decisions.planner

    @property
    def planner_name(self) -> str:
        return self.decisions.planner_name

    def request_stop(self, reason: str) -> None:
        """End the run at the next loop iteration with a hold (safe to call from a signal handler)."""
        self.state.stop_reason = reason

    # ---- the loop -----------------------------------------------------------------------------------------------

    def run(self, progress: Callable[[Progress], None] | None = None) -> RunReport:
        """Take off, explore, fly home, hover; returns the report. Raises :class:`LinkError` if the autopilot
        cannot be taken into OFFBOARD (GUIDED) at the start."""
        wall0, cpu0 = time.monotonic(), time.process_time()
        self.record.start(wall0)
        self.watchdog.frames_due_from(self.phases.take_off())
        self.feeder.start()
        next_progress_s = wall0
        try:
            while self.state.stop_reason is None and self.state.phase != "done":
                self._iterate()
                now = time.monotonic()
                if progress is not None and now >= next_progress_s:
                    progress(self._progress(now))
                    next_progress_s = now + self.config.progress_every_s
        finally:
            self.feeder.stop()
            self.phases.hold_position()
        if self.state.stop_reason is not None:
            self.state.ending = self.state.stop_reason
            log.warning("stopping: %s; holding position", self.state.stop_reason)
        maps = self.flight_maps.voxels
        if maps is not None:
            width_m, height_m = maps.grid.size_xy_m
            log.info(
                "maps grew to %.1f × %.1f m (%d growths, the 0.05 m window moved %d times; %.0f MB of arrays)",
                width_m,
                height_m,
                maps.growths,
                maps.recentrings,
                maps.nbytes() / 1e6,
            )
        if progress is not None:
            progress(self._progress(time.monotonic()))
        return self.record.report(
            time.monotonic() - wall0,
            time.process_time() - cpu0,
            ending=self.state.ending or "not started",
            planner=self.decisions.planner_name,
            predictor=self.decisions.predictor is not None,
            exploration_s=self.phases.exploration_s(),
            returned_home=self.state.reached_home,
        )

    def _iterate(self) -> None:
        cpu0 = time.thread_time()
        frame = self.source.next_frame(timeout_s=0.1)
        frame_in_cpu_s = time.thread_time()
        self.record.add_source_cpu(frame_in_cpu_s - cpu0)
        frame_in_s = time.monotonic()
        if frame is None and self.source.finished:
            self.state.stop_reason = self.state.stop_reason or "replay finished"
            return
        check = self.watchdog.check(frame_in_s)
        if check.jump_xy_m is not None:
            self._restart_in_the_new_frame(*check.jump_xy_m)
        if frame is not None:
            self.watchdog.ingest(frame)
        hold_reason = check.hold_reason
        if hold_reason is None and self.state.phase != "takeoff":  # the vertical climb needs no map
            hold_reason = self.watchdog.blind(frame_in_s)
        if hold_reason is not None:
            self.phases.enter_hold(hold_reason, self.watchdog.link_lost_in_control)
            return
        if self.phases.hold_reason is not None:
            self.phases.leave_hold()
            self.decisions.restart_at_rest()
        if self.state.phase == "takeoff":
            self.phases.check_takeoff_done(self.watchdog.last_pose, self.decisions.planner_name)
        elif self.phases.decision_due(time.monotonic()):
            self.decisions.decide(frame_in_s, frame_in_cpu_s)

    def _restart_in_the_new_frame(self, dx_m: float, dy_m: float) -> None:
        """Odometry jumped by (dx, dy): the maps and the goal planner's goals are in the old frame, so they start
        afresh, and home moves with the frame."""
        self.flight_maps.reset()
        self.decisions.planner.reset()
        self.state.move_home(dx_m, dy_m)

    def _progress(self, now: float) -> Progress:
        return self.record.progress(now, self.state.phase, self.phases.hold_reason)
