"""The goals-worth-a-look rule with the expert's near fallback (docs/policy/goal_policy.md, session 33): a goal the
policy ranks above the best goal worth a look is still flown when its path is shorter than ``near_fallback_ratio``
(0.3) × that goal's, as the expert flies a low-gain cluster on its way. Flies ``expert_sweep.py``'s val runs:

    python docs/policy/session33/near_sweep.py --name s33_near_drl40 --first 40 --count 96 \
        --planner drl --policy models/policy/policy.safetensors --workers 2
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import numpy as np

from edge_explorer.plan import goal_policy


def select_goal(self, view, pose):  # noqa: ANN001, ANN201 - GoalPolicyPlanner.select_goal's signature
    fused = self.fused if self.fused is not None else view.maps.low
    decision = goal_policy.goal_decision(view, pose, fused, self.last_action, self.config.goal_radius_m)
    if not decision.options.mask.any():
        return super(goal_policy.GoalPolicyPlanner, self).select_goal(view, pose)
    scores = goal_policy.weighted_scores(
        self.policy(decision.observation), decision.options, self.predictive.policy_cost_weight_per_m
    ).ravel()
    worth = goal_policy.best_cell_worth_a_look(view, decision, scores, fused, self.predictive)
    cost = decision.options.cost_m.ravel()
    preferred = np.flatnonzero(scores > scores[worth])
    near = preferred[cost[preferred] < self.predictive.near_fallback_ratio * cost[worth]]
    cell = int(near[np.argmax(scores[near])]) if len(near) else worth
    return goal_policy.goal_at_cell(view, decision, cell)


goal_policy.GoalPolicyPlanner.select_goal = select_goal
sys.argv[0] = str(Path(__file__).parents[1] / "expert_sweep.py")
runpy.run_path(sys.argv[0], run_name="__main__")
