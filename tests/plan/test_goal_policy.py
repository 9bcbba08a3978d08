"""The learned planner's choice of goal cell: the policy's score, less the path-cost weight, over valid cells only,
among the goals worth a look."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge_explorer.plan.frontier import Goal
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS, GoalOptions
from edge_explorer.plan.goal_policy import (
    GoalDecision,
    GoalPolicyPlanner,
    best_cell_worth_a_look,
    frontier_piece,
    goal_at_cell,
    goal_decision,
    nearest_goals,
    weighted_scores,
    worth_a_look,
)
from edge_explorer.plan.predictive import PredictiveConfig, visible_unknown
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.world.grid import OCCUPIED, UNKNOWN
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


def choose_cell(policy, decision: GoalDecision, cost_weight_per_m: float = 0.0) -> int:
    """The network's masked argmax (before the planner keeps to goals worth a look)."""
    return int(np.argmax(weighted_scores(policy(decision.observation), decision.options, cost_weight_per_m)))


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


def test_on_a_whole_floor_the_planner_chooses_only_among_goals_near_the_nearest():
    # crossing the window for a large view left the near rooms for a second pass along the corridor
    options = _decision({10: 4.0, 20: 15.0, 30: 19.5, 40: 30.0}).options
    near = nearest_goals(options, 15.0)
    assert set(np.flatnonzero(near.mask)) == {10, 20}  # 19.5 m is 15.5 m more than the nearest's 4 m
    np.testing.assert_array_equal(near.cost_m.flat[[10, 20]], [4.0, 15.0])
    assert np.isinf(near.cost_m.flat[30]) and near.node.flat[30] == -1
    assert nearest_goals(options, math.inf) is options  # off in the paper's envelope
    policy = _policy({10: 1.0, 40: 9.0})  # the far goal scores best, but is out of reach of the rule
    assert choose_cell(policy, GoalDecision({}, near, np.zeros(0, np.int32))) == 10


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


class _OnItsOwnThread:
    """A concurrent policy: scores on a thread of its own, counting what it was asked where."""

    def __init__(self, scores) -> None:  # noqa: ANN001 - a scoring callable
        from concurrent.futures import ThreadPoolExecutor

        self.scores, self.pool, self.calls, self.submitted = scores, ThreadPoolExecutor(1), 0, 0

    def __call__(self, observation):  # noqa: ANN001, ANN204 - the GoalPolicy signature
        self.calls += 1
        return self.scores(observation)

    def submit(self, observation):  # noqa: ANN001, ANN201
        self.submitted += 1
        return self.pool.submit(self.scores, observation)


def test_a_policy_that_scores_on_its_own_thread_flies_the_same_actions():
    """A ConcurrentGoalPolicy scores every goal decision through submit (while the options are searched), never
    inline, and the flight is action for action the plain policy's."""
    from edge_explorer.plan.goal_policy import ConcurrentGoalPolicy

    rooms = rasterize(two_room_plan(), 0.05)
    actions = []
    concurrent = _OnItsOwnThread(lambda o: nearest_first_scores())
    assert isinstance(concurrent, ConcurrentGoalPolicy) and not isinstance(lambda o: None, ConcurrentGoalPolicy)
    for policy in (lambda o: nearest_first_scores(), concurrent):
        env = ExplorationEnv([rooms], EnvConfig(coverage_goal=1.0, max_steps=120))
        planner = GoalPolicyPlanner(policy, PredictiveConfig(policy_cost_weight_per_m=0.5), env.table)
        planner.reset()
        _, info = env.reset(seed=7, options={"start_pose": (1.0, 1.5, -math.pi / 2)})
        flown, previous = [], 0
        for _ in range(120):
            action = planner.act(env.maps, env.pose, previous, env.thresholded_low)
            if action is None:
                break
            env.step(action)
            flown.append(action)
            previous = action
        actions.append(flown)
    assert actions[0] == actions[1] and len(actions[0]) > 20
    assert concurrent.submitted > 0 and concurrent.calls == 0


def _real_decision():
    """A decision of the two-room plan at its start, with the planner's view and the observed map as fused map."""
    rooms = rasterize(two_room_plan(), 0.05)
    env = ExplorationEnv([rooms], EnvConfig(coverage_goal=1.0, max_steps=50))
    env.reset(seed=7, options={"start_pose": (1.0, 1.5, -math.pi / 2)})
    planner = GoalPolicyPlanner(lambda o: nearest_first_scores(), table=env.table)
    planner.reset()
    view = planner.view(env.maps, env.pose)
    decision = goal_decision(view, env.pose, env.maps.low, 0, planner.config.goal_radius_m)
    return view, decision, env.maps.low


def test_a_frontier_piece_is_the_connected_frontier_near_the_targets():
    frontier = np.zeros((8, 30), dtype=bool)
    frontier[2, :] = True  # a strip of 30 cells
    frontier[6, :5] = True  # another one, not connected to it
    piece = frontier_piece(frontier, np.array([2 * 30 + 0]), radius_cells=10.0)
    assert piece[2, :11].all() and not piece[2, 11:].any()  # connected, and only within the radius
    assert not piece[6].any()  # near, but a separate piece of frontier


def test_goals_stuck_again_and_again_at_one_spot_give_up_the_frontier_they_were_after():
    # in a 0.75 m slot the follower found no safe motion and failed goal after goal a few cells further along one
    # frontier strip, for 500 steps (kthwhole_50010535_PLAN1, session 54)
    view, decision, _ = _real_decision()
    planner = GoalPolicyPlanner(lambda o: nearest_first_scores(), PredictiveConfig(stuck_failures=3))
    planner.reset()
    assert not planner.dropped(view.maps).any()  # nothing dropped yet (as a view starts the flight's record)
    cell = int(np.flatnonzero(decision.options.mask)[0])
    chosen = goal_at_cell(view, decision, cell)
    goal = Goal(chosen.path_xy_m, chosen.yaw_rad, chosen.target_cells[:1])  # one cell: its failure drops 3 × 3
    piece = frontier_piece(view.frontier, goal.target_cells, 5.0 / view.maps.low_grid.resolution_m)
    for k, pose in enumerate([(1.0, 1.5, 0.0), (3.0, 1.5, 0.0), (3.5, 1.5, 0.0), (3.0, 2.0, 0.0)]):
        planner.on_stuck(goal, view, pose)
        dropped = planner.dropped(view.maps)
        assert dropped[piece].all() == (k == 3)  # the third failure within 1 m of (3.0, 1.5) drops the piece
    assert piece.sum() > 9  # more than a failure's own drop


def _view_cells(view, decision, fused, cell: int) -> np.ndarray:  # noqa: ANN001 - the fixture's objects
    """The unknown cells a view from goal cell ``cell``'s node shows: the expert's gain of that goal."""
    return visible_unknown(
        view.graph.node_xy_m([int(decision.options.node.flat[cell])])[0],
        fused == UNKNOWN,
        fused == OCCUPIED,
        view.maps.low_grid,
        PredictiveConfig().sensor.range_m,
    )


def test_a_goal_that_is_not_worth_a_look_loses_to_the_best_one_that_is():
    view, decision, fused = _real_decision()
    valid = np.flatnonzero(decision.options.mask)
    gains = {int(c): len(_view_cells(view, decision, fused, int(c))) for c in valid}
    low, high = min(valid, key=gains.get), max(valid, key=gains.get)
    assert gains[low] < gains[high]
    config = PredictiveConfig(min_gain_cells=gains[high], policy_gain_weight=0.0)
    scores = np.full(G * G, -np.inf)
    scores[valid] = 0.0
    scores[low], scores[high] = 2.0, 1.0  # the policy prefers the goal that shows less
    assert best_cell_worth_a_look(view, decision, scores.reshape(G, G), fused, config) == high
    mask = worth_a_look(view, decision, fused, config)
    assert mask.flat[high] and not mask.flat[low]
    # nothing worth a look: every valid goal stays valid and the policy's best wins
    none = PredictiveConfig(min_gain_cells=10_000, policy_gain_weight=0.0)
    assert (worth_a_look(view, decision, fused, none) == decision.options.mask).all()
    assert best_cell_worth_a_look(view, decision, scores.reshape(G, G), fused, none) == low


@pytest.mark.parametrize("gain_weight", [0.0, 2.0])
def test_the_lazy_choice_is_the_argmax_over_the_goals_worth_a_look(gain_weight: float):
    view, decision, fused = _real_decision()
    config = PredictiveConfig(policy_max_detour_m=math.inf, policy_gain_weight=gain_weight)
    mask = worth_a_look(view, decision, fused, config)
    bonus = np.zeros(G * G)
    for cell in np.flatnonzero(decision.options.mask):
        bonus[cell] = gain_weight * math.log1p(len(_view_cells(view, decision, fused, int(cell))))
    rng = np.random.default_rng(0)
    for _ in range(20):
        scores = np.where(decision.options.mask, rng.normal(size=(G, G)), -np.inf)
        expected = int(np.argmax(np.where(mask, scores + bonus.reshape(G, G), -np.inf)))
        assert best_cell_worth_a_look(view, decision, scores, fused, config) == expected


def test_the_best_ranked_goal_is_kept_when_the_one_worth_a_look_is_a_long_detour():
    view, decision, fused = _real_decision()
    valid = [int(c) for c in np.flatnonzero(decision.options.mask)]
    gains = {c: len(_view_cells(view, decision, fused, c)) for c in valid}
    cost = decision.options.cost_m.ravel()
    near, far = min(
        ((a, b) for a in valid for b in valid if gains[a] < gains[b] and cost[a] < cost[b]),
        key=lambda pair: cost[pair[0]] - cost[pair[1]],  # the longest detour the fixture offers
    )
    detour_m = float(cost[far] - cost[near])
    scores = np.full(G * G, -np.inf)
    scores[valid] = 0.0
    scores[near], scores[far] = 2.0, 1.0  # the policy ranks the near goal first; only the far one is worth a look
    scores = scores.reshape(G, G)
    rule = dict(min_gain_cells=gains[far], policy_detour_min_cells=gains[near], policy_gain_weight=0.0)
    capped = PredictiveConfig(**rule, policy_max_detour_m=0.5 * detour_m)
    assert best_cell_worth_a_look(view, decision, scores, fused, capped) == near
    uncapped = PredictiveConfig(**rule, policy_max_detour_m=detour_m)  # a detour up to the cap is flown
    assert best_cell_worth_a_look(view, decision, scores, fused, uncapped) == far
    blind = PredictiveConfig(
        min_gain_cells=gains[far],
        policy_max_detour_m=0.5 * detour_m,
        policy_detour_min_cells=gains[near] + 1,
        policy_gain_weight=0.0,
    )  # the near goal shows too little even for the cap
    assert best_cell_worth_a_look(view, decision, scores, fused, blind) == far


def test_the_view_gain_term_lets_a_much_larger_view_outrank_a_better_scored_goal():
    view, decision, fused = _real_decision()
    valid = [int(c) for c in np.flatnonzero(decision.options.mask)]
    gains = {c: len(_view_cells(view, decision, fused, c)) for c in valid}
    small, large = min(valid, key=gains.get), max(valid, key=gains.get)
    margin = math.log1p(gains[large]) - math.log1p(gains[small])
    assert margin > 0
    scores = np.full(G * G, -np.inf)
    scores[valid] = -10.0
    scores[small], scores[large] = 1.0, 0.0  # the policy prefers the smaller view by 1
    scores = scores.reshape(G, G)
    rule = dict(min_gain_cells=0, policy_max_detour_m=math.inf)
    for weight, expected in ((0.0, small), (0.5 / margin, small), (2.0 / margin, large)):
        config = PredictiveConfig(**rule, policy_gain_weight=weight)
        assert best_cell_worth_a_look(view, decision, scores, fused, config) == expected, weight
    with pytest.raises(ValueError, match="policy_gain_weight"):
        PredictiveConfig(policy_gain_weight=-1.0)
