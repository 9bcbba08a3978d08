"""Evaluating a trained policy on buildings with the exploration benchmark's runs (DESIGN.md §7, Table I).

The policy flies exactly the benchmark's runs (:func:`edge_explorer.bench.explore.plan_specs`: one start pose per
building, the noise seed per run) with the same ending rule — coverage and correct coverage both at the goal, or the
step cap — and every run becomes a benchmark record (method ``drl``, or ``drl+pred`` with a predictor), so
:func:`~edge_explorer.bench.explore.summarize` and its Markdown table apply unchanged. The nearest-frontier baseline
is flown on the same specs in the same call, so the ratio of average path lengths compares like with like.

The actor is :func:`~edge_explorer.learn.policy_net.load_policy_module` of the weights file (torch, one thread), its
action the argmax of the logits — the policy's deterministic choice, as in the daemon.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch

from edge_explorer.bench import explore as bench
from edge_explorer.learn.policy_net import load_policy_module
from edge_explorer.sim.env import EnvConfig, ExplorationEnv, Predictor
from edge_explorer.world.raster import PlanRaster

BASELINE = "frontier"


def fly_policy(actor: torch.nn.Module, raster: PlanRaster, spec: bench.RunSpec, predictor: Predictor | None) -> dict:
    """One benchmark run of the policy; the record has the fields of :func:`bench.explore.run_episode`'s."""
    env = ExplorationEnv([raster], EnvConfig(coverage_goal=1.0, max_steps=spec.max_steps), predictor=predictor)
    obs, info = env.reset(seed=spec.seed, options={"start_pose": spec.start_pose})
    coverage, correct, path = [info["coverage"]], [info["correct_coverage"]], [info["path_length_m"]]
    collisions, policy_s = 0, 0.0
    start = time.perf_counter()
    while True:
        if coverage[-1] >= spec.coverage_goal and correct[-1] >= spec.coverage_goal:
            ending = "goal"
            break
        if len(path) > spec.max_steps:
            ending = "step_cap"
            break
        t = time.perf_counter()
        inputs = (torch.as_tensor(obs[k], dtype=torch.float32)[None] for k in ("high", "thres", "last_action"))
        with torch.no_grad():
            logits = actor(*inputs)
        action = int(logits.argmax())
        policy_s += time.perf_counter() - t
        obs, _, _, _, info = env.step(action)
        collisions += int(info["collided"])
        coverage.append(info["coverage"])
        correct.append(info["correct_coverage"])
        path.append(info["path_length_m"])
    return {
        "format": bench.RECORD_FORMAT,
        "spec": asdict(spec),
        "ending": ending,
        "steps": len(path) - 1,
        "collisions": collisions,
        "final_coverage": coverage[-1],
        "final_correct_coverage": correct[-1],
        "path_length_m": path[-1],
        "path_at_coverage_m": _first_crossing(coverage, path, spec.coverage_goal),
        "path_at_correct_coverage_m": _first_crossing(correct, path, spec.coverage_goal),
        "wall_s": time.perf_counter() - start,
        "planner_s": policy_s,
        "curves": {
            "coverage": np.round(coverage, 5).tolist(),
            "correct_coverage": np.round(correct, 5).tolist(),
            "path_length_m": np.round(path, 4).tolist(),
        },
    }


def _first_crossing(values: Sequence[float], path_m: Sequence[float], goal: float) -> float | None:
    hits = np.flatnonzero(np.asarray(values) >= goal)
    return float(path_m[hits[0]]) if len(hits) else None


_WORKER: dict[str, Any] = {}


def _init_worker(weights: str, predictor: str | None) -> None:
    import cv2

    cv2.setNumThreads(1)
    torch.set_num_threads(1)
    _WORKER["actor"] = load_policy_module(Path(weights))
    _WORKER["predictor"] = bench.load_predictor(predictor) if predictor else None


def _task(task: tuple[PlanRaster, bench.RunSpec]) -> dict:
    raster, spec = task
    if spec.method.startswith("drl"):
        return fly_policy(_WORKER["actor"], raster, spec, _WORKER["predictor"])
    return bench.run_episode(raster, spec, _WORKER["predictor"] if spec.predictor else None)


def evaluate_buildings(
    weights: Path,
    rasters: Sequence[PlanRaster],
    runs: int,
    seed: int = 0,
    config: bench.BenchConfig | None = None,
    predictor: str | None = None,
    workers: int = 1,
    progress: Callable[[Iterable[Any], int], Iterable[Any]] | None = None,
) -> tuple[list[dict], list[str]]:
    """Records of the policy and of the frontier baseline (with ``+pred`` both when ``predictor`` is given) on the
    benchmark's specs; returns (records, method names)."""
    config = config or bench.BenchConfig()
    suffix = bench.PRED_SUFFIX if predictor else ""
    methods = ["drl" + suffix, BASELINE + suffix]
    baseline_specs = bench.plan_specs(rasters, [BASELINE + suffix], runs, seed, config, predictor)
    specs = []
    for spec in baseline_specs:
        specs += [dataclasses.replace(spec, method=methods[0]), spec]
    by_name = {r.name: r for r in rasters}
    tasks = [(by_name[s.plan], s) for s in specs]
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(
        max_workers=workers, mp_context=context, initializer=_init_worker, initargs=(str(weights), predictor)
    ) as pool:
        results = pool.map(_task, tasks, chunksize=1)
        records = list(progress(results, len(tasks)) if progress is not None else results)
    return records, methods


def path_ratios(summary: dict[str, Any], methods: Sequence[str]) -> dict[str, float | None]:
    """Average path length at 95 % coverage of the policy / of the baseline, per building and over all runs."""
    policy, baseline = methods

    def ratio(group: dict[str, Any]) -> float | None:
        a, b = group[policy]["path_at_coverage_m"]["avg"], group[baseline]["path_at_coverage_m"]["avg"]
        return None if a is None or b is None else a / b

    return {**{plan: ratio(g) for plan, g in summary["plans"].items()}, "all": ratio(summary["all"])}
