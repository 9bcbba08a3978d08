"""The decision pipeline: one waypoint per step, project → predict → threshold → plan → waypoint → trajectory.

A decision is due when the vehicle's reference reaches the previous waypoint, and is taken on the last frame before
that, so the new segment starts without a pause. It projects both voxel maps (the flown footprint counted free),
runs the predictor and thresholds its output (when one is loaded), records coverage, then tries the candidate
actions best first, lazily (:meth:`DecisionPipeline._candidates`): the goal planner's — the learned goal policy's
(:class:`~edge_explorer.plan.goal_policy.GoalPolicyPlanner`) when one is loaded, else the configured frontier
planner's, the very objects the benchmark flies — the way home's, hover — the first one the safety check on the
observed high-res map accepts (:class:`~edge_explorer.plan.waypoint.WaypointPlanner`) becomes the waypoint, and a
minimum-jerk segment to it goes to the setpoint stream.

**The predictor runs off the frame-in → waypoint-out path.** It runs right after each waypoint is out, on that
decision's maps; the next decision thresholds that prediction against its own, newer observed maps (0.4 ms) and
plans on the result. The planner therefore sees a prediction made one decision (~0.5 m of flight, a few frames)
earlier, while every observed cell in its fused map is current: the predictor's ~8 ms (int8, LiteRT) leave each
decision's latency. A decision predicts first itself when there is no prediction yet or the maps' grid has changed
since (they grow, :mod:`edge_explorer.mapping.growing`). With Nearest Frontier the waypoint does not depend on the
prediction at all. The return's periodic plan of its path home over the whole map (~0.1–0.2 s on a 271 m floor)
runs after the waypoint too (:meth:`~.phases.FlightPhases.replan_home`).

**Where a step starts.** The autopilot tracks a moving position setpoint with a lag, so a step starts from the
*reference* (the end of the previous segment), not from the lagging odometry; the safety check uses the odometry
position. When the vehicle is more than ``reanchor_distance_m`` off its reference, the next step starts at rest at
the odometry pose.

**A policy that fails** (its model raises, or answers non-finite scores) hands over to the configured frontier
planner for the rest of the flight, said in the log. When the planner has nothing left while frontier cells
remain, its dropped targets get ``frontier_retries`` more chances.

The pipeline owns the goal planner, the models and the previous action; it reads the shared
:class:`~.state.FlightMaps`, asks the :class:`~.phases.FlightPhases` for the phase, the end of exploration and the
way home, queues its segments on the setpoint stream and tells the :class:`~.record.RunRecord` about every decision
and its coverage."""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Iterator
from concurrent.futures import Future
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from edge_explorer.mapping.observed import ObservedMaps
from edge_explorer.plan.follow import FreeSpace
from edge_explorer.plan.frontier import GoalPlanner, frontier_mask
from edge_explorer.plan.policy import PolicyRuntime
from edge_explorer.plan.registry import build_planner
from edge_explorer.plan.trajectory import TrajectoryState, min_jerk_segment
from edge_explorer.plan.waypoint import WaypointPlanner
from edge_explorer.plan.window import crop_maps, place_window
from edge_explorer.predict.predictor import PredictorRuntime
from edge_explorer.predict.thresholding import thresholded_map
from edge_explorer.runtime.daemon.config import DaemonConfig
from edge_explorer.runtime.daemon.phases import FlightPhases
from edge_explorer.runtime.daemon.record import RunRecord
from edge_explorer.runtime.daemon.report import DecisionView, StageTimings
from edge_explorer.runtime.daemon.setpoints import SetpointFeeder
from edge_explorer.runtime.daemon.state import FlightMaps
from edge_explorer.runtime.mavlink_link import MavlinkLink
from edge_explorer.runtime.mavlink_link import Pose as Odometry
from edge_explorer.vehicle.dynamics import Action, ActionTable
from edge_explorer.world.grid import GridSpec

log = logging.getLogger(__name__)
# The safety check's map: a square of this side around the vehicle. A step and its braking drift end within ~1.5 m of
# it, and the check reads only cells within ``safe_distance_m`` of that motion and clearances below it, so it answers
# on this crop exactly as on the whole map, at a cost that does not grow with the maps (they grow with the flight).
_SAFETY_WINDOW_M = 8.0


@dataclass(frozen=True)
class TimedScores:
    """The goal policy's scores for one decision of the goal planner, timed as stage "policy" (inside the stage
    "planner" that asks for them). A plain object rather than a bound method of the daemon: the planner holding it
    then holds no reference back to the daemon, a cycle that kept each finished flight's maps and planners (+31 MB
    a flight) alive until the cyclic collector's next full pass when flights ran back to back (the soak).

    It is a :class:`~edge_explorer.plan.goal_policy.ConcurrentGoalPolicy`: :meth:`submit` scores on the policy's
    own thread (LiteRT runs off the interpreter's lock) while the planner searches its goal options, which takes
    the policy's ~5 ms off a goal decision's latency."""

    policy: PolicyRuntime
    timings: StageTimings

    def __call__(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        with self.timings.timed("policy"):
            return self.policy.scores(observation)

    def submit(self, observation: dict[str, np.ndarray]) -> Future[np.ndarray]:
        """Score ``observation`` on a daemon thread of its own (~0.1 ms to start; a daemon thread never holds up
        the program's exit, which joins every other thread: an idle pool's worker would wait there for ever)."""
        future: Future[np.ndarray] = Future()
        threading.Thread(target=_run, args=(future, self, observation), name="goal-policy", daemon=True).start()
        return future


def _run(future: Future[np.ndarray], scores: TimedScores, observation: dict[str, np.ndarray]) -> None:
    try:
        future.set_result(scores(observation))
    except BaseException as exc:  # noqa: BLE001 - handed to the planner, which raises it where it waits
        future.set_exception(exc)


def make_planner(
    config: DaemonConfig, table: ActionTable, policy: PolicyRuntime | None, timings: StageTimings
) -> GoalPlanner:
    """The goal planner that explores, from the planner registry with the daemon's follower settings: the learned
    goal policy's (``drl``) when ``policy`` is loaded, else ``config.exploration_planner`` (also the one a failing
    policy hands over to)."""
    scores = TimedScores(policy, timings) if policy is not None else None
    name = "drl" if policy is not None else config.exploration_planner
    return build_planner(name, table, scores, follow=config.follow)


class DecisionPipeline:
    """The daemon's decisions (see the module docstring).

    Inputs: ``config``; ``link`` (the latest odometry); ``table``, the action table; ``timings``; ``feeder``, the
    setpoint stream the segments go to (and whose reference a step starts from); ``maps``, projected at each
    decision; ``phases``, the flight's phases; ``record``, told about decisions and coverage; ``policy`` and
    ``predictor``, the models (either may be dropped in flight when it fails). Owns the goal planner
    (:attr:`planner`), the previous action, the frontier retries and the latest decision's maps (:attr:`view`)."""

    def __init__(
        self,
        config: DaemonConfig,
        link: MavlinkLink,
        table: ActionTable,
        timings: StageTimings,
        feeder: SetpointFeeder,
        maps: FlightMaps,
        phases: FlightPhases,
        record: RunRecord,
        policy: PolicyRuntime | None = None,
        predictor: PredictorRuntime | None = None,
    ) -> None:
        self.config = config
        self.link = link
        self.table = table
        self.timings = timings
        self.feeder = feeder
        self.maps = maps
        self.phases = phases
        self.record = record
        self.policy = policy
        self.predictor = predictor
        self.planner = make_planner(config, table, policy, timings)
        self.view: DecisionView | None = None
        self.probabilities: np.ndarray | None = None  # the latest prediction on the low-res grid
        self._predicted_on: GridSpec | None = None  # the low-res grid of :attr:`probabilities`
        self._previous_action = int(Action.HOVER)
        self._frontier_retries = 0
        self._candidate_s = 0.0

    @property
    def planner_name(self) -> str:
        return "drl" if self.policy is not None else self.config.exploration_planner

    @property
    def previous_action(self) -> int:
        return self._previous_action

    def restart_at_rest(self) -> None:
        """The next step starts at rest where the vehicle is (after a hold)."""
        self._previous_action = int(Action.HOVER)

    def _step_start(self, now: float, odometry: Odometry) -> tuple[TrajectoryState, float]:
        """The state the next segment starts from, and when: the reference at the end of the current segment, or
        rest at the odometry pose when there is none or the vehicle is too far from it."""
        end_s = self.feeder.end_s
        if end_s is not None:
            reference = self.feeder.state_at(now)
            assert reference is not None
            off_m = math.hypot(reference.position[0] - odometry.x_m, reference.position[1] - odometry.y_m)
            if off_m <= self.config.reanchor_distance_m:
                start_s = max(end_s, now)
                state = self.feeder.state_at(start_s)
                assert state is not None
                return state, start_s
            log.warning("vehicle %.2f m off its reference: the next step starts where it is", off_m)
        self._previous_action = int(Action.HOVER)
        z = self.config.flight_height_m
        return TrajectoryState.at_rest(odometry.x_m, odometry.y_m, z, odometry.yaw_rad), now

    def decide(self, frame_in_s: float, frame_in_cpu_s: float) -> None:
        """One decision, the frame that triggered it in at ``frame_in_s`` (``frame_in_cpu_s`` of thread CPU time):
        the next waypoint's segment queued on the setpoint stream."""
        cfg, timed = self.config, self.timings.timed
        now = time.monotonic()
        with timed("mavlink_io"):
            odometry = self.link.latest_pose()
        assert odometry is not None
        start_state, start_s = self._step_start(now, odometry)
        pose = (float(start_state.position[0]), float(start_state.position[1]), float(start_state.position[3]))
        with timed("project"):
            high, high_grid, low, low_grid = self.maps.project(cfg.band)
        maps = ObservedMaps(high_grid, low_grid, high, low)
        low_cell = _cell(low_grid, pose)
        # The prediction feeds the goal planner's fused map and the coverage count; it runs once the waypoint is out
        # (module docstring), and this decision plans on the latest one. When Nearest Frontier decides (no policy,
        # or the policy handed over) the waypoint does not depend on it. The progress record (coverage against a
        # plan, the maps' unverified area: ~5 ms on a 271 m floor) never shapes the waypoint, so it runs then too:
        # the coverage goal or the map stop rule ends exploration one decision after the one whose maps reached it.
        frontier_decides = self.policy is None and self.config.exploration_planner == "frontier"
        thresholded = None if frontier_decides else self.latest_prediction(maps, low_cell)
        phase = self.phases.phase  # the phase the vehicle flew this step's path in, for the record
        if phase == "exploring":
            self.phases.check_end_of_exploration(
                now, self.record.coverage, self.record.unverified_m2, (odometry.x_m, odometry.y_m)
            )
        self._candidate_s = 0.0
        start = time.perf_counter()
        near = crop_maps(maps, place_window(low_grid, (odometry.x_m, odometry.y_m), _SAFETY_WINDOW_M))
        planner = WaypointPlanner(
            self.table, FreeSpace.from_codes(near.high, near.high_grid), cfg.follow.safe_distance_m
        )
        candidates = self._candidates(maps, pose, thresholded)
        waypoint = planner.first_safe((odometry.x_m, odometry.y_m), pose, self._previous_action, candidates)
        end = TrajectoryState(
            np.array([waypoint.x_m, waypoint.y_m, cfg.flight_height_m, waypoint.yaw_rad]),
            np.array([*waypoint.velocity[:2], 0.0, waypoint.velocity[2]]),
            np.zeros(4),
        )
        self.feeder.follow(min_jerk_segment(start_state, end, self.table.model.step_s), start_s)
        # The candidates' own stage (planner, the policy inside it) ran inside this block and is timed on its own.
        self.timings.add("waypoint_trajectory", time.perf_counter() - start - self._candidate_s)
        self._previous_action = waypoint.action
        self.record.decision(waypoint.source)
        self.timings.add("decision", time.monotonic() - frame_in_s)
        self.timings.add("decision_cpu", time.thread_time() - frame_in_cpu_s)
        thresholded = self.predict(maps, low_cell)  # on this decision's maps: the record's, and the next decision's
        self.record.record_progress(now, odometry, maps, thresholded, phase, self.probabilities)
        if self.phases.phase == "exploring":  # the reserve's way home, off the frame-in → waypoint-out path
            self.phases.measure_way_home(maps, (odometry.x_m, odometry.y_m), now)
        else:  # the return's periodic replan, off that path too
            self.phases.replan_home(maps, pose, now)
        self.view = DecisionView(high, high_grid, low, low_grid, thresholded)
        log.debug(
            "decision %d: %s %s → (%.2f, %.2f)",
            self.record.decisions,
            waypoint.source,
            Action(waypoint.action).name,
            waypoint.x_m,
            waypoint.y_m,
        )

    def latest_prediction(self, maps: ObservedMaps, low_cell: tuple[int, int]) -> np.ndarray | None:
        """Observed ∪ the latest prediction, thresholded against ``maps`` (docs/design.md §5); a new prediction when
        there is none on ``maps``' grid (the first decision, or the maps grew since). None without a predictor."""
        if self.predictor is None:
            return None
        if self.probabilities is None or self._predicted_on != maps.low_grid:
            return self.predict(maps, low_cell)
        with self.timings.timed("thresholding"):
            return thresholded_map(self.probabilities, maps.low, maps.observed_area_m2(), self.config.thresholds)

    def predict(self, maps: ObservedMaps, low_cell: tuple[int, int]) -> np.ndarray | None:
        """Observed ∪ thresholded prediction on the low-res grid (docs/design.md §5); None without a predictor. The
        probabilities stay in :attr:`probabilities` (for the map stop rule's expected wrong area)."""
        self.probabilities = None
        if self.predictor is None:
            return None
        model = self.predictor.for_map(maps.low)
        if model is not self.predictor:
            # A flight's observed extent only grows: the whole-floor model predicts for the rest of it, and the shipped
            # one's interpreter is released (about 12 MB of a 300 MB budget). Thresholding keeps the config's
            # thresholds, whose ``beyond`` are this model's.
            log.info("the observed cells span more than the predictor's envelope: the whole-floor predictor takes over")
            self.predictor = model
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
        self.probabilities, self._predicted_on = probabilities, maps.low_grid
        with self.timings.timed("thresholding"):
            return thresholded_map(probabilities, maps.low, maps.observed_area_m2(), self.config.thresholds)

    @contextmanager
    def _candidate_stage(self, stage: str) -> Iterator[None]:
        """Time a stage that runs inside the waypoint stage (the lazy candidates), so the two do not overlap."""
        start = time.perf_counter()
        with self.timings.timed(stage):
            yield
        self._candidate_s += time.perf_counter() - start

    def _candidates(
        self, maps: ObservedMaps, pose: tuple[float, float, float], thresholded: np.ndarray | None
    ) -> Iterator[tuple[str, int | None]]:
        """The actions to try, best first, computed lazily: a fallback only runs when the one before was unsafe.

        Exploring: the goal planner's action (which also ends exploration when nothing is left to explore).
        Returning: the next action along the way home. Then hover. Nothing once home: the vehicle holds.
        """
        previous = self._previous_action
        if self.phases.phase == "exploring":
            with self._candidate_stage("planner"):
                action = self.planner_action(maps, pose, previous, thresholded)
                if action is None and self.retry_frontiers(maps):
                    action = self.planner_action(maps, pose, previous, thresholded)
            if action is None:
                self.phases.finish_exploring("explored")
            else:
                yield "policy" if self.policy is not None else "frontier", action
        if self.phases.phase == "returning":
            with self._candidate_stage("planner"):
                action = self.phases.home_action(maps, pose, previous)
            yield "home", action
        if self.phases.phase in ("exploring", "returning"):
            yield "hover", int(Action.HOVER)

    def planner_action(
        self, maps: ObservedMaps, pose: tuple[float, float, float], previous: int, thresholded: np.ndarray | None
    ) -> int | None:
        """The exploring goal planner's action; a learned policy that fails hands over to the configured frontier
        planner here, for the rest of the flight (a model that fails in flight must not take the daemon down)."""
        try:
            return self.planner.act(maps, pose, previous, thresholded)
        except Exception as exc:  # noqa: BLE001 - see the docstring
            if self.policy is None:
                raise
            log.error(
                "the goal policy failed (%s: %s): the %s planner explores from here",
                type(exc).__name__,
                exc,
                self.config.exploration_planner,
            )
            self.policy = None
            self.planner = make_planner(self.config, self.table, None, self.timings)
            return self.planner.act(maps, pose, previous, thresholded)

    def retry_frontiers(self, maps: ObservedMaps) -> bool:
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
        self.planner.reset()
        return True


def _cell(grid: GridSpec, pose: tuple[float, float, float]) -> tuple[int, int]:
    row, col = grid.cell_of(pose[0], pose[1])
    return int(row), int(col)
