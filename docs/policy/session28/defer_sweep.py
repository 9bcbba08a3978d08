"""The goal policy that defers to its teacher when unsure (issue #21, session 28): a val sweep.

The policy scores every valid goal cell; where its softmax puts less than ``--confidence`` of its mass within
``--radius`` goal cells (Chebyshev) of its best cell, the decision is a near-tie between places far apart, which
the rollouts of ``branch_q.py`` show is where single choices swing a flight by metres. There the predictive expert's
goal (same view, same loop) is flown instead. Each run is ``expert_sweep.py``'s (the benchmark's run 0 on a val plan),
so the sweep pairs with the sweeps there::

    python docs/policy/session28/defer_sweep.py --name s28_defer50 --confidence 0.5 --first 40 --count 96
    python docs/policy/expert_sweep.py --compare s28_defer50 s24_si_last
"""

from __future__ import annotations

import argparse
import itertools
import json
from multiprocessing import Pool
from pathlib import Path

import numpy as np
from expert_sweep import fly_run
from tqdm import tqdm

from edge_explorer.bench import explore as bench
from edge_explorer.plan.follow import Pose
from edge_explorer.plan.frontier import Goal, View
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS
from edge_explorer.plan.goal_policy import GoalPolicyPlanner, goal_at_cell, goal_decision, weighted_scores
from edge_explorer.predict.predictor import thresholds_of
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.world.catalog import plan_to_raster
from edge_explorer.world.dataset import iter_shard_plans
from edge_explorer.world.raster import PlanRaster

_WORKER: dict = {}


def mass_near_best(scores: np.ndarray, radius: int) -> float:
    """Softmax mass of the (G, G) ``scores`` (−inf where masked) within ``radius`` cells of the best cell."""
    finite = np.isfinite(scores)
    probs = np.where(finite, np.exp(scores - scores[finite].max()), 0.0)
    probs /= probs.sum()
    row, col = divmod(int(np.argmax(np.where(finite, scores, -np.inf))), GOAL_GRID_CELLS)
    return float(probs[max(row - radius, 0) : row + radius + 1, max(col - radius, 0) : col + radius + 1].sum())


class DeferringPlanner(GoalPolicyPlanner):
    """:class:`GoalPolicyPlanner` that flies the expert's goal where the policy is unsure (module docstring)."""

    def __init__(self, policy, table, confidence: float, radius: int) -> None:
        super().__init__(policy, table=table)
        self.confidence, self.radius = confidence, radius
        self.decisions = self.deferred = 0

    def select_goal(self, view: View, pose: Pose) -> Goal | None:
        fused = self.fused if self.fused is not None else view.maps.low
        decision = goal_decision(view, pose, fused, self.last_action, self.config.goal_radius_m)
        if not decision.options.mask.any():
            return super(GoalPolicyPlanner, self).select_goal(view, pose)
        scores = weighted_scores(
            self.policy(decision.observation), decision.options, self.predictive.policy_cost_weight_per_m
        )
        self.decisions += 1
        if mass_near_best(scores, self.radius) < self.confidence:
            expert = super(GoalPolicyPlanner, self).select_goal(view, pose)
            if expert is not None:
                self.deferred += 1
                return expert
        return goal_at_cell(view, decision, int(np.argmax(scores)))


def _init(args: argparse.Namespace) -> None:
    import torch

    torch.set_num_threads(1)
    _WORKER.update(args=args, predictor=bench.load_predictor(args.predictor), policy=bench.load_policy(args.policy))


def fly(raster: PlanRaster) -> tuple[str, float | None, int, int | None, int, int]:
    """``expert_sweep.fly``'s row (plan, path at 95 %, collisions, steps) plus decisions and deferred decisions."""
    args, predictor = _WORKER["args"], _WORKER["predictor"]
    max_steps = bench.BenchConfig().max_steps
    env = ExplorationEnv(
        [raster], EnvConfig(coverage_goal=1.0, max_steps=max_steps, thresholds=thresholds_of(predictor)), predictor
    )
    planner = DeferringPlanner(_WORKER["policy"], env.table, args.confidence, args.radius)
    at_goal, collisions, steps_at_goal, _ = fly_run(env, planner, raster, max_steps)
    return raster.name, at_goal, collisions, steps_at_goal, planner.decisions, planner.deferred


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--name", required=True)
    parser.add_argument("--confidence", type=float, required=True, help="defer below this softmax mass near the best")
    parser.add_argument("--radius", type=int, default=2, help="goal cells around the best that count as near it")
    parser.add_argument("--first", type=int, default=40)
    parser.add_argument("--count", type=int, default=96)
    parser.add_argument("--predictor", default="models/predictor")
    parser.add_argument("--policy", default="models/policy/policy.safetensors")
    parser.add_argument("--plans", type=Path, default=Path("data/plans/val"))
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    shards = sorted(args.plans.glob("*.jsonl.gz"))
    plans = [plan_to_raster(p) for p in itertools.islice(iter_shard_plans(shards), args.first, args.first + args.count)]
    with Pool(args.workers, initializer=_init, initargs=(args,)) as pool:
        runs = list(tqdm(pool.imap(fly, plans), total=len(plans), desc=args.name))
    out = Path("runs/expert_sweep") / f"{args.name}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"args": {k: str(v) for k, v in vars(args).items()}, "runs": runs}))
    paths = [r[1] for r in runs if r[1] is not None]
    deferred = sum(r[5] for r in runs) / max(sum(r[4] for r in runs), 1)
    print(
        f"{args.name}: mean path at 95 % {np.mean(paths):.2f} m, reached {len(paths)}/{len(runs)}, collisions "
        f"{sum(r[2] for r in runs)}, deferred {100 * deferred:.1f} % of decisions -> {out}"
    )


if __name__ == "__main__":
    main()
