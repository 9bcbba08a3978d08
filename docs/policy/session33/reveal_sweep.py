"""Issue #21's mask says a goal that reveals nothing is invalid; the learned planner's mask only asks for a reachable
node near a fused frontier. This sweep masks such goals lazily at decision time and flies ``expert_sweep.py``'s val
runs with it (docs/policy/goal_policy.md, session 33):

    python docs/policy/session33/reveal_sweep.py MIN_GAIN --name s33_reveal1_drl40 --first 40 --count 96 \
        --planner drl --policy models/policy/policy.safetensors --workers 2

The policy's best valid cell is taken unless a view from its goal node shows fewer than MIN_GAIN cells that are
unknown in the fused map (the expert's gain, :func:`~edge_explorer.plan.predictive.visible_unknown`); then the next
best, up to :data:`TRIES` cells, else the first.
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import numpy as np

from edge_explorer.plan import goal_policy
from edge_explorer.plan.predictive import visible_unknown
from edge_explorer.world.grid import OCCUPIED, UNKNOWN

TRIES = 8
MIN_GAIN = int(sys.argv.pop(1))


def select_goal(self, view, pose):  # noqa: ANN001, ANN201 - GoalPolicyPlanner.select_goal's signature
    fused = self.fused if self.fused is not None else view.maps.low
    decision = goal_policy.goal_decision(view, pose, fused, self.last_action, self.config.goal_radius_m)
    if not decision.options.mask.any():
        return super(goal_policy.GoalPolicyPlanner, self).select_goal(view, pose)
    scores = goal_policy.weighted_scores(
        self.policy(decision.observation), decision.options, self.predictive.policy_cost_weight_per_m
    ).ravel()
    order = np.argsort(-scores, kind="stable")[:TRIES]
    order = order[np.isfinite(scores[order])]
    unknown, blocking = fused == UNKNOWN, fused == OCCUPIED
    for cell in order:
        node = int(decision.options.node.flat[cell])
        seen = visible_unknown(
            view.graph.node_xy_m([node])[0], unknown, blocking, view.maps.low_grid, self.predictive.sensor.range_m
        )
        if len(seen) >= MIN_GAIN:
            return goal_policy.goal_at_cell(view, decision, int(cell))
    return goal_policy.goal_at_cell(view, decision, int(order[0]))


goal_policy.GoalPolicyPlanner.select_goal = select_goal
sys.argv[0] = str(Path(__file__).parents[1] / "expert_sweep.py")
runpy.run_path(sys.argv[0], run_name="__main__")
