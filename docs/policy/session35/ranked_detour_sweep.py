"""The detour cap generalised (issue #21, session 35; val only, not shipped): when the goal worth a look is a detour
of more than ``policy_max_detour_m`` from the policy's best-ranked cell, fly the best-ranked cell *that shows at least
``policy_detour_min_cells``* unknown cells and saves more than that detour — not only the top cell, as the shipped cap
does. Aimed at building D run 0, where the top cell shows 1 cell and the second, 2.8 m away, 21 (goal_policy.md,
session 35). Wraps the shipped ``best_cell_worth_a_look`` and flies ``expert_sweep.py``'s val runs::

    python docs/policy/session35/ranked_detour_sweep.py --name s35_rdetour_drl40 --first 40 --count 96 \\
        --planner drl --policy models/policy/policy.safetensors --workers 2
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import numpy as np

from edge_explorer.plan import goal_policy

_shipped = goal_policy.best_cell_worth_a_look


def ranked_detour(view, decision, scores, fused_low, config) -> int:  # noqa: ANN001 - the shipped signature
    cell = _shipped(view, decision, scores, fused_low, config)
    cost = decision.options.cost_m.ravel()
    flat = scores.ravel()
    order = np.argsort(-flat, kind="stable")
    order = order[np.isfinite(flat[order]) & (cost[order] < cost[cell] - config.policy_max_detour_m)]
    gains = goal_policy._Gains(view, decision, fused_low, config)
    for ranked in order:
        if flat[ranked] <= flat[cell]:
            break  # only cells the policy ranks above the rule's goal
        if gains.count(int(ranked)) >= config.policy_detour_min_cells:
            return int(ranked)
    return cell


if __name__ == "__main__":
    goal_policy.best_cell_worth_a_look = ranked_detour
    sys.argv[0] = str(Path(__file__).parents[1] / "expert_sweep.py")
    runpy.run_path(sys.argv[0], run_name="__main__")
