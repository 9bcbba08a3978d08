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
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import torch

from edge_explorer.bench import explore as bench
from edge_explorer.learn.policy_net import TorchPolicy, load_policy_module
from edge_explorer.sim.env import Predictor
from edge_explorer.world.raster import PlanRaster

BASELINE = "frontier"


def fly_policy(actor: torch.nn.Module, raster: PlanRaster, spec: bench.RunSpec, predictor: Predictor | None) -> dict:
    """One benchmark run of the policy; the record of :func:`bench.explore.run_episode`."""
    return bench.run_episode(raster, spec, predictor, TorchPolicy(actor))


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
