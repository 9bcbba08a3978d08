"""What a run measures and reports: the stage timings (:data:`STAGES`, :class:`StageTimings`, reused by the
profiling report), the progress line (:class:`Progress`), the coverage against the plan (:class:`CoverageTruth`),
the latest decision's maps (:class:`DecisionView`) and the run report (:class:`RunReport`). The daemon's part that
keeps their figures is :class:`~edge_explorer.runtime.daemon.record.RunRecord`."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from edge_explorer.mapping.metrics import MapMetrics, map_metrics
from edge_explorer.mapping.projection import onto_grid
from edge_explorer.predict.verification import UnverifiedArea
from edge_explorer.world.flight_space import reachable_cells
from edge_explorer.world.grid import LOW_RES_M, UNKNOWN, GridSpec, resolution_factor
from edge_explorer.world.raster import PlanRaster, block_reduce_max

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
    observed_coverage: float | None  # the observed map alone: what the prediction added is coverage minus this
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
    timeline: list[tuple[float, float | None, float | None, float, float | None]]  # (t_s, coverage, correct,
    # path_m, observed coverage)
    path_xy_m: list[tuple[float, float]]
    # The maps' own view at the last decision (issue #56; predict/verification.py), with or without a plan: the area
    # the sensor confirmed near the building, and the unverified area (unknown reachable + expected wrong predicted)
    # whose falling below the threshold ends exploration without a plan ("map says verified").
    verified_m2: float | None = None
    unverified_m2: float | None = None
    unverified: dict[str, float] | None = None  # its parts: unknown_reachable_m2, expected_wrong_m2, predicted_m2

    def to_json(self) -> dict[str, Any]:
        doc = asdict(self)
        doc["stages"] = {k: asdict(v) for k, v in self.stages.items()}
        return doc


def unverified_parts(area: UnverifiedArea) -> dict[str, float]:
    """The parts of an unverified area for a report, m² rounded to 0.01."""
    return {
        "unknown_reachable_m2": round(area.unknown_reachable_m2, 2),
        "expected_wrong_m2": round(area.expected_wrong_m2, 2),
        "predicted_m2": round(area.predicted_m2, 2),
    }


class CoverageTruth:
    """The plan's ground truth at 0.20 m, to measure coverage (docs/design.md §7) of maps on any grid: the daemon's
    grow from take-off, their extent unrelated to the plan's, and are taken onto the plan's grid
    (:func:`~edge_explorer.mapping.projection.onto_grid`)."""

    def __init__(self, raster: PlanRaster) -> None:
        low = raster.coarsened(LOW_RES_M)
        self.grid = low.grid
        self.truth = low.truth_codes()
        self.interior = low.interior
        factor = resolution_factor(raster.grid.resolution_m, LOW_RES_M)
        self.reachable = block_reduce_max(reachable_cells(raster), factor, low.grid.shape)

    def metrics(self, observed: np.ndarray, grid: GridSpec, thresholded: np.ndarray | None) -> MapMetrics:
        observed = onto_grid(observed, grid, self.grid)
        thres = None if thresholded is None else onto_grid(thresholded, grid, self.grid)
        return map_metrics(observed, self.truth, self.interior, thres)

    def unexplored(self, known: np.ndarray, grid: GridSpec) -> tuple[np.ndarray, np.ndarray]:
        """Bool masks on :attr:`grid`: N_M cells UNKNOWN in ``known`` (M_thres, or the observed low-res map), and
        those of them holding a cell the vehicle can reach — to explain a flight that ends short."""
        unexplored = self.interior & (onto_grid(known, grid, self.grid) == UNKNOWN)
        return unexplored, unexplored & self.reachable


@dataclass
class DecisionView:
    """The maps of the latest decision (for the run summary's picture)."""

    high: np.ndarray
    high_grid: GridSpec
    low: np.ndarray
    low_grid: GridSpec
    thresholded: np.ndarray | None  # observed ∪ thresholded prediction, when a predictor runs
