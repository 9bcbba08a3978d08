"""The exploration benchmark behind the paper's Table I and its coverage-vs-path-length figure (Fig. 5): the runs.

Methods are planner names (:data:`~edge_explorer.plan.registry.PLANNERS`: ``frontier``, ``fuel``, …), optionally
with ``+pred``: the paper's "+ Predictor" variants, where the planner still decides on the *observed* map but every
step the observed map goes through the predictor and coverage is counted on the thresholded prediction
(docs/design.md §5, §7; the simulator does this when it is given a predictor).

Runs: every run of a building starts from the same pose, drawn from the configuration space by the simulator's own
sampler with a seed derived from the benchmark seed and the building's name (:func:`start_pose`, so another method
— the DRL policy — can use the same starts); runs differ by the sensor- and motion-noise seed (:func:`run_seed`).
A run ends when coverage and correct coverage both reach the goal (95 %), when the planner has nothing left to
explore, or at the step cap. Every step's coverage, correct coverage and path length are recorded.

Runs go to worker processes; with an output folder each finished run is written there as a small JSON record and a
rerun skips the runs already recorded with the same settings (:func:`run_benchmark`). The records are summed up —
Table I, the paired differences between methods, the failures, the coverage figure — by
:mod:`edge_explorer.bench.summary`.
"""

from __future__ import annotations

import importlib
import json
import os
import time
import zlib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from edge_explorer.backends.card import CARD_FILE
from edge_explorer.cluster.units import map_units
from edge_explorer.errors import EdgeExplorerError
from edge_explorer.plan.goal_policy import GoalPolicy
from edge_explorer.plan.registry import PLANNERS, build_planner
from edge_explorer.predict.predictor import thresholds_of
from edge_explorer.sim.env import EnvConfig, ExplorationEnv, Predictor
from edge_explorer.sim.episode import Episode
from edge_explorer.world.raster import PlanRaster, clearance_m

PRED_SUFFIX = "+pred"
RECORD_FORMAT = "edge-explorer/explore-run"
START_CLEARANCE_M = 0.5  # from the start pose to the nearest wall
_START_ATTEMPTS = 100


@dataclass(frozen=True)
class BenchConfig:
    """When a run ends."""

    coverage_goal: float = 0.95
    max_steps: int = 1500

    def __post_init__(self) -> None:
        if not 0 < self.coverage_goal <= 1 or self.max_steps < 1:
            raise ValueError("coverage_goal must be in (0, 1] and max_steps ≥ 1")


@dataclass(frozen=True)
class RunSpec:
    """Everything that determines one run; a stored record is reused only if its spec is equal."""

    method: str
    plan: str
    run: int
    seed: int  # sensor- and motion-noise seed
    start_pose: tuple[float, float, float]
    coverage_goal: float
    max_steps: int
    predictor: str | None  # reference for +pred methods (see load_predictor)
    policy: str | None = None  # reference for the drl methods (see load_policy)

    @property
    def record_name(self) -> str:
        return f"{self.method}__{self.plan}__run{self.run:02d}.json"


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


def _derived_seed(seed: int, plan_name: str, *slot: int) -> int:
    sequence = np.random.SeedSequence(entropy=seed, spawn_key=(zlib.crc32(plan_name.encode()), *slot))
    return int(sequence.generate_state(1, dtype=np.uint32)[0])


def run_seed(seed: int, plan_name: str, run: int) -> int:
    """Noise seed of run ``run`` on a building: depends on the benchmark seed, the building's name and the run."""
    return _derived_seed(seed, plan_name, run + 1)


def start_pose(raster: PlanRaster, seed: int) -> tuple[float, float, float]:
    """The start pose of every run on ``raster``: the simulator's uniform draw from its configuration space, seeded
    from the benchmark seed and the building's name (so it does not depend on which other plans are benchmarked),
    redrawn until it lies at least :data:`START_CLEARANCE_M` from the walls — a vehicle takes off in the open, and
    one drawn at the very edge of the configuration space would touch a wall with its first, noisy, hover."""
    env = ExplorationEnv([raster], EnvConfig(motion_noise=False))
    clearance = clearance_m(raster)
    best, best_clearance = None, -1.0
    for attempt in range(_START_ATTEMPTS):
        env.reset(seed=_derived_seed(seed, raster.name, 0, attempt))
        row, col = (int(v) for v in raster.grid.cell_of(*env.pose[:2]))
        if clearance[row, col] > best_clearance:
            best, best_clearance = env.pose, float(clearance[row, col])
        if best_clearance >= START_CLEARANCE_M:
            break
    assert best is not None
    return best


def load_predictor(reference: str) -> Predictor:
    """The predictor named by ``reference``: a callable from the 256×256 int8 north-up low-res window to occupancy
    probabilities of the same shape (what :class:`~edge_explorer.sim.env.ExplorationEnv` takes).

    ``reference`` is one of

    * a model folder (``models/predictor``) or its ``card.json``: the exported artifacts through the backend chain
      (:func:`~edge_explorer.backends.chain.load_model`, int8 first, each checked against the card) — what the
      daemon flies;
    * a ``.safetensors`` file of :func:`~edge_explorer.learn.unet.save_unet`: the torch model (needs the ``train``
      extra), for weights that have not been exported yet;
    * ``module:callable``: any Python function, e.g. a test double.
    """
    path = Path(reference)
    if path.suffix == ".safetensors":
        if not path.is_file():
            raise EdgeExplorerError(f"--predictor {reference}: no such file")
        try:
            from edge_explorer.learn.unet import TorchPredictor
        except ImportError as exc:
            raise EdgeExplorerError(
                f"--predictor {reference}: torch weights need the train extra (pip install -e '.[train]'): {exc}"
            ) from exc
        return TorchPredictor.from_file(path)
    if path.is_dir() or path.name == CARD_FILE:
        from edge_explorer.backends.chain import load_model
        from edge_explorer.predict.predictor import PredictorRuntime

        return PredictorRuntime(load_model(path))
    module_name, _, attribute = reference.partition(":")
    if not module_name or not attribute:
        raise EdgeExplorerError(
            f"--predictor {reference!r}: expected a model folder with card.json, a .safetensors file or "
            "module:callable (a Python function from the 256×256 low-res window to probabilities)"
        )
    try:
        predictor = getattr(importlib.import_module(module_name), attribute)
    except (ImportError, AttributeError) as exc:
        raise EdgeExplorerError(f"--predictor {reference!r}: cannot load it ({exc})") from exc
    if not callable(predictor):
        raise EdgeExplorerError(f"--predictor {reference!r} is not callable")
    return predictor


def load_policy(reference: str) -> GoalPolicy:
    """The learned goal policy named by ``reference`` as a :data:`~edge_explorer.plan.goal_policy.GoalPolicy`
    (observation → 59 × 59 goal-cell scores), flown by :class:`~edge_explorer.plan.goal_policy.GoalPolicyPlanner`:

    * a ``.safetensors`` of :func:`~edge_explorer.learn.goal_net.save_goal_net` — the torch weights a training run
      writes (``train`` extra);
    * a model folder (``models/policy``) or its ``card.json`` — the exported policy through the backend chain, as the
      daemon runs it.
    """
    path = Path(reference)
    if path.suffix == ".safetensors":
        if not path.is_file():
            raise EdgeExplorerError(f"--policy {reference}: no such file")
        try:
            from edge_explorer.learn.goal_net import TorchGoalPolicy
        except ImportError as exc:
            raise EdgeExplorerError(
                f"--policy {reference}: torch weights need the train extra (pip install -e '.[train]'): {exc}"
            ) from exc
        try:
            return TorchGoalPolicy.from_file(path)
        except ValueError as exc:
            raise EdgeExplorerError(f"--policy {reference}: {exc}") from None
    if path.is_dir() or path.name == CARD_FILE:
        from edge_explorer.backends.chain import load_model
        from edge_explorer.plan.policy import PolicyRuntime

        return PolicyRuntime(load_model(path)).scores
    raise EdgeExplorerError(
        f"--policy {reference!r}: expected a model folder with card.json or a goal-policy .safetensors"
    )


# ---- one run ------------------------------------------------------------------------------------------------------
def run_episode(
    raster: PlanRaster,
    spec: RunSpec,
    predictor: Predictor | None = None,
    policy: GoalPolicy | None = None,
) -> dict[str, Any]:
    """Fly one run and return its record: the spec, how it ended, and the per-step curves.

    A planner method decides from the observed (and fused) map; the ``drl`` methods fly the learned goal ``policy``
    through the same planner loop (:class:`~edge_explorer.plan.goal_policy.GoalPolicyPlanner`)."""
    method = spec.method.removesuffix(PRED_SUFFIX)
    # the run, not the env, decides when to stop; the predictor's card may carry calibrated thresholds
    # (docs/design.md §5)
    config = EnvConfig(coverage_goal=1.0, max_steps=spec.max_steps, thresholds=thresholds_of(predictor))
    env = ExplorationEnv([raster], config, predictor=predictor)
    if PLANNERS[method].needs_policy and policy is None:
        raise EdgeExplorerError(f"{spec.method} needs a policy")
    planner = build_planner(method, env.table, policy)
    planner.reset()
    _, info = env.reset(seed=spec.seed, options={"start_pose": spec.start_pose})
    episode = Episode(env, planner, info, coverage_goal=spec.coverage_goal, max_steps=spec.max_steps)
    coverage, correct, path = [info["coverage"]], [info["correct_coverage"]], [info["path_length_m"]]
    start = time.perf_counter()
    for step in episode.steps():
        coverage.append(step.info["coverage"])
        correct.append(step.info["correct_coverage"])
        path.append(step.info["path_length_m"])
    ending = episode.ending
    assert ending is not None
    return {
        "format": RECORD_FORMAT,
        "spec": asdict(spec),
        "ending": ending,
        "why": explain_ending(env, ending, coverage[-1], correct[-1], spec),
        "steps": len(path) - 1,
        "collisions": episode.collisions,
        "final_coverage": coverage[-1],
        "final_correct_coverage": correct[-1],
        "path_length_m": path[-1],
        "path_at_coverage_m": _first_crossing(coverage, path, spec.coverage_goal),
        "path_at_correct_coverage_m": _first_crossing(correct, path, spec.coverage_goal),
        "wall_s": time.perf_counter() - start,
        "planner_s": episode.planner_s,
        "curves": {
            "coverage": np.round(coverage, 5).tolist(),
            "correct_coverage": np.round(correct, 5).tolist(),
            "path_length_m": np.round(path, 4).tolist(),
        },
    }


def explain_ending(env: ExplorationEnv, ending: str, coverage: float, correct: float, spec: RunSpec) -> dict[str, Any]:
    """Why a run ended where it did, in words and figures (issue #18): the goal; the step limit; or a planner
    stall — the planner found nothing left to explore in the observed map while N_M cells were still unknown, split
    into those the vehicle could have flown into and those it could only have seen from elsewhere. Space no flight
    can reach or see is not in N_M at all (``plans check`` reports its area), so it never explains a short run."""
    unexplored, reachable = env.unexplored()
    cell_m2 = env.maps.low_grid.resolution_m**2
    unexplored_m2 = float(unexplored.sum() * cell_m2)
    reachable_m2 = float(reachable.sum() * cell_m2)
    figures = {"unexplored_m2": round(unexplored_m2, 2), "unexplored_reachable_m2": round(reachable_m2, 2)}
    if ending == "goal":
        return {"reason": "goal", "text": f"coverage {coverage:.1%} and correct coverage {correct:.1%}", **figures}
    left = f"{unexplored_m2:.1f} m² of N_M unknown ({reachable_m2:.1f} m² of it reachable)"
    if ending == "step_cap":
        return {
            "reason": "step_limit",
            "text": f"step limit {spec.max_steps} reached at {coverage:.1%}; {left}",
            **figures,
        }
    if coverage >= spec.coverage_goal:  # coverage there, correct coverage short: the prediction filled cells wrongly
        text = f"nothing left to explore at {coverage:.1%}, but correct coverage {correct:.1%}: predicted cells wrong"
        return {"reason": "wrong_prediction", "text": text, **figures}
    text = f"planner stall: no reachable frontier left in the observed map at {coverage:.1%}; {left}"
    return {"reason": "planner_stall", "text": text, **figures}


def _first_crossing(values: Sequence[float], path_m: Sequence[float], goal: float) -> float | None:
    hits = np.flatnonzero(np.asarray(values) >= goal)
    return float(path_m[hits[0]]) if len(hits) else None


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
    stored = {"policy": None, **record.get("spec", {})}  # records from before the drl methods have no policy
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
