"""Explain the learned planner's decisions in one benchmark run: the cells it ranked best and why (issue #21, s35).

Re-flies a drl+pred run of a ``bench explore`` JSON (as ``trace_drl.py``) and, at each decision whose path so far
lies in ``--from-m``..``--to-m``, prints the ten valid goal cells with the best weighted score (policy score −
weight × path cost) and the ten nearest ones: goal position, raw score, path cost, the view's unknown cells (the
worth-a-look gain) and which one was flown::

    PYTHONPATH=docs/policy/session35 python docs/policy/session35/explain_decision.py \
        docs/bench/policy_bundled.json D 6 --from-m 28 --to-m 29
"""

from __future__ import annotations

import argparse

import numpy as np
from trace_drl import raster_of, record_spec

from edge_explorer.bench import explore as bench
from edge_explorer.plan import goal_policy as gp
from edge_explorer.predict.predictor import thresholds_of
from edge_explorer.sim.env import EnvConfig, ExplorationEnv


class ExplainingPlanner(gp.GoalPolicyPlanner):
    """The shipped planner, printing its ranking when ``self.explain`` is set."""

    explain = False
    context = ""  # path and coverage now, printed with each explained decision

    def select_goal(self, view, pose):
        goal = super().select_goal(view, pose)
        if not self.explain or goal is None:
            return goal
        fused = self.fused if self.fused is not None else view.maps.low
        decision = gp.goal_decision(view, pose, fused, self.last_action, self.config.goal_radius_m)
        if not decision.options.mask.any():
            return goal
        raw = np.asarray(self.policy(decision.observation), dtype=np.float64).reshape(decision.options.mask.shape)
        weighted = gp.weighted_scores(raw, decision.options, self.predictive.policy_cost_weight_per_m)
        gains = gp._Gains(view, decision, fused, self.predictive)
        valid = np.flatnonzero(decision.options.mask)
        end_x, end_y = goal.path_xy_m[-1]
        flown_m = np.sum(np.hypot(*np.diff(goal.path_xy_m, axis=0).T))
        print(
            f"{self.context}: pose ({pose[0]:.1f}, {pose[1]:.1f}), {len(valid)} valid cells; "
            f"flown: ({end_x:.1f}, {end_y:.1f}) after {flown_m:.1f} m"
        )
        by_score = valid[np.argsort(-weighted.flat[valid])][:10]
        by_cost = valid[np.argsort(decision.options.cost_m.flat[valid])][:10]
        for name, cells in (("best weighted", by_score), ("nearest", by_cost)):
            print(f"   {name}:")
            for cell in cells:
                node = int(decision.options.node.flat[cell])
                x, y = view.graph.node_xy_m([node])[0]
                gains.worth_a_look(int(cell))
                cost_m = decision.options.cost_m.flat[cell]
                print(
                    f"     ({x:5.1f}, {y:5.1f}) raw {raw.flat[cell]:6.2f} cost {cost_m:5.1f} m "
                    f"weighted {weighted.flat[cell]:6.2f} gain {gains.cells[node]:4d}"
                )
        return goal


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bench_json")
    parser.add_argument("plan")
    parser.add_argument("run", type=int)
    parser.add_argument("--from-m", type=float, default=0.0)
    parser.add_argument("--to-m", type=float, default=1e9)
    parser.add_argument("--predictor", default="models/predictor")
    parser.add_argument("--policy", default="models/policy/policy.safetensors")
    args = parser.parse_args()
    spec = record_spec(args.bench_json, args.plan, args.run)
    raster = raster_of(spec["plan"])
    predictor = bench.load_predictor(args.predictor)
    config = EnvConfig(coverage_goal=1.0, max_steps=spec["max_steps"], thresholds=thresholds_of(predictor))
    env = ExplorationEnv([raster], config, predictor=predictor)
    planner = ExplainingPlanner(bench.load_policy(args.policy), table=env.table)
    planner.reset()
    _, info = env.reset(seed=spec["seed"], options={"start_pose": np.asarray(spec["start_pose"])})
    previous = 0
    while (info["coverage"] < 0.95 or info["correct_coverage"] < 0.95) and info["path_length_m"] <= args.to_m:
        planner.explain = args.from_m <= info["path_length_m"] <= args.to_m
        planner.context = f"path {info['path_length_m']:.1f} m, coverage {info['coverage']:.3f}"
        action = planner.act(env.maps, env.pose, previous, env.thresholded_low)
        if action is None:
            break
        _, _, _, _, info = env.step(action)
        previous = 0 if info["collided"] else action


if __name__ == "__main__":
    main()
