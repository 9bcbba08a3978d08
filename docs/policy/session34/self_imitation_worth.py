"""Self-imitation under the worth-a-look rule (issue #21, session 34).

Session 24's recipe (``session24/self_imitation.py``: greedy once and ``--samples`` sampled flights per train plan,
the best sampled flight's decisions kept where it is ≥ ``--margin`` m shorter) with the planner the product flies
since session 33: the greedy flight takes the best cell worth a look (``best_cell_worth_a_look``), a sampled flight
samples the softmax of the weighted scores over the cells worth a look (``worth_a_look``), and each decision is
recorded with that mask — the mask ``GoalEnv.action_masks`` gives and the choice the product makes among. The policy
was self-imitated (session 24) before the rule existed; one round under it asks whether the rule's own mistakes
(session 33: C and D crossed late) are learnable. Same arguments and outputs as the session-24 script::

    python docs/policy/session34/self_imitation_worth.py --first 6000 --count 300 --samples 4 --temperature 0.5 \\
        --margin 1.0 --policy models/policy/policy.safetensors --out runs/s34/si/train
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "session24"))
import self_imitation  # noqa: E402

from edge_explorer.plan.follow import Pose  # noqa: E402
from edge_explorer.plan.frontier import Goal, View  # noqa: E402
from edge_explorer.plan.goal_policy import (  # noqa: E402
    GoalPolicyPlanner,
    best_cell_worth_a_look,
    goal_at_cell,
    goal_decision,
    weighted_scores,
    worth_a_look,
)


class WorthRecordingPlanner(self_imitation.RecordingPolicyPlanner):
    """The product's goal choice (greedy) or a sample of the policy's softmax over the cells worth a look."""

    def select_goal(self, view: View, pose: Pose) -> Goal | None:
        fused = self.fused if self.fused is not None else view.maps.low
        decision = goal_decision(view, pose, fused, self.last_action, self.config.goal_radius_m)
        if not decision.options.mask.any():
            return GoalPolicyPlanner.select_goal(self, view, pose)  # the expert's fallbacks
        scores = weighted_scores(
            self.policy(decision.observation), decision.options, self.predictive.policy_cost_weight_per_m
        )
        if self.rng is None:
            cell = best_cell_worth_a_look(view, decision, scores, fused, self.predictive)
            mask = decision.options.flat_mask()  # greedy flights' records are never kept
        else:
            mask = worth_a_look(view, decision, fused, self.predictive).ravel()
            flat = np.where(mask, scores.ravel(), -np.inf)
            z = (flat - flat.max()) / self.temperature
            p = np.exp(z)
            cell = int(self.rng.choice(len(p), p=p / p.sum()))
        o = decision.observation
        self.records.append((o["high"], o["thres"], self.last_action, mask, cell))
        return goal_at_cell(view, decision, cell)


self_imitation.RecordingPolicyPlanner = WorthRecordingPlanner  # the workers are forked after this line

if __name__ == "__main__":
    self_imitation.main()
