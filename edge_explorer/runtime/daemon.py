"""The on-device exploration daemon: depth frames + MAVLink odometry in, position setpoints out (DESIGN.md §8).

One process, one loop (:class:`Daemon`), no torch. Around the loop the parts it wires together:

* **Per depth frame** (default 15 Hz): check the frame (NaN/inf, no returns, wrong shape, a timestamp not after the
  last one: dropped, with a rate-limited log line and a count per reason), take the pose at the frame's timestamp
  from the link's odometry buffer (a replayed frame brings its own), fuse it into the 0.05 m and 0.20 m voxel maps.
  :meth:`~edge_explorer.mapping.voxels.VoxelMaps.fuse` validates before it writes, so a rejected frame never
  corrupts the maps.
* **Per decision** (one per step period, 1 s by default, the period of the shared action table: a decision is due
  when the vehicle's reference reaches the previous waypoint, and is taken on the last frame before that, so the
  new segment starts without a pause): project both maps, run the predictor and threshold its output (when a
  predictor is loaded), measure coverage against the plan (when one is known), build the policy observation and
  run the policy (or the Nearest Frontier planner), turn the action into a waypoint through the action table, check
  it on the observed high-res map (:mod:`edge_explorer.plan.waypoint`: the policy's choice, else the frontier
  planner's, else hover, else hold) and plan a minimum-jerk segment to it
  (:func:`~edge_explorer.plan.trajectory.min_jerk_segment`). Without a policy the waypoint does not depend on the
  prediction (the frontier planner decides on the observed map, as in the benchmark's ``+pred`` methods), so the
  predictor then runs right after the waypoint is out, off the frame-in → waypoint-out path.
* **Setpoints**: :class:`SetpointFeeder`, a thread, samples the active segment at the setpoint rate and hands it to
  :meth:`~edge_explorer.runtime.mavlink_link.MavlinkLink.set_target`; the link streams it (with its heartbeat) to
  the autopilot.

**Where a step starts.** The autopilot tracks a moving position setpoint with a lag (about 0.25 m at 0.5 m/s for
the simulated vehicle, more for PX4's default gains). A step therefore starts from the *reference* — the end of the
previous segment, where the vehicle is about to be — not from the lagging odometry, so the vehicle moves by the
table's motion each step, as in training; the policy observation and the planners see that step-start pose. The
safety check uses the odometry position (the straight motion from where the vehicle really is). When the vehicle
is more than ``reanchor_distance_m`` off its reference (it stopped at an obstacle, a hold, a pose jump), the next
step starts at rest at the odometry pose.

**Flown space is free.** The depth camera cannot see the space right around itself (nothing closer than 0.2 m,
and the lowest layers of the projected height band only from a few decimetres on), so the cells the vehicle
stands in could stay UNKNOWN — and the planners and the safety check never fly through unknown space. The
vehicle's own body has been there, though: every 0.05 m cell within ``footprint_clear_m`` of a pose it flew
through at band height counts as FREE unless the sensor saw it occupied (as navigation costmaps clear the robot's
footprint). The simulator's planar sensor sees from zero range, so this also keeps the observation close to the
one the policy was trained on.

**Degrading safely.** The daemon holds position (the link's :meth:`hold`: the latest odometry pose) and logs why
whenever an input is missing: the autopilot's heartbeat lost, odometry older than ``odometry_max_age_s``, a pose
jump (consecutive odometry poses farther apart than the vehicle can fly plus ``pose_jump_m``: a VIO reset or
relocalisation), no usable depth frame for ``depth_timeout_s`` (not while climbing at take-off: the vertical climb
needs no map, and a camera on the ground may see nothing). After a jump the maps are in the old frame, so they are
started afresh (and home is moved by the jump); frames are not fused for ``jump_settle_s``. It resumes when the
input is back; after ``max_hold_s`` without it, it ends the flight (its last setpoint is a hold; once setpoints
stop, the autopilot's own failsafe takes over). If the autopilot leaves OFFBOARD while the link is healthy, a pilot
or a failsafe took over: the daemon ends the run instead of taking control back; if it left OFFBOARD because the
link was lost, or right after the daemon's own setpoint stream stalled (the process got no CPU time for 0.5 s:
PX4's offboard-loss failsafe), the daemon re-engages OFFBOARD once the link is back.

**A policy that makes no progress** (the observed area grew by less than ``policy_min_gain_m2`` over its last
``policy_window`` decisions) hands over to the frontier planner for the rest of the flight, said in the log.

**The end.** Exploration ends at ``coverage_goal`` (predicted coverage with a predictor, observed without), at
``time_limit_s``, or when the frontier planner has nothing left (after giving the targets it dropped
``frontier_retries`` more chances while frontier cells remain); the daemon then flies home (the take-off point,
along a path over observed free space, with the same six actions) and hovers there for ``home_hover_s``.
:meth:`Daemon.request_stop` (SIGINT/SIGTERM) ends the loop at once with a hold.

Every stage is timed (:class:`StageTimings`, reused by the profiling report) and the run is summed up in a
:class:`RunReport`.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from edge_explorer.backends.card import CARD_FILE
from edge_explorer.backends.chain import load_model
from edge_explorer.errors import EdgeExplorerError
from edge_explorer.mapping.ego import observation_from_maps
from edge_explorer.mapping.metrics import MapMetrics, map_metrics
from edge_explorer.mapping.observed import ObservedMaps
from edge_explorer.mapping.projection import HeightBand, align_to_grid, project
from edge_explorer.mapping.voxels import FusionConfig, FusionInputError, VoxelMaps, VoxelRegion
from edge_explorer.plan.follow import FollowConfig, FreeSpace, choose_action
from edge_explorer.plan.frontier import NearestFrontier, PlannerConfig, frontier_mask
from edge_explorer.plan.policy import PolicyRuntime
from edge_explorer.plan.trajectory import MinJerkSegment, TrajectoryState, min_jerk_segment
from edge_explorer.plan.waypoint import WaypointPlanner, path_home
from edge_explorer.predict.predictor import PredictorRuntime
from edge_explorer.predict.thresholding import ThresholdConfig, thresholded_map
from edge_explorer.runtime.depth_sources import DepthFrame, DepthSource, Recorder
from edge_explorer.runtime.mavlink_link import PX4_OFFBOARD_MODE, LinkError, LinkStatus, MavlinkLink
from edge_explorer.runtime.mavlink_link import Pose as Odometry
from edge_explorer.sim.camera import CameraPose
from edge_explorer.sim.dynamics import Action, ActionTable, load_action_table
from edge_explorer.world.grid import FREE, LOW_RES_M, UNKNOWN, GridSpec
from edge_explorer.world.raster import PlanRaster

log = logging.getLogger(__name__)

# Stage names of :class:`StageTimings`. "predictor": its ego window (pad + shift, unshift) and the network; "ego": the
# policy observation (rotate, crop, inflate); "planner": the Nearest Frontier planner or the way home;
# "decision": the whole frame-in → waypoint-out latency of a decision (the triggering frame's fusion included);
# "decision_cpu": the CPU time the loop's thread spent on it (all of its work runs on that thread), which does not
# grow when other processes compete for the cores — the wall-clock latency does.
STAGES: tuple[str, ...] = (
    "fuse",
    "project",
    "ego",
    "predictor",
    "thresholding",
    "coverage",
    "policy",
    "planner",
    "waypoint_trajectory",
    "mavlink_io",
    "decision",
    "decision_cpu",
)
AUTOPILOT_MODES = {"px4": PX4_OFFBOARD_MODE, "ardupilot": "GUIDED"}
# A mode change this soon after our setpoint stream stalled is the autopilot's reaction to the stall, not a pilot's.
STALL_BLAME_S = 3.0


# ---------------------------------------------------------------------------------------------------------------
# Configuration, timings and the run report
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DaemonConfig:
    """How the daemon flies and when it stops. Times in seconds, distances in metres (map frame)."""

    coverage_goal: float = 0.95
    time_limit_s: float = 600.0  # exploration time after take-off; the demo on building A reaches 95 % in ~5 min
    return_home: bool = True
    home_hover_s: float = 2.0
    return_time_limit_s: float = 180.0
    flight_height_m: float = HeightBand().flight_z_m
    takeoff_speed_mps: float = 0.5  # average climb speed (the min-jerk peak is 1.875× that)
    autopilot: str = "px4"  # start sequence: "px4" (OFFBOARD) or "ardupilot" (GUIDED + take-off)
    offboard_warmup_s: float = 1.0
    setpoint_rate_hz: float = 20.0
    decision_lead_s: float = 1.0 / 15.0  # decide on the last frame before the reference reaches its waypoint
    odometry_max_age_s: float = 0.3
    pose_jump_m: float = 1.0
    jump_settle_s: float = 1.0
    depth_timeout_s: float = 1.0
    max_hold_s: float = 60.0  # inputs not back after this long: end the flight (the autopilot's failsafe takes over)
    reanchor_distance_m: float = 0.5
    footprint_clear_m: float = 0.2  # flown space counted as free (below the 0.25 m robot radius; 0 disables)
    policy_hover_limit: int = 3  # consecutive policy hovers after which the frontier planner decides
    frontier_retries: int = 1  # times the frontier planner's dropped targets get another chance before "explored"
    # The policy hands over to the frontier planner for the rest of the flight when the observed area grew by less
    # than policy_min_gain_m2 over its last policy_window decisions (0 disables the watchdog).
    policy_window: int = 60
    policy_min_gain_m2: float = 8.0  # the frontier planner observes ~25 m² a minute on A-D, ~5 near the end
    progress_every_s: float = 5.0
    band: HeightBand = field(default_factory=HeightBand)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    thresholds: ThresholdConfig = field(default_factory=ThresholdConfig)
    # Mean-safe motions (noise_sigmas 0): the 3-sigma preference of the benchmark's follower models the training
    # simulator's per-action motion noise, while this vehicle tracks minimum-jerk setpoints (0 collisions in 16
    # acceptance flights without it); with it, narrow doorways made the vehicle hover, back off and retry for tens of
    # metres (docs/runtime/README.md).
    follow: FollowConfig = field(default_factory=lambda: FollowConfig(noise_sigmas=0.0))

    def __post_init__(self) -> None:
        if not 0 < self.coverage_goal <= 1:
            raise ValueError(f"coverage_goal must be in (0, 1], got {self.coverage_goal}")
        if self.autopilot not in AUTOPILOT_MODES:
            raise ValueError(f"autopilot must be one of {sorted(AUTOPILOT_MODES)}, got {self.autopilot!r}")
        if min(self.frontier_retries, self.policy_hover_limit, self.policy_window, self.policy_min_gain_m2) < 0:
            raise ValueError("frontier_retries, policy_hover_limit, policy_window and policy_min_gain_m2 must be ≥ 0")
        if self.setpoint_rate_hz < 10:
            raise ValueError(f"setpoint_rate_hz must be ≥ 10 (DESIGN.md §8), got {self.setpoint_rate_hz}")
        positive = (
            "time_limit_s",
            "takeoff_speed_mps",
            "odometry_max_age_s",
            "pose_jump_m",
            "depth_timeout_s",
            "max_hold_s",
            "reanchor_distance_m",
            "progress_every_s",
            "flight_height_m",
        )
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")


@dataclass(frozen=True)
class StageStats:
    """Latency percentiles of one stage, milliseconds."""

    count: int
    mean_ms: float
    p50_ms: float
    p95_ms: float
    p99_ms: float
    max_ms: float


class StageTimings:
    """Wall-clock durations per stage (:data:`STAGES`) of one run; thread-safe to add to."""

    def __init__(self) -> None:
        self._seconds: dict[str, list[float]] = {stage: [] for stage in STAGES}

    def add(self, stage: str, seconds: float) -> None:
        self._seconds[stage].append(seconds)

    @contextmanager
    def timed(self, stage: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self._seconds[stage].append(time.perf_counter() - start)

    def samples_ms(self, stage: str) -> np.ndarray:
        return 1e3 * np.asarray(self._seconds[stage], dtype=np.float64)

    def stats(self) -> dict[str, StageStats]:
        """Percentiles of every stage that ran at least once."""
        out = {}
        for stage in STAGES:
            ms = self.samples_ms(stage)
            if len(ms):
                p50, p95, p99 = np.percentile(ms, [50, 95, 99])
                out[stage] = StageStats(len(ms), float(ms.mean()), float(p50), float(p95), float(p99), float(ms.max()))
        return out


@dataclass(frozen=True)
class Progress:
    """What a progress line shows."""

    elapsed_s: float
    phase: str
    coverage: float | None
    correct_coverage: float | None
    path_length_m: float
    decisions: int
    decision_p95_ms: float | None
    holding: str | None  # why the daemon holds position, None while it flies


@dataclass(frozen=True)
class RunReport:
    """How a run went: the figures the run summary, the acceptance bench and the profiling report read."""

    ending: str  # coverage goal | time limit | explored | interrupted (…) | pilot took over (…) | replay finished
    planner: str  # "drl" or "frontier"
    predictor: bool
    coverage: float | None  # None without a plan to measure against
    correct_coverage: float | None
    f1: float | None
    path_length_m: float  # odometry positions at the decisions, like the simulator's per-step path
    path_at_goal_m: float | None  # path length when coverage first reached the goal
    exploration_s: float | None
    returned_home: bool
    decisions: int
    waypoint_sources: dict[str, int]  # policy / frontier / hover / home / hold
    frames_fused: int
    frames_dropped: dict[str, int]  # per reason
    holds: list[dict[str, Any]]  # {"t_s", "reason", "duration_s"}
    wall_s: float
    process_cpu_s: float
    source_cpu_s: float  # CPU time spent producing frames inside the loop (the camera renderer in simulation)
    stages: dict[str, StageStats]
    timeline: list[tuple[float, float | None, float | None, float]]  # (t_s, coverage, correct, path_m)
    path_xy_m: list[tuple[float, float]]

    def to_json(self) -> dict[str, Any]:
        doc = asdict(self)
        doc["stages"] = {k: asdict(v) for k, v in self.stages.items()}
        return doc


class CoverageTruth:
    """The plan's ground truth at 0.20 m, to measure coverage (DESIGN.md §7) of maps on any nesting grid."""

    def __init__(self, raster: PlanRaster) -> None:
        low = raster.coarsened(LOW_RES_M)
        self.grid = low.grid
        self.truth = low.truth_codes()
        self.interior = low.interior

    def metrics(self, observed: np.ndarray, grid: GridSpec, thresholded: np.ndarray | None) -> MapMetrics:
        observed = align_to_grid(observed, grid, self.grid)
        thres = None if thresholded is None else align_to_grid(thresholded, grid, self.grid)
        return map_metrics(observed, self.truth, self.interior, thres)


@dataclass
class DecisionView:
    """The maps of the latest decision (for the run summary's picture)."""

    high: np.ndarray
    high_grid: GridSpec
    low: np.ndarray
    low_grid: GridSpec
    thresholded: np.ndarray | None  # observed ∪ thresholded prediction, when a predictor runs


# ---------------------------------------------------------------------------------------------------------------
# The setpoint stream
# ---------------------------------------------------------------------------------------------------------------


class SetpointFeeder:
    """A thread that samples the active minimum-jerk segment at ``rate_hz`` and hands it to the link.

    :meth:`follow` queues a segment starting at a given time (the previous one keeps running until then);
    :meth:`clear` stops feeding — afterwards the link streams whatever target it was given last (a hold).
    """

    def __init__(self, link: MavlinkLink, rate_hz: float, timings: StageTimings) -> None:
        self._link = link
        self._period_s = 1.0 / rate_hz
        self._timings = timings
        self._lock = threading.Lock()
        self._segments: list[tuple[float, MinJerkSegment]] = []  # (start_s, segment), by start time
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="setpoint-feeder", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self.clear()
        self._stop.set()
        self._thread.join(timeout=1.0)

    def follow(self, segment: MinJerkSegment, start_s: float) -> None:
        with self._lock:
            self._segments = [s for s in self._segments if s[0] < start_s][-1:] + [(start_s, segment)]

    def clear(self) -> None:
        with self._lock:
            self._segments = []

    @property
    def end_s(self) -> float | None:
        """When the last queued segment ends; None when nothing is being fed."""
        with self._lock:
            return None if not self._segments else self._segments[-1][0] + self._segments[-1][1].duration_s

    def state_at(self, t_s: float) -> TrajectoryState | None:
        """The reference at ``t_s`` (held at a segment's end after it); None when nothing is being fed."""
        with self._lock:
            return self._state_at(t_s)

    def _state_at(self, t_s: float) -> TrajectoryState | None:
        active = [s for s in self._segments if s[0] <= t_s] or self._segments[:1]
        if not active:
            return None
        start_s, segment = active[-1]
        return segment.state_at(t_s - start_s)

    def _run(self) -> None:
        next_s = time.monotonic()
        while not self._stop.wait(max(0.0, next_s - time.monotonic())):
            next_s += self._period_s
            with self._lock:  # held while setting, so that after clear() no stale target is set
                state = self._state_at(time.monotonic())
                if state is None:
                    continue
                start = time.perf_counter()
                try:
                    x, y, z, yaw = (float(v) for v in state.position)
                    self._link.set_target(x, y, z, yaw)
                except Exception:  # noqa: BLE001 - the stream must outlive any single bad sample
                    log.exception("setpoint feeder error")
                self._timings.add("mavlink_io", time.perf_counter() - start)
            if next_s < time.monotonic() - self._period_s:  # fell behind: no burst
                next_s = time.monotonic() + self._period_s


# ---------------------------------------------------------------------------------------------------------------
# Frame checks
# ---------------------------------------------------------------------------------------------------------------


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


# ---------------------------------------------------------------------------------------------------------------
# The daemon
# ---------------------------------------------------------------------------------------------------------------


class Daemon:
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
        # Nearest Frontier, with this daemon's follower settings: the fallback, or the planner
        self.frontier = NearestFrontier(PlannerConfig(follow=config.follow), self.table)
        self.maps: VoxelMaps | None = None
        self._region = region
        self._feeder = SetpointFeeder(link, config.setpoint_rate_hz, self.timings)
        self._throttled = _ThrottledLog()
        self._stop_reason: str | None = None
        self._ending: str | None = None
        self._phase = "takeoff"  # takeoff → exploring → returning → home → done
        self._home_xy: tuple[float, float] | None = None
        self._home_since_s: float | None = None
        self._explore_start_s: float | None = None
        self._explore_end_s: float | None = None
        self._previous_action = int(Action.HOVER)
        self._policy_hovers = 0
        self._frontier_retries = 0
        self._policy_areas_m2: list[float] = []  # observed area at each policy decision (the watchdog's window)
        self._policy_handed_over = False
        self._hold_reason: str | None = None
        self._hold_since_s = 0.0
        self._holds: list[dict[str, Any]] = []
        self._link_lost_in_control = False  # the link was lost since the autopilot was last seen in OFFBOARD
        self._last_pose: Odometry | None = None
        self._jump_until_s = -math.inf
        self._last_frame_stamp_s: float | None = None
        self._last_fused_s = math.inf  # set at take-off: the first frame has depth_timeout_s to arrive
        self._frames_fused = 0
        self._frames_dropped: dict[str, int] = {}
        self._decisions = 0
        self._sources: dict[str, int] = {}
        self._metrics: MapMetrics | None = None
        self._path: list[tuple[float, float]] = []
        self._path_length_m = 0.0
        self._path_at_goal_m: float | None = None
        self._timeline: list[tuple[float, float | None, float | None, float]] = []
        self._source_cpu_s = 0.0
        self._candidate_s = 0.0
        self.view: DecisionView | None = None

    # -- public ------------------------------------------------------------------------------------------------

    @property
    def planner_name(self) -> str:
        return "drl" if self.policy is not None else "frontier"

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

    # -- the loop ----------------------------------------------------------------------------------------------

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

    def _check_inputs(self, now: float) -> str | None:
        """Why the daemon must hold position now (None when every input is healthy)."""
        cfg = self.config
        with self.timings.timed("mavlink_io"):
            status = self.link.status()
            pose = self.link.latest_pose()
        if not status.connected:
            self._link_lost_in_control = True
            return f"MAVLink link lost (no autopilot heartbeat for {self.link.config.link_lost_after_s:.1f} s)"
        if status.odometry_age_s is None or status.odometry_age_s > cfg.odometry_max_age_s or pose is None:
            return f"odometry stale (none for more than {cfg.odometry_max_age_s:.1f} s)"
        previous, self._last_pose = self._last_pose, pose
        if previous is not None:
            dt = max(pose.stamp_s - previous.stamp_s, 0.0)
            jump = math.dist((pose.x_m, pose.y_m, pose.z_m), (previous.x_m, previous.y_m, previous.z_m))
            if jump > cfg.pose_jump_m + self.table.model.speed_max_m_s * dt:
                self._jump_until_s = now + cfg.jump_settle_s
                log.warning(
                    "odometry jumped %.2f m in %.2f s: the maps are in the old frame, starting new ones; frames are "
                    "not fused for %.1f s",
                    jump,
                    dt,
                    cfg.jump_settle_s,
                )
                self._new_maps()
                self.frontier.reset()  # its goals are in the old frame too
                if self._home_xy is not None:
                    hx, hy = self._home_xy
                    self._home_xy = (hx + pose.x_m - previous.x_m, hy + pose.y_m - previous.y_m)
        if now < self._jump_until_s:
            return "settling after an odometry jump"
        return self._mode_problem(status)

    def _mode_problem(self, status: LinkStatus) -> str | None:
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
        self._stop_reason = f"pilot took over (autopilot left {wanted} for {status.mode or 'an unknown mode'})"
        return self._stop_reason

    # -- frames ------------------------------------------------------------------------------------------------

    def _ingest(self, frame: DepthFrame) -> None:
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
        assert pose is not None and self.maps is not None
        camera = CameraPose(pose.x_m, pose.y_m, pose.z_m, pose.yaw_rad, pose.pitch_rad, pose.roll_rad)
        start = time.perf_counter()
        try:
            self.maps.fuse(
                frame.depth_m, frame.intrinsics, camera.position_m, camera.rotation_map_from_optical(), frame.stamp_s
            )
        except FusionInputError as exc:
            self._drop(f"rejected by fusion ({exc})")
            return
        self.timings.add("fuse", time.perf_counter() - start)
        self._last_frame_stamp_s = frame.stamp_s
        self._last_fused_s = time.monotonic()
        self._frames_fused += 1
        self._mark_flown(pose)
        if self.recorder is not None:
            self.recorder.write(frame, pose)

    def _mark_flown(self, pose: Odometry) -> None:
        """Stamp the vehicle's footprint (see the module docstring) once it flies at band height."""
        radius_cells = int(self.config.footprint_clear_m / self._flown_grid.resolution_m)
        if radius_cells <= 0 or pose.z_m < self.config.band.min_z_m:
            return
        row, col = self._flown_grid.cell_of(pose.x_m, pose.y_m)
        cv2.circle(self._flown, (int(col), int(row)), radius_cells, 1, thickness=-1)

    def _drop(self, reason: str) -> None:
        self._frames_dropped[reason] = self._frames_dropped.get(reason, 0) + 1
        self._throttled.warn(reason, f"depth frame dropped: {reason}")

    # -- holding -----------------------------------------------------------------------------------------------

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

    # -- take-off and landing ------------------------------------------------------------------------------------

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

    # -- decisions -----------------------------------------------------------------------------------------------

    def _decision_due(self, now: float) -> bool:
        if self._phase == "home":
            if self._home_since_s is not None and now - self._home_since_s >= self.config.home_hover_s:
                self._phase = "done"
            return False
        end_s = self._feeder.end_s
        return end_s is None or now >= end_s - self.config.decision_lead_s

    def _step_start(self, now: float, odometry: Odometry) -> tuple[TrajectoryState, float]:
        """The state the next segment starts from, and when: the reference at the end of the current segment, or
        rest at the odometry pose when there is none or the vehicle is too far from it."""
        end_s = self._feeder.end_s
        if end_s is not None:
            reference = self._feeder.state_at(now)
            assert reference is not None
            off_m = math.hypot(reference.position[0] - odometry.x_m, reference.position[1] - odometry.y_m)
            if off_m <= self.config.reanchor_distance_m:
                start_s = max(end_s, now)
                state = self._feeder.state_at(start_s)
                assert state is not None
                return state, start_s
            log.warning("vehicle %.2f m off its reference: the next step starts where it is", off_m)
        self._previous_action = int(Action.HOVER)
        z = self.config.flight_height_m
        return TrajectoryState.at_rest(odometry.x_m, odometry.y_m, z, odometry.yaw_rad), now

    def _decide(self, frame_in_s: float, frame_in_cpu_s: float) -> None:
        assert self.maps is not None
        cfg, timed = self.config, self.timings.timed
        now = time.monotonic()
        with timed("mavlink_io"):
            odometry = self.link.latest_pose()
        assert odometry is not None
        start_state, start_s = self._step_start(now, odometry)
        pose = (float(start_state.position[0]), float(start_state.position[1]), float(start_state.position[3]))
        with timed("project"):
            high, high_grid = project(self.maps.high, cfg.band)
            high[(self._flown != 0) & (high == UNKNOWN)] = FREE
            low, low_grid = project(self.maps.low, cfg.band)
        maps = ObservedMaps(high_grid, low_grid, high, low)
        high_cell = _cell(high_grid, pose)
        low_cell = _cell(low_grid, pose)
        # The prediction feeds the policy's observation and the coverage count. When the frontier planner decides
        # (no policy, or the policy handed over) the waypoint does not depend on it, so it runs once the waypoint is
        # out (the coverage goal then ends exploration one decision later).
        predict_after = self.predictor is not None and self._frontier_decides
        thresholded = None
        if not predict_after:
            thresholded = self._predict(maps, low_cell)
            self._record_progress(now, odometry, maps, thresholded)
        if self._phase == "exploring":
            self._check_end_of_exploration(now)
        self._candidate_s = 0.0
        start = time.perf_counter()
        planner = WaypointPlanner(self.table, FreeSpace.from_codes(high, high_grid), cfg.follow.safe_distance_m)
        candidates = self._candidates(maps, pose, high_cell, low_cell, thresholded)
        waypoint = planner.first_safe((odometry.x_m, odometry.y_m), pose, self._previous_action, candidates)
        end = TrajectoryState(
            np.array([waypoint.x_m, waypoint.y_m, cfg.flight_height_m, waypoint.yaw_rad]),
            np.array([*waypoint.velocity[:2], 0.0, waypoint.velocity[2]]),
            np.zeros(4),
        )
        self._feeder.follow(min_jerk_segment(start_state, end, self.table.model.step_s), start_s)
        # The candidates' own stages (ego, policy, planner) ran inside this block and are timed on their own.
        self.timings.add("waypoint_trajectory", time.perf_counter() - start - self._candidate_s)
        self._previous_action = waypoint.action
        self._decisions += 1
        self._sources[waypoint.source] = self._sources.get(waypoint.source, 0) + 1
        self.timings.add("decision", time.monotonic() - frame_in_s)
        self.timings.add("decision_cpu", time.thread_time() - frame_in_cpu_s)
        if predict_after:
            thresholded = self._predict(maps, low_cell)
            self._record_progress(now, odometry, maps, thresholded)
        self.view = DecisionView(high, high_grid, low, low_grid, thresholded)
        log.debug(
            "decision %d: %s %s → (%.2f, %.2f)",
            self._decisions,
            waypoint.source,
            Action(waypoint.action).name,
            waypoint.x_m,
            waypoint.y_m,
        )

    def _predict(self, maps: ObservedMaps, low_cell: tuple[int, int]) -> np.ndarray | None:
        """Observed ∪ thresholded prediction on the low-res grid (DESIGN.md §5); None without a predictor."""
        if self.predictor is None:
            return None
        try:
            with self.timings.timed("predictor"):
                probabilities = self.predictor.predict(maps.low, low_cell)
        except Exception as exc:  # noqa: BLE001 - a model that fails in flight must not take the daemon down
            log.error(
                "the predictor failed (%s: %s): flying on without it, coverage counts observed cells",
                type(exc).__name__,
                exc,
            )
            self.predictor = None
            return None
        with self.timings.timed("thresholding"):
            return thresholded_map(probabilities, maps.low, maps.observed_area_m2(), self.config.thresholds)

    def _record_progress(
        self, now: float, odometry: Odometry, maps: ObservedMaps, thresholded: np.ndarray | None
    ) -> None:
        """Coverage against the plan (if known) and the path, once per decision."""
        xy = (odometry.x_m, odometry.y_m)
        if self._path and self._phase in ("exploring", "returning"):
            self._path_length_m += math.dist(self._path[-1], xy)
        self._path.append(xy)
        coverage = correct = None
        if self.truth is not None:
            with self.timings.timed("coverage"):
                self._metrics = self.truth.metrics(maps.low, maps.low_grid, thresholded)
            coverage, correct = self._metrics.coverage, self._metrics.correct_coverage
            if self._path_at_goal_m is None and coverage >= self.config.coverage_goal:
                self._path_at_goal_m = self._path_length_m
        self._timeline.append((now - self._t0_s, coverage, correct, self._path_length_m))

    def _check_end_of_exploration(self, now: float) -> None:
        assert self._explore_start_s is not None
        if self._metrics is not None and self._metrics.coverage >= self.config.coverage_goal:
            self._finish_exploring("coverage goal")
        elif now - self._explore_start_s >= self.config.time_limit_s:
            self._finish_exploring("time limit")

    @contextmanager
    def _candidate_stage(self, stage: str) -> Iterator[None]:
        """Time a stage that runs inside the waypoint stage (the lazy candidates), so the two do not overlap."""
        start = time.perf_counter()
        with self.timings.timed(stage):
            yield
        self._candidate_s += time.perf_counter() - start

    def _candidates(
        self,
        maps: ObservedMaps,
        pose: tuple[float, float, float],
        high_cell: tuple[int, int],
        low_cell: tuple[int, int],
        thresholded: np.ndarray | None,
    ) -> Iterator[tuple[str, int | None]]:
        """The actions to try, best first, computed lazily: a fallback only runs when the one before was unsafe.

        Exploring: the policy's action (unless it hovered more than ``policy_hover_limit`` times in a row), then
        the frontier planner's (which also ends exploration when nothing is left to explore and no policy runs).
        Returning: the next action along the way home. Then hover. Nothing once home: the vehicle holds.
        """
        previous = self._previous_action
        if self._phase == "exploring":
            if self.policy is not None and not self._policy_stalled(maps):
                with self._candidate_stage("ego"):
                    thres = thresholded if thresholded is not None else maps.low
                    observation = observation_from_maps(
                        maps.high,
                        thres,
                        maps.high_grid.resolution_m,
                        maps.low_grid.resolution_m,
                        high_cell,
                        low_cell,
                        pose[2],
                        previous,
                    )
                with self._candidate_stage("policy"):
                    action = self.policy.act(observation)
                self._policy_hovers = self._policy_hovers + 1 if action == Action.HOVER else 0
                if self._policy_hovers <= self.config.policy_hover_limit:
                    yield "policy", action
            with self._candidate_stage("planner"):
                action = self.frontier.act(maps, pose, previous)
                if action is None and self._frontier_decides and self._retry_frontiers(maps):
                    action = self.frontier.act(maps, pose, previous)
            if action is None and self._frontier_decides:
                self._finish_exploring("explored")
            else:
                yield "frontier", action
        if self._phase == "returning":
            with self._candidate_stage("planner"):
                action = self._home_action(maps, pose)
            yield "home", action
        if self._phase in ("exploring", "returning"):
            yield "hover", int(Action.HOVER)

    @property
    def _frontier_decides(self) -> bool:
        """Whether the frontier planner is the one exploring (no policy, or the policy handed over)."""
        return self.policy is None or self._policy_handed_over

    def _policy_stalled(self, maps: ObservedMaps) -> bool:
        """The policy's progress watchdog (see :class:`DaemonConfig`): True once the policy has handed over."""
        cfg = self.config
        if self._policy_handed_over or cfg.policy_window == 0:
            return self._policy_handed_over
        self._policy_areas_m2.append(maps.observed_area_m2())
        if len(self._policy_areas_m2) > cfg.policy_window:
            gain_m2 = self._policy_areas_m2[-1] - self._policy_areas_m2.pop(0)
            if gain_m2 < cfg.policy_min_gain_m2:
                self._policy_handed_over = True
                log.warning(
                    "the policy observed %.1f m² in its last %d decisions: the frontier planner explores from here",
                    gain_m2,
                    cfg.policy_window,
                )
        return self._policy_handed_over

    def _retry_frontiers(self, maps: ObservedMaps) -> bool:
        """Whether to give the frontier planner's dropped targets another chance (and reset it) when it has nothing
        left while frontier cells remain: a target dropped early — unseen from where the vehicle stalled, or cut off
        by a phantom obstacle since cleared — may be reachable in the map as it is now."""
        remaining = int(np.count_nonzero(frontier_mask(maps.low)))
        if remaining == 0 or self._frontier_retries >= self.config.frontier_retries:
            return False
        self._frontier_retries += 1
        log.info(
            "no reachable frontier left but %d frontier cells remain: retrying the targets given up on (%d/%d)",
            remaining,
            self._frontier_retries,
            self.config.frontier_retries,
        )
        self.frontier.reset()
        return True

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

    # -- reporting -------------------------------------------------------------------------------------------------

    def _progress(self, now: float) -> Progress:
        decision = self.timings.stats().get("decision")
        m = self._metrics
        return Progress(
            elapsed_s=now - self._t0_s,
            phase=self._phase,
            coverage=None if m is None else m.coverage,
            correct_coverage=None if m is None else m.correct_coverage,
            path_length_m=self._path_length_m,
            decisions=self._decisions,
            decision_p95_ms=None if decision is None else decision.p95_ms,
            holding=self._hold_reason,
        )

    def _report(self, wall_s: float, cpu_s: float) -> RunReport:
        m = self._metrics
        exploration_s = None
        if self._explore_start_s is not None:
            exploration_s = (self._explore_end_s or time.monotonic()) - self._explore_start_s
        return RunReport(
            ending=self._ending or "not started",
            planner=self.planner_name,
            predictor=self.predictor is not None,
            coverage=None if m is None else m.coverage,
            correct_coverage=None if m is None else m.correct_coverage,
            f1=None if m is None else m.f1,
            path_length_m=self._path_length_m,
            path_at_goal_m=self._path_at_goal_m,
            exploration_s=exploration_s,
            returned_home=self._phase in ("home", "done") and self.config.return_home,
            decisions=self._decisions,
            waypoint_sources=dict(self._sources),
            frames_fused=self._frames_fused,
            frames_dropped=dict(self._frames_dropped),
            holds=list(self._holds),
            wall_s=wall_s,
            process_cpu_s=cpu_s,
            source_cpu_s=self._source_cpu_s,
            stages=self.timings.stats(),
            timeline=list(self._timeline),
            path_xy_m=list(self._path),
        )


def _cell(grid: GridSpec, pose: tuple[float, float, float]) -> tuple[int, int]:
    row, col = grid.cell_of(pose[0], pose[1])
    return int(row), int(col)


def band_z_range_m(band: HeightBand) -> tuple[float, float]:
    """The height the voxel maps cover: the projected band and one 0.20 m layer either side, on the 0.20 m layer
    boundaries of the band (so both resolutions project exactly the band's layers).

    Nothing outside the band is projected, and rays are clipped to the maps' box, so floor and ceiling returns still
    carve the free space they cross inside it; a box 1.4 m tall instead of floor-to-ceiling cuts the voxel memory
    (0.05 m: 2 bytes of log-odds and 2 of update stamp per voxel) and the ray traversal by more than half.
    """
    layers = math.ceil((band.max_z_m - band.min_z_m) / LOW_RES_M - 1e-9)
    return band.min_z_m - LOW_RES_M, band.min_z_m + (layers + 1) * LOW_RES_M


class ModelSetupError(EdgeExplorerError):
    """The models the user asked for cannot be used."""


@dataclass(frozen=True)
class ModelChoice:
    """The models a run uses, and the log lines that say why."""

    policy: PolicyRuntime | None
    predictor: PredictorRuntime | None
    notes: tuple[str, ...]


def _flight_ready(card: Path) -> tuple[bool, str]:
    """(ready, why) from a policy card's ``flight_ready`` record; a card without one is not ready."""
    try:
        record = json.loads(card.read_text()).get("flight_ready")
    except (OSError, ValueError, AttributeError) as exc:
        return False, f"{card} is unreadable ({exc})"
    if not isinstance(record, dict) or not isinstance(record.get("ready"), bool):
        return False, f"{card} records no flight_ready evaluation"
    return record["ready"], str(record.get("why", ""))


def choose_models(
    models_dir: Path,
    planner: str,
    backend_order: tuple[str, ...],
    precision: str = "int8",
    num_threads: int = 1,
    model_orders: Mapping[str, tuple[str, ...]] | None = None,
) -> ModelChoice:
    """Load the shipped models the run can use (see DESIGN.md §8 and the module docstring).

    ``planner``: ``drl`` needs ``models_dir/policy/card.json`` and fails with :class:`ModelSetupError` (one line)
    when it is missing or cannot be loaded; ``auto`` uses the policy only when its card says it is flight-ready
    (``flight_ready.ready``: the building evaluation of these weights passed, see
    :func:`edge_explorer.learn.policy_card.flight_ready`) and it loads, and the frontier planner otherwise, saying
    why; ``frontier`` never loads the policy. The predictor (``models_dir/predictor/card.json``)
    is used when it loads; otherwise the run goes on without it (coverage = observed) and says why.
    ``model_orders`` (the device profile's per-model orders) replaces ``backend_order`` for the models it names.
    """

    def load(name: str, wrapper: type) -> tuple[object | None, str]:
        """(the wrapped model, its backend report) or (None, why not)."""
        card = models_dir / name / CARD_FILE
        if not card.is_file():
            return None, f"no {name} model: {card} is missing"
        try:
            order = (model_orders or {}).get(name, backend_order)
            model = wrapper(load_model(card, order, precision, num_threads))
        except EdgeExplorerError as exc:
            return None, str(exc)
        return model, model.model.report

    notes: list[str] = []
    policy = None
    policy_card = models_dir / "policy" / CARD_FILE
    if planner == "frontier":
        notes.append("planner: frontier (asked for)")
    elif planner == "auto" and policy_card.is_file() and not (ready := _flight_ready(policy_card))[0]:
        notes.append(f"planner: frontier (the DRL policy is not flight-ready: {ready[1]}; --planner drl flies it)")
    else:
        policy, said = load("policy", PolicyRuntime)
        if policy is None and planner == "drl":
            raise ModelSetupError(f"--planner drl: {said}")
        notes.append(f"planner: drl ({said})" if policy else f"planner: frontier (no usable DRL policy: {said})")
    predictor, said = load("predictor", PredictorRuntime)
    notes.append(f"predictor: {said}" if predictor else f"predictor: none, coverage counts observed cells ({said})")
    return ModelChoice(policy, predictor, tuple(notes))
