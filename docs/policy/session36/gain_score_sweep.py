"""The view's gain as a term of the planner's ranking (issue #21, session 36; val only): every valid goal cell is
ranked by the policy's weighted score plus ``GAIN_WEIGHT`` × ln(1 + the unknown cells a view from it shows), then
the shipped rule (goals worth a look, the 10 m detour cap) picks from that ranking. Aimed at building C runs 6 and
9, where the policy flies 1.5 m to a view of 52 cells next to one 4 m away showing 508 (goal_policy.md, session 36).
Wraps the shipped ``best_cell_worth_a_look`` and flies ``expert_sweep.py``'s val runs::

    GAIN_WEIGHT=0.5 python docs/policy/session36/gain_score_sweep.py --name s36_g0.5_drl40 --first 40 --count 96 \\
        --planner drl --policy models/policy/policy.safetensors --workers 2
"""

from __future__ import annotations

import os
import runpy
import sys
from pathlib import Path

import numpy as np

from edge_explorer.plan import goal_policy

_shipped = goal_policy.best_cell_worth_a_look
GAIN_WEIGHT = float(os.environ.get("GAIN_WEIGHT", "0.5"))


def gain_ranked(view, decision, scores, fused_low, config) -> int:  # noqa: ANN001 - the shipped signature
    gains = goal_policy._Gains(view, decision, fused_low, config)
    flat = scores.ravel().copy()
    for cell in np.flatnonzero(np.isfinite(flat)):
        flat[cell] += GAIN_WEIGHT * np.log1p(gains.count(int(cell)))
    return _shipped(view, decision, flat.reshape(scores.shape), fused_low, config)


if __name__ == "__main__":
    goal_policy.best_cell_worth_a_look = gain_ranked
    sys.argv[0] = str(Path(__file__).parents[1] / "expert_sweep.py")
    runpy.run_path(sys.argv[0], run_name="__main__")
