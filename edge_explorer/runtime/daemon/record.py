"""The run record (:class:`RunRecord`): the figures of one flight as its parts report them — decisions and their
waypoint sources, frames fused and dropped, holds, the path and the coverage timeline — and the progress line and
the run report built from them.

It knows no other part: the watchdog tells it about frames, the phases about holds, the decision pipeline about
decisions and coverage; what it cannot know (the phase, the hold, the planner, the ending) the daemon passes in when
it asks for a progress line or the report."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from edge_explorer.mapping.metrics import MapMetrics
from edge_explorer.mapping.observed import ObservedMaps
from edge_explorer.predict.verification import UnverifiedArea, unverified_area_m2
from edge_explorer.runtime.daemon.report import CoverageTruth, Progress, RunReport, StageTimings, unverified_parts
from edge_explorer.runtime.mavlink_link import Pose as Odometry

Timeline = list[tuple[float, float | None, float | None, float, float | None]]  # (t_s, coverage, correct, path_m,
# observed coverage)


class RunRecord:
    """The figures of one run. ``coverage_goal`` marks the path length at the goal; ``timings`` is the run's stage
    timings (its statistics go into the report); ``truth`` (a plan of the building) enables coverage. Times are
    ``time.monotonic()`` seconds, reported relative to :meth:`start`."""

    def __init__(self, coverage_goal: float, timings: StageTimings, truth: CoverageTruth | None = None) -> None:
        self.coverage_goal = coverage_goal
        self.timings = timings
        self.truth = truth
        self.t0_s = 0.0
        self.decisions = 0
        self.sources: dict[str, int] = {}
        self.frames_fused = 0
        self.frames_dropped: dict[str, int] = {}
        self.holds: list[dict[str, Any]] = []
        self.metrics: MapMetrics | None = None
        self.path: list[tuple[float, float]] = []
        self.path_length_m = 0.0
        self.path_at_goal_m: float | None = None
        self.observed_coverage: float | None = None
        self.unverified: UnverifiedArea | None = None  # the maps' own estimate at the latest decision (issue #56)
        self.timeline: Timeline = []
        self.source_cpu_s = 0.0

    @property
    def unverified_m2(self) -> float | None:
        """The latest decision's unverified area (m², the map stop rule's figure); None before one."""
        return None if self.unverified is None else self.unverified.total_m2

    @property
    def coverage(self) -> float | None:
        """The latest decision's coverage (predicted with a predictor); None before one or without a plan."""
        return None if self.metrics is None else self.metrics.coverage

    def start(self, t0_s: float) -> None:
        self.t0_s = t0_s

    def add_source_cpu(self, seconds: float) -> None:
        """CPU time spent producing frames inside the loop."""
        self.source_cpu_s += seconds

    def frame_fused(self) -> None:
        self.frames_fused += 1

    def frame_dropped(self, reason: str) -> None:
        self.frames_dropped[reason] = self.frames_dropped.get(reason, 0) + 1

    def hold_began(self, since_s: float, reason: str) -> None:
        self.holds.append({"t_s": since_s - self.t0_s, "reason": reason, "duration_s": None})

    def hold_ended(self, held_s: float) -> None:
        self.holds[-1]["duration_s"] = held_s

    def decision(self, source: str) -> None:
        """One waypoint out, chosen by ``source`` (policy / frontier / hover / home / hold)."""
        self.decisions += 1
        self.sources[source] = self.sources.get(source, 0) + 1

    def record_progress(
        self,
        now: float,
        odometry: Odometry,
        maps: ObservedMaps,
        thresholded: np.ndarray | None,
        phase: str,
        probabilities: np.ndarray | None = None,
    ) -> None:
        """Coverage against the plan (if known) and the path, once per decision (the path grows while exploring or
        returning). Coverage is also measured on the observed map alone, so a flight shows how much of its coverage
        the prediction added (issue #17). The maps' own unverified area (from ``thresholded`` and the predictor's
        ``probabilities``; :mod:`edge_explorer.predict.verification`) is measured with or without a plan: without
        one it is what ends exploration."""
        xy = (odometry.x_m, odometry.y_m)
        if self.path and phase in ("exploring", "returning"):
            self.path_length_m += math.dist(self.path[-1], xy)
        self.path.append(xy)
        coverage = correct = None
        with self.timings.timed("coverage"):  # the maps' completeness: against the plan if known, and by themselves
            fused = maps.low if thresholded is None else thresholded
            self.unverified = unverified_area_m2(maps.low, fused, probabilities, maps.low_grid.resolution_m)
            if self.truth is not None:
                self.metrics = self.truth.metrics(maps.low, maps.low_grid, thresholded)
                observed = self.metrics if thresholded is None else self.truth.metrics(maps.low, maps.low_grid, None)
        if self.truth is not None:
            coverage, correct = self.metrics.coverage, self.metrics.correct_coverage
            self.observed_coverage = observed.coverage
            if self.path_at_goal_m is None and coverage >= self.coverage_goal:
                self.path_at_goal_m = self.path_length_m
        self.timeline.append((now - self.t0_s, coverage, correct, self.path_length_m, self.observed_coverage))

    def progress(self, now: float, phase: str, holding: str | None) -> Progress:
        decision = self.timings.stats().get("decision")
        m = self.metrics
        return Progress(
            elapsed_s=now - self.t0_s,
            phase=phase,
            coverage=None if m is None else m.coverage,
            correct_coverage=None if m is None else m.correct_coverage,
            path_length_m=self.path_length_m,
            decisions=self.decisions,
            decision_p95_ms=None if decision is None else decision.p95_ms,
            holding=holding,
        )

    def report(
        self,
        wall_s: float,
        cpu_s: float,
        *,
        ending: str,
        planner: str,
        predictor: bool,
        exploration_s: float | None,
        returned_home: bool,
    ) -> RunReport:
        m = self.metrics
        return RunReport(
            ending=ending,
            planner=planner,
            predictor=predictor,
            coverage=None if m is None else m.coverage,
            correct_coverage=None if m is None else m.correct_coverage,
            observed_coverage=self.observed_coverage,
            f1=None if m is None else m.f1,
            path_length_m=self.path_length_m,
            path_at_goal_m=self.path_at_goal_m,
            exploration_s=exploration_s,
            returned_home=returned_home,
            decisions=self.decisions,
            waypoint_sources=dict(self.sources),
            frames_fused=self.frames_fused,
            frames_dropped=dict(self.frames_dropped),
            holds=list(self.holds),
            wall_s=wall_s,
            process_cpu_s=cpu_s,
            source_cpu_s=self.source_cpu_s,
            stages=self.timings.stats(),
            timeline=list(self.timeline),
            path_xy_m=list(self.path),
            verified_m2=None if self.unverified is None else self.unverified.verified_m2,
            unverified_m2=None if self.unverified is None else self.unverified.total_m2,
            unverified=None if self.unverified is None else unverified_parts(self.unverified),
        )
