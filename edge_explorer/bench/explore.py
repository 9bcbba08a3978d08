"""The exploration benchmark behind the paper's Table I and its coverage-vs-path-length figure (Fig. 5): the runs.

Methods are planner names (:data:`~edge_explorer.plan.registry.PLANNERS`: ``frontier``, ``fuel``, …), optionally
with ``+pred``: the paper's "+ Predictor" variants, where the planner still decides on the *observed* map but every
step the observed map goes through the predictor and coverage is counted on the thresholded prediction
(docs/design.md §5, §7; the simulator does this when it is given a predictor).

Runs: every run of a building starts from the same pose, drawn from the configuration space by the simulator's own
sampler with a seed derived from the benchmark seed and the building's name
(:func:`~edge_explorer.sim.starts.start_pose`, so another method — the DRL policy — can use the same starts); runs
differ by the sensor- and motion-noise seed (:func:`~edge_explorer.world.seeds.run_seed`). A run
(:func:`~edge_explorer.sim.episode.run_episode`) ends when coverage and correct coverage both reach the goal (95 %),
when the planner has nothing left to explore, or at the step cap. Every step's coverage, correct coverage and path
length are recorded. With ``stop="map"`` (``--stop map``) the goal, which needs the truth, is replaced by the map
stop rule, which does not (issue #56): the run ends when the maps' unverified area falls below a threshold, and its
record says how right the map was there (false stops: correct coverage below 90 %).

Runs go to worker processes; with an output folder each finished run is written there as a small JSON record and a
rerun skips the runs already recorded with the same settings (:func:`run_benchmark`). The records are summed up —
Table I, the paired differences between methods, the failures, the coverage figure — by
:mod:`edge_explorer.bench.summary`.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from edge_explorer.cluster.units import map_units
from edge_explorer.errors import EdgeExplorerError
from edge_explorer.learn.loaders import load_policy, load_predictor
from edge_explorer.plan.goal_policy import GoalPolicy
from edge_explorer.plan.registry import PLANNERS
from edge_explorer.predict.verification import DEFAULT_STOP_THRESHOLD_M2
from edge_explorer.sim.env import Predictor
from edge_explorer.sim.runs import PRED_SUFFIX, RECORD_FORMAT, STOP_MODES, RunSpec, run_episode
from edge_explorer.sim.starts import start_pose
from edge_explorer.world.raster import PlanRaster
from edge_explorer.world.seeds import run_seed


@dataclass(frozen=True)
class BenchConfig:
    """When a run ends: ``stop`` "truth" at the coverage goal (coverage and correct coverage against the plan), or
    "map" when the map stop rule says the map is verified (unverified area below ``stop_threshold_m2``, issue #56,
    :mod:`edge_explorer.predict.verification`); either way when the planner has nothing left or at ``max_steps``."""

    coverage_goal: float = 0.95
    max_steps: int = 1500
    stop: str = "truth"
    stop_threshold_m2: float = DEFAULT_STOP_THRESHOLD_M2

    def __post_init__(self) -> None:
        if not 0 < self.coverage_goal <= 1 or self.max_steps < 1:
            raise ValueError("coverage_goal must be in (0, 1] and max_steps ≥ 1")
        if self.stop not in STOP_MODES or not self.stop_threshold_m2 >= 0:
            raise ValueError(f"stop must be one of {STOP_MODES} and stop_threshold_m2 ≥ 0")


# ---- methods, seeds, starts ---------------------------------------------------------------------------------------
def parse_methods(text: str) -> list[str]:
    """Validate a comma-separated method list (``frontier``, ``fuel``, each optionally with ``+pred``)."""
    methods = [m.strip() for m in text.split(",") if m.strip()]
    if not methods:
        raise EdgeExplorerError("no method given; choose from " + ", ".join(_known_methods()))
    for m in methods:
        if m not in _known_methods():
            raise EdgeExplorerError(f"unknown method {m!r}; choose from {', '.join(_known_methods())}")
    if len(set(methods)) != len(methods):
        raise EdgeExplorerError(f"method listed twice in {text!r}")
    return methods


def _known_methods() -> list[str]:
    return [*PLANNERS, *(name + PRED_SUFFIX for name in PLANNERS)]


def needs_policy(method: str) -> bool:
    """Whether ``method`` flies a learned goal policy (``drl``, ``drl+pred``)."""
    return PLANNERS[method.removesuffix(PRED_SUFFIX)].needs_policy


# ---- many runs ----------------------------------------------------------------------------------------------------
def plan_specs(
    rasters: Sequence[PlanRaster],
    methods: Sequence[str],
    runs: int,
    seed: int,
    config: BenchConfig = BenchConfig(),
    predictor: str | None = None,
    policy: str | None = None,
) -> list[RunSpec]:
    """Every (method, building, run) of a benchmark, building-major so that early results cover every method."""
    if any(m.endswith(PRED_SUFFIX) for m in methods) and predictor is None:
        raise EdgeExplorerError("the +pred methods need --predictor (e.g. models/predictor); none was given")
    if any(needs_policy(m) for m in methods) and policy is None:
        raise EdgeExplorerError("the drl methods need --policy (e.g. models/policy); none was given")
    names = [r.name for r in rasters]
    if len(set(names)) != len(names):
        raise EdgeExplorerError("two plans share a name; benchmark records are keyed by plan name")
    specs = []
    for raster in rasters:
        pose = start_pose(raster, seed)
        for run in range(runs):
            for method in methods:
                specs.append(
                    RunSpec(
                        method,
                        raster.name,
                        run,
                        run_seed(seed, raster.name, run),
                        pose,
                        config.coverage_goal,
                        config.max_steps,
                        predictor if method.endswith(PRED_SUFFIX) else None,
                        policy if needs_policy(method) else None,
                        config.stop,
                        config.stop_threshold_m2 if config.stop == "map" else None,
                    )
                )
    return specs


_WORKER_PREDICTORS: dict[str, Predictor] = {}
_WORKER_POLICIES: dict[str, GoalPolicy] = {}


def _run_task(task: tuple[PlanRaster, RunSpec]) -> dict[str, Any]:
    raster, spec = task
    predictor = None
    if spec.predictor is not None:
        if spec.predictor not in _WORKER_PREDICTORS:
            _WORKER_PREDICTORS[spec.predictor] = load_predictor(spec.predictor)
        predictor = _WORKER_PREDICTORS[spec.predictor]
    policy = None
    if spec.policy is not None:
        if spec.policy not in _WORKER_POLICIES:
            _WORKER_POLICIES[spec.policy] = load_policy(spec.policy)
        policy = _WORKER_POLICIES[spec.policy]
    return run_episode(raster, spec, predictor, policy)


def _single_thread_worker() -> None:
    import cv2

    cv2.setNumThreads(1)  # one process per core: no nested thread pools


def _read_record(path: Path, spec: RunSpec) -> dict[str, Any] | None:
    try:
        record = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    # records from before the drl methods have no policy, those from before the map stop rule no stop settings
    stored = {"policy": None, "stop": "truth", "stop_threshold_m2": None, **record.get("spec", {})}
    if record.get("format") != RECORD_FORMAT or stored != json.loads(json.dumps(asdict(spec))):
        return None
    return record


def run_benchmark(
    rasters: Sequence[PlanRaster],
    specs: Sequence[RunSpec],
    workers: int = 1,
    out_dir: Path | None = None,
    progress: Callable[[Iterable[Any], int], Iterable[Any]] | None = None,
    ray: str | None = None,
) -> list[dict[str, Any]]:
    """Records of every spec, in spec order; runs recorded in ``out_dir`` with the same spec are not flown again.

    ``progress`` wraps the iterator of finished runs (e.g. a tqdm bar): ``progress(iterable, total)``. The runs go
    to ``workers`` processes, or with ``ray`` (``"auto"`` or an address) to Ray tasks; each is recorded as it ends.
    """
    by_name = {r.name: r for r in rasters}
    records: dict[int, dict[str, Any]] = {}
    todo = []
    for k, spec in enumerate(specs):
        stored = _read_record(out_dir / spec.record_name, spec) if out_dir is not None else None
        if stored is not None:
            records[k] = stored
        else:
            todo.append(k)
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
    tasks = [(by_name[specs[k].plan], specs[k]) for k in todo]
    # Fresh interpreters ("spawn"): forking a parent whose opencv thread pool is running can deadlock the child.
    results = map_units(
        _run_task, tasks, workers=workers, ray=ray, initializer=_single_thread_worker, start_method="spawn"
    )
    for j, record in progress(results, len(todo)) if progress is not None else results:
        records[todo[j]] = record
        if out_dir is not None:
            (out_dir / specs[todo[j]].record_name).write_text(json.dumps(record, separators=(",", ":")) + "\n")
    return [records[k] for k in range(len(specs))]


def default_workers() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))
