"""The on-device exploration daemon: depth frames + MAVLink odometry in, position setpoints out (docs/design.md §8).

One process, one loop (:class:`Daemon`), no torch. Around the loop the parts it wires together:

* **Per depth frame** (default 15 Hz): check the frame (NaN/inf, no returns, wrong shape, a timestamp not after the
  last one: dropped, with a rate-limited log line and a count per reason), take the pose at the frame's timestamp
  from the link's odometry buffer (a replayed frame brings its own), fuse it into the 0.05 m and 0.20 m voxel maps.
  :meth:`~edge_explorer.mapping.voxels.VoxelMaps.fuse` validates before it writes, so a rejected frame never
  corrupts the maps. The maps are never sized from a plan: they start around the take-off point and grow as the
  vehicle observes (:mod:`edge_explorer.mapping.growing`: a growing 0.20 m map, a 0.05 m window that follows the
  vehicle over a growing 2-D 0.05 m map).
* **Per decision** (one per step period, 1 s by default, the period of the shared action table: a decision is due
  when the vehicle's reference reaches the previous waypoint, and is taken on the last frame before that, so the
  new segment starts without a pause): project both maps, run the predictor and threshold its output (when a
  predictor is loaded), measure coverage against the plan (when one is known), ask the goal planner for the next
  action — the learned goal policy's planner (:class:`~edge_explorer.plan.goal_policy.GoalPolicyPlanner`: the
  policy observation in, a goal cell out, the goal flown along observed free space) when a policy is loaded, else
  ``exploration_planner`` — turn the action into a waypoint through the action table, check it on the observed
  high-res map (:mod:`edge_explorer.plan.waypoint`: the planner's choice, else hover, else hold) and plan a
  minimum-jerk segment to it (:func:`~edge_explorer.plan.trajectory.min_jerk_segment`). With Nearest Frontier the
  waypoint does not depend on the prediction (it decides on the observed map, as in the benchmark's ``+pred``
  methods), so the predictor then runs right after the waypoint is out, off the frame-in → waypoint-out path.
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

**A learned goal policy that fails** (its model raises or answers non-finite scores) hands over to the configured
frontier planner for the rest of the flight, said in the log. Its goals are flown by the same goal-planner loop as
every planner's, through observed free space, so it cannot choose a collision.

**The end.** Exploration ends at ``coverage_goal`` (predicted coverage with a predictor, observed without) when a
plan of the building is known; without one, by the map stop rule — when the maps' own unverified area (unknown space
the vehicle could still reach or see, plus the expected wrong area among the predicted cells:
:mod:`edge_explorer.predict.verification`) falls below ``stop_threshold_m2``, ending "map says verified"; when what
is left of the flight budget ``time_limit_s`` is the reserve to fly home (``FlightPhases.home_reserve_s``); or when
the frontier planner has nothing left (after giving the targets it dropped ``frontier_retries`` more chances while
frontier cells remain); the daemon then flies home (the take-off point, along a path over observed free space, with
the same six actions) and hovers there for ``home_hover_s``. :meth:`Daemon.request_stop` (SIGINT/SIGTERM) ends the
loop at once with a hold.

Every stage is timed (:class:`StageTimings`, reused by the profiling report) and the run is summed up in a
:class:`RunReport`.

How it is built (read :mod:`.loop` first). :class:`Daemon` composes plain parts, each built from explicit inputs
and owning its own state, each testable alone; what two of them share is a small explicit object, not an attribute
of the daemon:

* :class:`~.state.FlightState` (:mod:`.state`) — where the flight stands: phase, home, stop reason, ending;
  :class:`~.state.FlightMaps` — the voxel maps and the flown footprint;
* :class:`~.watchdog.InputWatchdog` (:mod:`.watchdog`; config, link, the vehicle's top speed, timings, maps, state,
  record, recorder) — the input checks (stale odometry, pose jumps, link loss, autopilot mode, no depth) and frame
  ingestion; it reports a pose jump and the daemon starts maps, goal planner and home afresh;
* :class:`~.phases.FlightPhases` (:mod:`.phases`; config, link, action table, setpoint feeder, state, maps,
  record) — take-off, climb, explore, hold, re-engage, the way home;
* :class:`~.decisions.DecisionPipeline` (:mod:`.decisions`; config, link, action table, timings, setpoint feeder,
  maps, phases, record, policy, predictor) — project → predict → threshold → plan → waypoint → trajectory; it owns
  the goal planner (built through :func:`~edge_explorer.plan.registry.build_planner`) and drops a failing model;
* :class:`~.record.RunRecord` (:mod:`.record`; coverage goal, timings, truth) — the counts, holds, path and
  coverage timeline, the progress line and the :class:`RunReport` (its types: :mod:`.report`);
* :class:`SetpointFeeder` (:mod:`.setpoints`) — the setpoint stream;
* :mod:`.config` — :class:`DaemonConfig`; :mod:`.models` — which shipped models a run flies.

What the parts need from one another beyond that (the latest odometry pose, the coverage, the previous action, the
planner's name, whether the link was lost in control) the daemon's loop passes as method arguments.
"""

from edge_explorer.runtime.daemon.config import AUTOPILOT_MODES, STALL_BLAME_S, DaemonConfig, band_z_range_m
from edge_explorer.runtime.daemon.decisions import DecisionPipeline
from edge_explorer.runtime.daemon.loop import Daemon
from edge_explorer.runtime.daemon.models import ModelChoice, ModelSetupError, choose_models
from edge_explorer.runtime.daemon.phases import FlightPhases
from edge_explorer.runtime.daemon.record import RunRecord
from edge_explorer.runtime.daemon.report import (
    STAGES,
    CoverageTruth,
    DecisionView,
    Progress,
    RunReport,
    StageStats,
    StageTimings,
)
from edge_explorer.runtime.daemon.setpoints import SetpointFeeder
from edge_explorer.runtime.daemon.state import FlightMaps, FlightState
from edge_explorer.runtime.daemon.watchdog import InputCheck, InputWatchdog, frame_problem

__all__ = [
    "AUTOPILOT_MODES",
    "STAGES",
    "STALL_BLAME_S",
    "CoverageTruth",
    "Daemon",
    "DaemonConfig",
    "DecisionPipeline",
    "DecisionView",
    "FlightMaps",
    "FlightPhases",
    "FlightState",
    "InputCheck",
    "InputWatchdog",
    "ModelChoice",
    "ModelSetupError",
    "Progress",
    "RunRecord",
    "RunReport",
    "SetpointFeeder",
    "StageStats",
    "StageTimings",
    "band_z_range_m",
    "choose_models",
    "frame_problem",
]
