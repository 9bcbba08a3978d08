"""The learned planner's choice of goal cell: the policy's score, less the path-cost weight, over valid cells only."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS, GoalOptions
from edge_explorer.plan.goal_policy import GoalDecision, GoalPolicyPlanner, choose_cell
from edge_explorer.plan.predictive import PredictiveConfig
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan
from tests.plan.test_policy import nearest_first_scores

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


def test_the_planner_flies_a_cost_weighted_policy_to_full_coverage():
    rooms = rasterize(two_room_plan(), 0.05)
    env = ExplorationEnv([rooms], EnvConfig(coverage_goal=1.0, max_steps=400))
    planner = GoalPolicyPlanner(
        lambda o: nearest_first_scores(), PredictiveConfig(policy_cost_weight_per_m=0.5), env.table
    )
    planner.reset()
    _, info = env.reset(seed=7, options={"start_pose": (1.0, 1.5, -math.pi / 2)})
    previous, collisions = 0, 0
    while info["coverage"] < 0.95 and info["steps"] < 400:
        action = planner.act(env.maps, env.pose, previous, env.thresholded_low)
        assert action is not None
        _, _, _, _, info = env.step(action)
        collisions += int(info["collided"])
        previous = action
    assert info["coverage"] >= 0.95 and collisions == 0
