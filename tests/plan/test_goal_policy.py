"""The learned planner's choice of goal cell: the policy's score, less the path-cost weight, over valid cells only."""

from __future__ import annotations

import numpy as np
import pytest

from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS, GoalOptions
from edge_explorer.plan.goal_policy import GoalDecision, choose_cell
from edge_explorer.plan.predictive import PredictiveConfig

G = GOAL_GRID_CELLS


def _decision(valid: dict[int, float]) -> GoalDecision:
    """A decision whose valid flat cells are ``valid`` (cell → path cost in m)."""
    node = np.full((G, G), -1, np.int64)
    cost = np.full((G, G), np.inf)
    for i, (cell, cost_m) in enumerate(valid.items()):
        node.flat[cell], cost.flat[cell] = i, cost_m
    return GoalDecision({}, GoalOptions(node, cost), np.zeros(0, np.int32))


def _policy(scores: dict[int, float]):
    grid = np.zeros((G, G), np.float32)
    for cell, score in scores.items():
        grid.flat[cell] = score
    return lambda observation: grid


def test_without_a_cost_weight_the_best_valid_score_wins_and_a_masked_cell_never_does():
    decision = _decision({10: 20.0, 20: 2.0})
    policy = _policy({5: 9.0, 10: 3.0, 20: 2.0})  # cell 5 scores best but is masked
    assert choose_cell(policy, decision) == 10


def test_the_cost_weight_trades_score_for_path_length():
    decision = _decision({10: 20.0, 20: 2.0})
    policy = _policy({10: 3.0, 20: 2.0})
    assert choose_cell(policy, decision, cost_weight_per_m=0.05) == 10  # 3 − 1.0 > 2 − 0.1
    assert choose_cell(policy, decision, cost_weight_per_m=0.1) == 20  # 3 − 2.0 < 2 − 0.2


def test_a_negative_cost_weight_is_refused():
    with pytest.raises(ValueError, match="policy_cost_weight_per_m"):
        PredictiveConfig(policy_cost_weight_per_m=-0.1)
