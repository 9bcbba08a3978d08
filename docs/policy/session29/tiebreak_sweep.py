"""The predictive expert whose near-ties the learned policy breaks (issue #21, session 29): a val sweep.

Session 20 traced the expert's bad runs on A and D to near-ties: two fused frontier clusters about equally near
(γ = 0 scores a cluster by 1 / (path + offset)), and the noise seed decides which is flown. The goal policy was
cloned from the expert and then self-imitated its own shorter flights, and it is ahead of the expert on A-D. Here the
expert decides as always, except that among the worthwhile clusters whose score is within ``--tie`` of the best
(``(path + offset) <= (1 + tie) * (best path + offset)``) the one the policy scores highest is flown: the policy's
score of a cluster is its best valid goal-cell score within one goal cell of the ego cell of the cluster's goal
node. Everything else (near-fallback picks, fallbacks, the goal built for a cluster) is the expert's. Each run is
``expert_sweep.py``'s (the benchmark's run 0 on a val plan), so the sweep pairs with the stored expert sweeps::

    PYTHONPATH=docs/policy python docs/policy/session29/tiebreak_sweep.py --name s29_tb25_40 --tie 0.25 --first 40
    python docs/policy/expert_sweep.py --compare s29_tb25_40 s28_defer1.01
"""

from __future__ import annotations

import argparse

import numpy as np
from expert_sweep import add_sweep_args, fly_run, fly_sweep

from edge_explorer.bench import explore as bench
from edge_explorer.plan.follow import Pose
from edge_explorer.plan.frontier import (
    Goal,
    View,
    frontier_mask,
    nearest_frontier_goal,
)
from edge_explorer.plan.goal_grid import ego_goal_cells
from edge_explorer.plan.goal_policy import GoalPolicyPlanner, goal_decision, weighted_scores
from edge_explorer.plan.predictive import choose_cluster
from edge_explorer.predict.predictor import thresholds_of
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.world.raster import PlanRaster

_WORKER: dict = {}


class TieBreakPlanner(GoalPolicyPlanner):
    """The expert, with its near-tied clusters ranked by the policy (module docstring)."""

    def __init__(self, policy, table, tie: float) -> None:
        super().__init__(policy, table=table)
        self.tie = tie
        self.decisions = self.ties = self.changed = 0

    def select_goal(self, view: View, pose: Pose) -> Goal | None:
        if not view.frontier.any():
            return None
        graph, cfg = view.graph, self.predictive
        start = graph.node_at(*pose[:2])
        if start < 0:
            return None
        cost, predecessors = graph.search([start])
        options, paths, gain = self.cluster_options(view, cost[0])
        pick = choose_cluster(paths, gain, cfg)
        if pick is None:
            observed = frontier_mask(view.maps.low) & ~self.dropped(view.maps)
            return nearest_frontier_goal(view, pose, observed, self.config.goal_radius_m)
        self.decisions += 1
        worth = gain >= cfg.min_gain_cells
        if worth[pick]:  # a near-fallback pick (a low-gain cluster on the way) stays the expert's
            near = paths + cfg.cost_offset_m <= (1 + self.tie) * (paths[pick] + cfg.cost_offset_m)
            tied = np.flatnonzero(worth & near)
            if len(tied) > 1:
                self.ties += 1
                fused = self.fused if self.fused is not None else view.maps.low
                choice = self.policy_choice(view, pose, fused, [options[i][0] for i in tied])
                if choice is not None and tied[choice] != pick:
                    self.changed += 1
                    pick = int(tied[choice])
        return self.cluster_goal(view, predecessors[0], *options[pick])

    def policy_choice(self, view: View, pose: Pose, fused: np.ndarray, nodes: list[int]) -> int | None:
        """Index into ``nodes`` of the one the policy scores highest, or None when it scores none of them."""
        decision = goal_decision(view, pose, fused, self.last_action, self.config.goal_radius_m)
        if not decision.options.mask.any():
            return None
        scores = weighted_scores(self.policy(decision.observation), decision.options, 0.0)
        grid = view.maps.low_grid
        cells = ego_goal_cells(view.graph.node_xy_m(nodes), pose, grid.origin_xy, grid.resolution_m)
        best = np.full(len(nodes), -np.inf)
        for k, (row, col) in enumerate(cells):
            window = scores[max(row - 1, 0) : row + 2, max(col - 1, 0) : col + 2]
            if window.size:
                best[k] = window.max()
        return int(np.argmax(best)) if np.isfinite(best).any() else None


def _init(args: argparse.Namespace) -> None:
    import torch

    torch.set_num_threads(1)
    _WORKER.update(args=args, predictor=bench.load_predictor(args.predictor), policy=bench.load_policy(args.policy))


def fly(raster: PlanRaster) -> tuple:
    """``expert_sweep.fly``'s row (plan, path at 95 %, collisions, steps) plus decisions, ties, changed picks."""
    args, predictor = _WORKER["args"], _WORKER["predictor"]
    max_steps = bench.BenchConfig().max_steps
    env = ExplorationEnv(
        [raster], EnvConfig(coverage_goal=1.0, max_steps=max_steps, thresholds=thresholds_of(predictor)), predictor
    )
    planner = TieBreakPlanner(_WORKER["policy"], env.table, args.tie)
    at_goal, collisions, steps_at_goal, _ = fly_run(env, planner, raster, max_steps)
    return raster.name, at_goal, collisions, steps_at_goal, planner.decisions, planner.ties, planner.changed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_sweep_args(parser)
    parser.add_argument("--tie", type=float, required=True, help="relative score margin that counts as a near-tie")
    args = parser.parse_args()
    runs = fly_sweep(args, fly, _init, (args,))
    paths = [r[1] for r in runs if r[1] is not None]
    decisions, ties, changed = (sum(r[k] for r in runs) for k in (4, 5, 6))
    print(
        f"{args.name}: mean path at 95 % {np.mean(paths):.2f} m, reached {len(paths)}/{len(runs)}, collisions "
        f"{sum(r[2] for r in runs)}; {decisions} decisions, {ties} near-ties, {changed} picks changed "
        f"-> runs/expert_sweep/{args.name}.json"
    )


if __name__ == "__main__":
    main()
