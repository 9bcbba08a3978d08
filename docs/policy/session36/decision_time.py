"""What the view-gain ranking term costs a decision (issue #21, session 36): flies val plans with the learned planner
and, at every decision, times the goal choice (``goal_policy.best_cell_worth_a_look``) twice on the same inputs:
without the gain term (``policy_gain_weight`` 0: only the best-ranked few views measured) and with it (every valid
cell's view measured). Prints the median and 95th percentile of each and their ratio, measured in one process::

    python docs/policy/session36/decision_time.py --first 40 --count 5 --gain-weight 2
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import time
from pathlib import Path

import numpy as np

from edge_explorer.bench import explore as bench
from edge_explorer.plan import goal_policy
from edge_explorer.plan.goal_policy import GoalPolicyPlanner
from edge_explorer.plan.predictive import PredictiveConfig
from edge_explorer.predict.predictor import thresholds_of
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.world.catalog import plan_to_raster
from edge_explorer.world.dataset import iter_shard_plans

_choose = goal_policy.best_cell_worth_a_look
TIMES: dict[str, list[float]] = {"without": [], "with": []}


def timed_choice(view, decision, scores, fused_low, config) -> int:  # noqa: ANN001 - the product's signature
    """Both choices timed on the same decision: without the gain term, then with it (``config``'s weight); the
    choice with it is flown."""
    start = time.perf_counter()
    _choose(view, decision, scores, fused_low, dataclasses.replace(config, policy_gain_weight=0.0))
    TIMES["without"].append(time.perf_counter() - start)
    start = time.perf_counter()
    cell = _choose(view, decision, scores, fused_low, config)
    TIMES["with"].append(time.perf_counter() - start)
    return cell


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--first", type=int, default=40)
    parser.add_argument("--count", type=int, default=5)
    parser.add_argument("--gain-weight", type=float, default=2.0)
    args = parser.parse_args()
    goal_policy.best_cell_worth_a_look = timed_choice
    predictor, policy = bench.load_predictor("models/predictor"), bench.load_policy("models/policy/policy.safetensors")
    shards = sorted(Path("data/plans/val").glob("*.jsonl.gz"))
    for plan in itertools.islice(iter_shard_plans(shards), args.first, args.first + args.count):
        raster = plan_to_raster(plan)
        config = EnvConfig(coverage_goal=0.95, max_steps=1500, thresholds=thresholds_of(predictor))
        env = ExplorationEnv([raster], config, predictor=predictor)
        planner = GoalPolicyPlanner(policy, PredictiveConfig(policy_gain_weight=args.gain_weight), env.table)
        _, info = env.reset(seed=0, options={"start_pose": bench.start_pose(raster, 0)})
        previous, done = 0, False
        while not done:
            action = planner.act(env.maps, env.pose, previous, env.thresholded_low)
            if action is None:
                break
            _, _, done, truncated, info = env.step(action)
            done = done or truncated
            previous = 0 if info["collided"] else action
    ms = {k: 1000 * np.array(v) for k, v in TIMES.items()}
    for name, t in ms.items():
        print(f"{name:8s} {len(t)} decisions: median {np.median(t):.2f} ms, p95 {np.percentile(t, 95):.2f} ms")
    print(f"with / without: median {np.median(ms['with']) / np.median(ms['without']):.1f}×")


if __name__ == "__main__":
    main()
