"""One simulated exploration run with a planner and its record, as the exploration benchmark
(:mod:`edge_explorer.bench.explore`) and the goal policy's training evaluation fly it: :class:`RunSpec` (what
determines a run) and :func:`run_episode` (the run, flown by the one step loop :class:`~edge_explorer.sim.episode.
Episode`, and its record: how it ended and why, the per-step curves)."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from edge_explorer.errors import EdgeExplorerError
from edge_explorer.plan.goal_policy import GoalPolicy
from edge_explorer.plan.registry import PLANNERS, build_planner
from edge_explorer.predict.predictor import thresholds_of
from edge_explorer.predict.verification import UnverifiedArea, unverified_area_m2
from edge_explorer.sim.env import EnvConfig, ExplorationEnv, Predictor
from edge_explorer.sim.episode import Episode
from edge_explorer.world.raster import PlanRaster

PRED_SUFFIX = "+pred"
RECORD_FORMAT = "edge-explorer/explore-run"
STOP_MODES = ("truth", "map")
FALSE_STOP_CORRECT = 0.90  # a map stop with correct coverage below this is a false stop (issue #56)


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
    predictor: str | None  # reference for +pred methods (see edge_explorer.learn.loaders.load_predictor)
    policy: str | None = None  # reference for the drl methods (see edge_explorer.learn.loaders.load_policy)
    stop: str = "truth"  # "truth": the coverage goal ends a run; "map": the map stop rule does (issue #56)
    stop_threshold_m2: float | None = None  # the map stop rule's threshold on the unverified area (stop "map")

    def __post_init__(self) -> None:
        if self.stop not in STOP_MODES:
            raise ValueError(f"stop must be one of {STOP_MODES}, got {self.stop!r}")
        if (self.stop == "map") != (self.stop_threshold_m2 is not None):
            raise ValueError("stop 'map' needs stop_threshold_m2, stop 'truth' takes none")

    @property
    def record_name(self) -> str:
        return f"{self.method}__{self.plan}__run{self.run:02d}.json"


def run_episode(
    raster: PlanRaster,
    spec: RunSpec,
    predictor: Predictor | None = None,
    policy: GoalPolicy | None = None,
) -> dict[str, Any]:
    """Fly one run and return its record: the spec, how it ended, and the per-step curves.

    A planner method decides from the observed (and fused) map; the ``drl`` methods fly the learned goal ``policy``
    through the same planner loop (:class:`~edge_explorer.plan.goal_policy.GoalPolicyPlanner`).

    With ``spec.stop == "map"`` the coverage goal does not end the run: the map stop rule does, when the unverified
    area of the maps (:func:`~edge_explorer.predict.verification.unverified_area_m2`) falls below
    ``spec.stop_threshold_m2``; the record then also holds the unverified area at every step and at the end, and
    coverage, correct coverage and path at the stop (its end, whatever ended it)."""
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
    unverified: list[UnverifiedArea] = []
    map_stop = None if spec.stop != "map" else _map_stop_rule(env, spec, unverified)
    episode = Episode(env, planner, info, coverage_goal=spec.coverage_goal, max_steps=spec.max_steps, map_stop=map_stop)
    coverage, correct, path = [info["coverage"]], [info["correct_coverage"]], [info["path_length_m"]]
    start = time.perf_counter()
    for step in episode.steps():
        coverage.append(step.info["coverage"])
        correct.append(step.info["correct_coverage"])
        path.append(step.info["path_length_m"])
    ending = episode.ending
    assert ending is not None
    record = {
        "format": RECORD_FORMAT,
        "spec": asdict(spec),
        "ending": ending,
        "why": explain_ending(env, ending, coverage[-1], correct[-1], spec),
        "steps": len(path) - 1,
        "collisions": episode.collisions,
        "final_coverage": coverage[-1],
        "final_correct_coverage": correct[-1],
        "path_length_m": path[-1],
        "n_m_m2": info["n_m_m2"],
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
    if spec.stop == "map":
        record.update(_map_stop_figures(unverified[-1], correct[-1], path[-1]))
        record["curves"]["unverified_m2"] = np.round([u.total_m2 for u in unverified], 3).tolist()
    return record


def _map_stop_rule(env: ExplorationEnv, spec: RunSpec, unverified: list[UnverifiedArea]) -> Callable[[], bool]:
    """The map stop rule on ``env``'s maps with ``spec``'s threshold; each call appends its unverified area."""
    threshold = spec.stop_threshold_m2
    assert threshold is not None

    def map_stop() -> bool:
        maps = env.maps
        area = unverified_area_m2(maps.low, env.thresholded_low, env.probabilities_low, maps.low_grid.resolution_m)
        unverified.append(area)
        return area.total_m2 < threshold

    return map_stop


def _map_stop_figures(end: UnverifiedArea, correct: float, path_m: float) -> dict[str, Any]:
    """What a ``--stop map`` record adds besides the curve of the unverified area: that area at the end, correct
    coverage and path at the stop, and whether it was a false stop (correct coverage below 90 % there)."""
    return {
        "unverified": {k: round(v, 3) for k, v in asdict(end).items()} | {"total_m2": round(end.total_m2, 3)},
        "correct_coverage_at_stop": correct,
        "path_at_stop_m": path_m,
        "false_stop": correct < FALSE_STOP_CORRECT,
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
    if ending == "map_stop":
        text = (
            f"map says verified (unverified area below {spec.stop_threshold_m2} m²) at coverage {coverage:.1%}, "
            f"correct coverage {correct:.1%}; {figures['unexplored_m2']:.1f} m² of N_M unknown"
        )
        return {"reason": "map_stop", "text": text, **figures}
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
