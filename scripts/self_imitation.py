"""Self-imitation of the goal policy (issue #21, session 24): can the policy learn from its own best flights?

PPO from the cloned policy failed on the host (session 23) because its critic explains almost nothing. Self-
imitation needs no critic: on each train plan fly the greedy policy once and ``--samples`` more times choosing each
goal cell by sampling the policy's softmax over its weighted scores (temperature ``--temperature``), from the same
start and noise seed (the benchmark's run 0). Where the best sampled flight reaches 95 % coverage and correct
coverage without a collision and is at least ``--margin`` metres shorter than the greedy one, its decisions (the
observation, the mask, the cell it chose) become demonstrations in the goal-demos format, ready for
``edge-explorer train goal-bc --init models/policy/policy.safetensors``::

    python scripts/self_imitation.py --first 3000 --count 120 --out runs/s24/si/train
    python scripts/self_imitation.py --first 3120 --count 24 --out runs/s24/si/val
    edge-explorer train goal-bc --train-demos runs/s24/si/train --val-demos runs/s24/si/val \\
        --init models/policy/policy.safetensors --steps 600 --lr 1e-4 --out runs/s24/si/bc
    python scripts/expert_sweep.py --name s24_si --first 40 --count 96 --planner drl \\
        --policy runs/s24/si/bc/best.safetensors
    python scripts/expert_sweep.py --compare s24_si s23_drl_base

Train plans only (the sweep's val plans 40–135 judge the result); ``summary.json`` in ``--out`` lists every plan's
greedy and sampled paths.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from multiprocessing import Pool
from pathlib import Path

import numpy as np
from tqdm import tqdm

from edge_explorer.bench import explore as bench
from edge_explorer.learn.goal_demos import Record, write_demos
from edge_explorer.plan.follow import Pose
from edge_explorer.plan.frontier import Goal, View
from edge_explorer.plan.goal_policy import GoalPolicyPlanner, goal_at_cell, goal_decision, weighted_scores
from edge_explorer.predict.predictor import thresholds_of
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.world.catalog import plan_to_raster
from edge_explorer.world.dataset import iter_shard_plans
from edge_explorer.world.plan import FloorPlan
from edge_explorer.world.raster import PlanRaster

sys.path.insert(0, str(Path(__file__).resolve().parent))  # scripts/: the sweep's benchmark run (expert_sweep.py)
from expert_sweep import fly_run  # noqa: E402

_WORKER: dict = {}


class RecordingPolicyPlanner(GoalPolicyPlanner):
    """The learned goal planner, greedy or sampling, recording each decision with the cell it chose."""

    def __init__(self, policy, table, temperature: float, rng: np.random.Generator | None) -> None:
        super().__init__(policy, table=table)
        self.temperature, self.rng = temperature, rng
        self.records: list[Record] = []

    def select_goal(self, view: View, pose: Pose) -> Goal | None:
        fused = self.fused if self.fused is not None else view.maps.low
        decision = goal_decision(view, pose, fused, self.last_action, self.config.goal_radius_m)
        if not decision.options.mask.any():
            return super().select_goal(view, pose)
        scores = weighted_scores(
            self.policy(decision.observation), decision.options, self.predictive.policy_cost_weight_per_m
        ).ravel()
        if self.rng is None:
            cell = int(np.argmax(scores))
        else:
            z = (scores - scores.max()) / self.temperature
            p = np.exp(z)
            cell = int(self.rng.choice(len(p), p=p / p.sum()))
        o = decision.observation
        self.records.append((o["high"], o["thres"], self.last_action, decision.options.flat_mask(), cell))
        return goal_at_cell(view, decision, cell)


def _init(args: argparse.Namespace) -> None:
    import torch

    torch.set_num_threads(1)
    _WORKER.update(args=args, predictor=bench.load_predictor(args.predictor), policy=bench.load_policy(args.policy))


def _flight(raster: PlanRaster, rng: np.random.Generator | None) -> tuple[float | None, int, list[Record]]:
    """(path at 95 % coverage or None, collisions, decisions) of the benchmark's run 0 on ``raster``."""
    args, predictor = _WORKER["args"], _WORKER["predictor"]
    max_steps = bench.BenchConfig().max_steps
    config = EnvConfig(coverage_goal=1.0, max_steps=max_steps, thresholds=thresholds_of(predictor))
    env = ExplorationEnv([raster], config, predictor=predictor)
    planner = RecordingPolicyPlanner(_WORKER["policy"], env.table, args.temperature, rng)
    at_goal, collisions, _, done = fly_run(env, planner, raster, max_steps)
    return (at_goal if done else None), collisions, planner.records


def plan_rollouts(indexed: tuple[int, FloorPlan]) -> dict:
    """The greedy flight and the sampled ones on one plan (rasterized here, in the worker); the best sampled
    flight's decisions if it wins."""
    index, plan = indexed
    raster = plan_to_raster(plan)
    args = _WORKER["args"]
    greedy, greedy_collisions, _ = _flight(raster, None)
    sampled = []
    for k in range(args.samples):
        rng = np.random.default_rng([args.seed, index, k])
        path, collisions, records = _flight(raster, rng)
        sampled.append((path, collisions, records))
    ok = [(p, r) for p, c, r in sampled if p is not None and c == 0]
    best = min(ok, key=lambda t: t[0]) if ok else None
    wins = best is not None and (greedy is None or best[0] <= greedy - args.margin)
    return {
        "plan": raster.name,
        "greedy": greedy,
        "greedy_collisions": greedy_collisions,
        "sampled": [p for p, _, _ in sampled],
        "kept": wins,
        "records": best[1] if wins else [],
    }


def _write_block(args: argparse.Namespace, rows: list[dict], block: list[Record], before: int) -> int:
    """Writes one block's kept decisions as a demo shard and the summary so far, so a run cut off (a lease's box)
    keeps every finished block; returns the block's decision count."""
    if block:
        name = f"shard-{(len(rows) - 1) // args.block:06d}"
        write_demos(args.out / f"{name}.npz", block)
        (args.out / f"{name}.json").write_text(json.dumps({"decisions": len(block)}))
    greedy = np.array([r["greedy"] if r["greedy"] is not None else np.nan for r in rows])
    best = np.array([min([p for p in r["sampled"] if p is not None], default=np.nan) for r in rows])
    summary = {
        "args": {k: str(v) for k, v in vars(args).items()},
        "plans": len(rows),
        "kept": sum(r["kept"] for r in rows),
        "decisions": before + len(block),
        "greedy_mean_m": float(np.nanmean(greedy)),
        "best_sampled_mean_m": float(np.nanmean(best)),
        "rows": rows,
    }
    (args.out / "summary.json").write_text(json.dumps(summary, indent=1))
    return len(block)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--first", type=int, required=True, help="first train plan")
    parser.add_argument("--count", type=int, required=True)
    parser.add_argument("--out", type=Path, required=True, help="demonstration shard folder")
    parser.add_argument("--samples", type=int, default=3, help="sampled flights per plan")
    parser.add_argument("--temperature", type=float, default=1.0)
    parser.add_argument("--margin", type=float, default=1.0, help="metres the best sample must save to be kept")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--predictor", default="models/predictor")
    parser.add_argument("--policy", default="models/policy")
    parser.add_argument("--plans", type=Path, default=Path("data/plans/train"))
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--block", type=int, default=16, help="plans per demo shard (written as each block ends)")
    args = parser.parse_args()
    shards = sorted(args.plans.glob("*.jsonl.gz"))
    if not shards:
        raise SystemExit(f"{args.plans}: no plan shards; generate them with `edge-explorer plans generate`")
    plans = itertools.islice(iter_shard_plans(shards), args.first, args.first + args.count)
    args.out.mkdir(parents=True, exist_ok=True)
    rows: list[dict] = []
    decisions = 0
    with Pool(args.workers, initializer=_init, initargs=(args,)) as pool:
        jobs = pool.imap(plan_rollouts, enumerate(plans, start=args.first))
        block: list[Record] = []
        for row in tqdm(jobs, total=args.count, desc="self-imitation"):
            block += row.pop("records")
            rows.append(row)
            if len(rows) % args.block == 0:
                decisions += _write_block(args, rows, block, decisions)
                block = []
        if len(rows) % args.block:
            decisions += _write_block(args, rows, block, decisions)
    summary = json.loads((args.out / "summary.json").read_text())
    print(
        f"{len(rows)} plans: greedy {summary['greedy_mean_m']:.2f} m, best of {args.samples} sampled "
        f"{summary['best_sampled_mean_m']:.2f} m; kept {summary['kept']} plans, {decisions} decisions -> {args.out}"
    )


if __name__ == "__main__":
    main()
