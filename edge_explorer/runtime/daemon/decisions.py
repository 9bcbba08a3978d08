"""The decision pipeline: one waypoint per step, project → predict → threshold → plan → waypoint → trajectory.

A decision is due when the vehicle's reference reaches the previous waypoint, and is taken on the last frame before
that, so the new segment starts without a pause. It projects both voxel maps (the flown footprint counted free),
runs the predictor and thresholds its output (when one is loaded), records coverage, then tries the candidate
actions best first, lazily (:meth:`DecisionPipeline._candidates`): the learned planner's
(:meth:`DecisionPipeline._policy_action`, the seam where a learned planner plugs in), the Nearest Frontier
planner's, the way home's, hover — the first one the safety check on the observed high-res map accepts
(:class:`~edge_explorer.plan.waypoint.WaypointPlanner`) becomes the waypoint, and a minimum-jerk segment to it goes
to the setpoint stream. Without a policy the waypoint does not depend on the prediction, so the predictor then runs
right after the waypoint is out, off the frame-in → waypoint-out path.

**Where a step starts.** The autopilot tracks a moving position setpoint with a lag, so a step starts from the
*reference* (the end of the previous segment), not from the lagging odometry; the safety check uses the odometry
position. When the vehicle is more than ``reanchor_distance_m`` off its reference, the next step starts at rest at
the odometry pose.

**A policy that makes no progress** (the observed area grew by less than ``policy_min_gain_m2`` over its last
``policy_window`` decisions) hands over to the frontier planner for the rest of the flight. When the frontier
planner has nothing left while frontier cells remain, its dropped targets get ``frontier_retries`` more chances."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from edge_explorer.mapping.ego import observation_from_maps
from edge_explorer.mapping.observed import ObservedMaps
from edge_explorer.mapping.projection import project
from edge_explorer.plan.follow import FreeSpace
from edge_explorer.plan.frontier import frontier_mask
from edge_explorer.plan.trajectory import TrajectoryState, min_jerk_segment
from edge_explorer.plan.waypoint import WaypointPlanner
from edge_explorer.predict.thresholding import thresholded_map
from edge_explorer.runtime.daemon.report import DecisionView
from edge_explorer.runtime.mavlink_link import Pose as Odometry
from edge_explorer.sim.dynamics import Action
from edge_explorer.world.grid import FREE, UNKNOWN, GridSpec

log = logging.getLogger(__name__)


class DecisionPipeline:
    """The daemon's decisions (see the module docstring). Owns the previous action and the policy's hover count,
    progress window and hand-over, the frontier retries; reads the daemon's maps, flown footprint, models,
    ``frontier`` planner, ``table``, ``_feeder`` and phase."""

    def _init_decisions(self) -> None:
        self._previous_action = int(Action.HOVER)
        self._policy_hovers = 0
        self._frontier_retries = 0
        self._policy_areas_m2: list[float] = []  # observed area at each policy decision (the watchdog's window)
        self._policy_handed_over = False
        self._candidate_s = 0.0

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
        predict_after = (
            self.predictor is not None and self._frontier_decides and self.config.exploration_planner == "frontier"
        )
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
                action = self._policy_action(maps, pose, high_cell, low_cell, thresholded, previous)
                self._policy_hovers = self._policy_hovers + 1 if action == Action.HOVER else 0
                if self._policy_hovers <= self.config.policy_hover_limit:
                    yield "policy", action
            with self._candidate_stage("planner"):
                action = self.frontier.act(maps, pose, previous, thresholded)
                if action is None and self._frontier_decides and self._retry_frontiers(maps):
                    action = self.frontier.act(maps, pose, previous, thresholded)
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

    def _policy_action(
        self,
        maps: ObservedMaps,
        pose: tuple[float, float, float],
        high_cell: tuple[int, int],
        low_cell: tuple[int, int],
        thresholded: np.ndarray | None,
        previous: int,
    ) -> int:
        """The learned planner's action for this step: the policy observation built from the maps (DESIGN.md §5,
        stage "ego") and the policy's choice (stage "policy"). The one place the learned planner is called: another
        learned planner plugs in here, behind the same arguments."""
        assert self.policy is not None
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
        return action

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


def _cell(grid: GridSpec, pose: tuple[float, float, float]) -> tuple[int, int]:
    row, col = grid.cell_of(pose[0], pose[1])
    return int(row), int(col)
