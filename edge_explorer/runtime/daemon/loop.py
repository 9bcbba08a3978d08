"""The daemon's loop (:class:`Daemon`): per iteration, the next depth frame, the input checks, the frame's fusion,
then either a hold, the take-off's progress or — when one is due — a decision.

The daemon's parts live beside it, one module each: the flight phases and holds (:mod:`.phases`), the input
watchdog and frame ingestion (:mod:`.watchdog`), the decision pipeline (:mod:`.decisions`), the setpoint stream
(:mod:`.setpoints`) and the run record and report (:mod:`.report`)."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

from edge_explorer.mapping.voxels import VoxelMaps, VoxelRegion
from edge_explorer.plan.frontier import GoalPlanner
from edge_explorer.plan.policy import PolicyRuntime
from edge_explorer.plan.registry import build_planner
from edge_explorer.predict.predictor import PredictorRuntime
from edge_explorer.runtime.daemon.config import DaemonConfig
from edge_explorer.runtime.daemon.decisions import DecisionPipeline, TimedScores
from edge_explorer.runtime.daemon.phases import FlightPhases
from edge_explorer.runtime.daemon.report import CoverageTruth, Progress, RunRecord, RunReport, StageTimings
from edge_explorer.runtime.daemon.setpoints import SetpointFeeder
from edge_explorer.runtime.daemon.watchdog import InputWatchdog
from edge_explorer.runtime.depth_sources import DepthSource, Recorder
from edge_explorer.runtime.mavlink_link import MavlinkLink
from edge_explorer.vehicle.dynamics import ActionTable, load_action_table

log = logging.getLogger(__name__)


class Daemon(FlightPhases, InputWatchdog, DecisionPipeline, RunRecord):
    """The closed loop of one flight. Build it, :meth:`run` it; :meth:`request_stop` may come from a signal.

    ``link`` must be started (and connected) by the caller, who also stops it afterwards (that sends the final hold
    setpoint and closes the telemetry log). ``truth`` (a plan of the building) enables coverage and the coverage
    goal; ``region`` is the voxel maps' box (default: 24 m × 14 m centred on the take-off point). ``recorder``
    keeps every fused frame with its pose, for replay.
    """

    def __init__(
        self,
        config: DaemonConfig,
        link: MavlinkLink,
        source: DepthSource,
        policy: PolicyRuntime | None = None,
        predictor: PredictorRuntime | None = None,
        truth: CoverageTruth | None = None,
        region: VoxelRegion | None = None,
        table: ActionTable | None = None,
        recorder: Recorder | None = None,
    ) -> None:
        self.config = config
        self.link = link
        self.source = source
        self.policy = policy
        self.predictor = predictor
        self.truth = truth
        self.table = table if table is not None else load_action_table()
        self.recorder = recorder
        self.timings = StageTimings()
        self.frontier = self._make_planner()
        self.maps: VoxelMaps | None = None
        self._region = region
        self._feeder = SetpointFeeder(link, config.setpoint_rate_hz, self.timings)
        self._init_phases()
        self._init_watchdog()
        self._init_decisions()
        self._init_record()

    def _make_planner(self) -> GoalPlanner:
        """The goal planner that explores, with this daemon's follower settings: the learned goal policy when one
        is loaded, else ``config.exploration_planner``; also the one a failing policy hands over to (without it)."""
        scores = TimedScores(self.policy, self.timings) if self.policy is not None else None
        return build_planner(self.planner_name, self.table, scores, follow=self.config.follow)

    @property
    def planner_name(self) -> str:
        return "drl" if self.policy is not None else self.config.exploration_planner

    @property
    def phase(self) -> str:
        """``takeoff``, ``exploring``, ``returning``, ``home`` or ``done``."""
        return self._phase

    @property
    def home_xy_m(self) -> tuple[float, float] | None:
        return self._home_xy

    def request_stop(self, reason: str) -> None:
        """End the run at the next loop iteration with a hold (safe to call from a signal handler)."""
        self._stop_reason = reason

    def run(self, progress: Callable[[Progress], None] | None = None) -> RunReport:
        """Take off, explore, fly home, hover; returns the report. Raises :class:`LinkError` if the autopilot
        cannot be taken into OFFBOARD (GUIDED) at the start."""
        wall0, cpu0 = time.monotonic(), time.process_time()
        self._t0_s = wall0
        self._take_off()
        self._feeder.start()
        next_progress_s = wall0
        try:
            while self._stop_reason is None and self._phase != "done":
                self._iterate()
                now = time.monotonic()
                if progress is not None and now >= next_progress_s:
                    progress(self._progress(now))
                    next_progress_s = now + self.config.progress_every_s
        finally:
            self._feeder.stop()
            self._hold_position()
        if self._stop_reason is not None:
            self._ending = self._stop_reason
            log.warning("stopping: %s; holding position", self._stop_reason)
        if progress is not None:
            progress(self._progress(time.monotonic()))
        return self._report(time.monotonic() - wall0, time.process_time() - cpu0)

    def _iterate(self) -> None:
        cpu0 = time.thread_time()
        frame = self.source.next_frame(timeout_s=0.1)
        frame_in_cpu_s = time.thread_time()
        self._source_cpu_s += frame_in_cpu_s - cpu0
        frame_in_s = time.monotonic()
        if frame is None and self.source.finished:
            self._stop_reason = self._stop_reason or "replay finished"
            return
        hold_reason = self._check_inputs(frame_in_s)
        if frame is not None:
            self._ingest(frame)
        blind = frame_in_s - self._last_fused_s > self.config.depth_timeout_s
        if hold_reason is None and blind and self._phase != "takeoff":  # the vertical climb needs no map
            hold_reason = f"no usable depth frame for more than {self.config.depth_timeout_s:.1f} s"
        if hold_reason is not None:
            self._enter_hold(hold_reason)
            return
        if self._hold_reason is not None:
            self._leave_hold()
        if self._phase == "takeoff":
            self._check_takeoff_done()
        elif self._decision_due(time.monotonic()):
            self._decide(frame_in_s, frame_in_cpu_s)
