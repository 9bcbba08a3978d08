"""Evaluating a trained policy on buildings with the exploration benchmark's runs (DESIGN.md §7, Table I).

The policy flies exactly the benchmark's runs (:func:`edge_explorer.bench.explore.plan_specs`: one start pose per
building, the noise seed per run) with the same ending rule — coverage and correct coverage both at the goal, or the
step cap — and every run becomes a benchmark record (method ``drl``, or ``drl+pred`` with a predictor), so
:func:`~edge_explorer.bench.explore.summarize` and its Markdown table apply unchanged. The nearest-frontier baseline
is flown on the same specs in the same call, so the ratio of average path lengths compares like with like.

The actor is :func:`~edge_explorer.learn.policy_net.load_policy_module` of the weights file (torch, one thread), its
action the argmax of the logits — the policy's deterministic choice, as in the daemon.

:func:`compare_runs` sets training runs side by side: their val evaluations (``eval.csv`` of
:mod:`~edge_explorer.learn.train_policy`) against PPO steps and wall time, one PNG and the figures as JSON.
"""

from __future__ import annotations

import csv
import dataclasses
import json
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import torch

from edge_explorer.bench import explore as bench
from edge_explorer.cluster.units import map_units
from edge_explorer.errors import EdgeExplorerError
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
    ray: str | None = None,
) -> tuple[list[dict], list[str]]:
    """Records of the policy and of the frontier baseline (with ``+pred`` both when ``predictor`` is given) on the
    benchmark's specs, flown in ``workers`` processes or with ``ray`` as Ray tasks; returns (records, method names)."""
    config = config or bench.BenchConfig()
    suffix = bench.PRED_SUFFIX if predictor else ""
    methods = ["drl" + suffix, BASELINE + suffix]
    baseline_specs = bench.plan_specs(rasters, [BASELINE + suffix], runs, seed, config, predictor)
    specs = []
    for spec in baseline_specs:
        specs += [dataclasses.replace(spec, method=methods[0]), spec]
    by_name = {r.name: r for r in rasters}
    tasks = [(by_name[s.plan], s) for s in specs]
    results = map_units(
        _task,
        tasks,
        workers=workers,
        ray=ray,
        initializer=_init_worker,
        initargs=(str(weights), predictor),
        start_method="spawn",
    )
    records: dict[int, dict] = dict(progress(results, len(tasks)) if progress is not None else results)
    return [records[k] for k in range(len(tasks))], methods


def path_ratios(summary: dict[str, Any], methods: Sequence[str]) -> dict[str, float | None]:
    """Average path length at 95 % coverage of the policy / of the baseline, per building and over all runs."""
    policy, baseline = methods

    def ratio(group: dict[str, Any]) -> float | None:
        a, b = group[policy]["path_at_coverage_m"]["avg"], group[baseline]["path_at_coverage_m"]["avg"]
        return None if a is None or b is None else a / b

    return {**{plan: ratio(g) for plan, g in summary["plans"].items()}, "all": ratio(summary["all"])}


CURVE_METRICS = ("mean_coverage", "success_rate", "collisions_per_episode")


def _numbers(row: dict[str, str]) -> dict[str, Any]:
    def value(text: str) -> Any:
        if text == "":
            return None
        try:
            return float(text)
        except ValueError:
            return text

    return {k: value(v) for k, v in row.items()}


def run_figures(run_dir: Path) -> dict[str, Any]:
    """A training run's val evaluations and totals: every ``eval.csv`` row (plus ``train_wall_s``, the wall time
    after the untrained actor's evaluation — BC, PPO and evaluations, not the expert episodes), the rows after BC
    and after the last PPO evaluation, the best actor's row, PPO steps, wall time and SB3's last PPO steps/s."""
    evals_csv = run_dir / "eval.csv"
    if not evals_csv.exists():
        raise EdgeExplorerError(f"{run_dir}: no eval.csv; pass a folder written by `edge-explorer train policy`")
    with evals_csv.open(newline="") as fh:
        rows = [_numbers(r) for r in csv.DictReader(fh)]
    start = next((r["wall_s"] for r in rows if r["stage"] == "init"), 0.0)
    for row in rows:
        row["train_wall_s"] = round(row["wall_s"] - start, 1)
    state = json.loads((run_dir / "state.json").read_text())
    ppo = [r for r in rows if r["stage"] in ("phase1", "phase2")]
    fps = None
    if (run_dir / "progress.csv").exists():
        with (run_dir / "progress.csv").open(newline="") as fh:
            logged = [r["time/fps"] for r in csv.DictReader(fh) if r.get("time/fps")]
        fps = float(logged[-1]) if logged else None
    return {
        "run": str(run_dir),
        "ppo_steps": state["timesteps"],
        "wall_s": round(state["wall_s"], 1),
        "ppo_steps_per_s": fps,
        "after_bc": next((r for r in rows if r["stage"] == "bc"), None),
        "after_ppo": ppo[-1] if ppo else None,
        "best": state.get("best_eval"),
        "evaluations": rows,
    }


def compare_runs(runs: dict[str, Path], png: Path, json_path: Path) -> dict[str, Any]:
    """Learning curves of several runs (label → run folder) in one figure — val coverage, success and collisions
    per episode against PPO env steps (the BC actor at 0) and against wall time — and their figures as JSON."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from edge_explorer.cli import write_json

    figures = {label: run_figures(Path(folder)) for label, folder in runs.items()}
    fig, axes = plt.subplots(len(CURVE_METRICS), 2, figsize=(12, 9), sharex="col")
    for label, run in figures.items():
        rows = [r for r in run["evaluations"] if r["stage"] != "init"]
        for i, metric in enumerate(CURVE_METRICS):
            for j, x in enumerate(("timesteps", "train_wall_s")):
                xs = [r[x] / (1 if j == 0 else 3600) for r in rows]
                (line,) = axes[i, j].plot(xs, [r[metric] for r in rows], "o-", ms=3, label=label)
                bc = [k for k, r in enumerate(rows) if r["stage"] == "bc"]
                axes[i, j].plot([xs[k] for k in bc], [rows[k][metric] for k in bc], "s", ms=8, color=line.get_color())
    for i, metric in enumerate(CURVE_METRICS):
        axes[i, 0].set_ylabel(metric.replace("_", " "))
        if metric == "collisions_per_episode":
            for ax in axes[i]:
                ax.set_yscale("symlog", linthresh=1.0)
                ax.set_ylim(bottom=0)
        else:
            for ax in axes[i]:
                ax.set_ylim(0, 1.02)
    axes[-1, 0].set_xlabel("PPO env steps (square: after BC, at 0)")
    axes[-1, 1].set_xlabel("wall time after the untrained evaluation [h] (BC + PPO + evaluations)")
    axes[0, 0].legend()
    fig.suptitle("val evaluation (deterministic actor, 8 val plans, 500 steps)")
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    plt.close(fig)
    write_json(json_path, {"runs": figures})
    return figures
