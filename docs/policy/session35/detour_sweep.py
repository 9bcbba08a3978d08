"""The worth-a-look rule with a detour cap (issue #21, session 35; measured on val): the policy's best-ranked goal is
flown anyway, though a view from it shows fewer than ``min_gain_cells`` unknown cells, when the best goal worth a look
would cost more than ``--detour-m`` (default 10 m) more path and the ranked goal still shows ``--min-cells`` (default
10). Aimed at building D's runs 0 and 6, where the rule sent the vehicle 16 m away from a predicted corridor that it
flew back to later (``explain_decision.py``); unlike the expert's near fallback (a ratio of paths, ``near_sweep.py``),
short detours stay with the rule. Flies ``expert_sweep.py``'s val runs (other arguments are its own)::

    python docs/policy/session35/detour_sweep.py --name s35_detour10_drl40 --first 40 --count 96 \\
        --planner drl --policy models/policy/policy.safetensors --workers 2
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import numpy as np

from edge_explorer.plan import goal_policy

DETOUR_M = 10.0
MIN_CELLS = 10


def select_goal(self, view, pose):  # noqa: ANN001, ANN201 - GoalPolicyPlanner.select_goal's signature
    fused = self.fused if self.fused is not None else view.maps.low
    decision = goal_policy.goal_decision(view, pose, fused, self.last_action, self.config.goal_radius_m)
    if not decision.options.mask.any():
        return super(goal_policy.GoalPolicyPlanner, self).select_goal(view, pose)
    scores = goal_policy.weighted_scores(
        self.policy(decision.observation), decision.options, self.predictive.policy_cost_weight_per_m
    )
    cell = goal_policy.best_cell_worth_a_look(view, decision, scores, fused, self.predictive)
    top = int(np.argmax(scores))
    cost = decision.options.cost_m.ravel()
    if top != cell and cost[cell] - cost[top] > DETOUR_M:
        gains = goal_policy._Gains(view, decision, fused, self.predictive)
        gains.worth_a_look(top)
        if gains.cells[int(decision.options.node.flat[top])] >= MIN_CELLS:
            cell = top
    return goal_policy.goal_at_cell(view, decision, cell)


if __name__ == "__main__":
    for flag in ("--detour-m", "--min-cells"):
        if flag in sys.argv:
            at = sys.argv.index(flag)
            globals()["DETOUR_M" if flag == "--detour-m" else "MIN_CELLS"] = type(DETOUR_M)(sys.argv[at + 1])
            del sys.argv[at : at + 2]
    goal_policy.GoalPolicyPlanner.select_goal = select_goal
    sys.argv[0] = str(Path(__file__).parents[1] / "expert_sweep.py")
    runpy.run_path(sys.argv[0], run_name="__main__")
