"""The predictive expert: fused frontiers, visible gain, a flight on the fused map (edge_explorer.plan.predictive)."""

import math

import numpy as np
import pytest

from edge_explorer.plan.predictive import (
    PredictiveConfig,
    PredictiveFrontier,
    choose_cluster,
    fused_frontier_mask,
    visible_unknown,
)
from edge_explorer.plan.registry import build_planner
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.world.grid import FREE, OCCUPIED, UNKNOWN, GridSpec
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan
from tests.plan.test_frontier import west_room_seen


def test_a_frontier_the_prediction_filled_is_no_target():
    observed = np.full((5, 8), UNKNOWN, dtype=np.int8)
    observed[:, :4] = FREE
    fused = observed.copy()
    assert fused_frontier_mask(observed, fused)[:, 3].all()  # the observed frontier, without a prediction
    fused[:2, 4:] = OCCUPIED  # the predictor claims the north-east: a wall
    fused[2:, 4:] = FREE  # … and free space south-east
    assert not fused_frontier_mask(observed, fused).any()
    fused[4, 6] = UNKNOWN  # one unsure cell, not next to an observed free one
    assert not fused_frontier_mask(observed, fused).any()
    with pytest.raises(ValueError, match="shape"):
        fused_frontier_mask(observed, fused[:, :4])


def test_open_prediction_keeps_a_corridor_mouth_the_prediction_only_began_to_fill():
    observed = np.full((5, 12), UNKNOWN, dtype=np.int8)
    observed[:, :3] = FREE
    fused = observed.copy()
    fused[:, 3:6] = FREE  # the predictor fills the first 0.6 m of the corridor; beyond it, unknown
    assert not fused_frontier_mask(observed, fused).any()  # no fused UNKNOWN cell next to an observed free one
    assert fused_frontier_mask(observed, fused, open_prediction=True)[:, 2].all()  # free cells lead to unknown
    assert not fused_frontier_mask(observed, fused, open_prediction=True)[:, :2].any()
    fused[:, 6] = OCCUPIED  # the predictor closes the corridor off with a wall: filled, no target
    assert not fused_frontier_mask(observed, fused, open_prediction=True).any()


def test_a_low_gain_cluster_on_the_way_is_flown_before_a_far_rich_one():
    paths_m = np.array([15.0, 3.0, 20.0])
    gains = np.array([200, 10, 400])  # the near cluster shows too little to be a target on its own
    strict = PredictiveConfig(cost_decay_per_m=0.0, near_fallback_ratio=0.0)
    assert choose_cluster(paths_m, gains, strict) == 0  # γ = 0: the nearest cluster worth a look
    assert choose_cluster(paths_m, gains, PredictiveConfig(near_fallback_ratio=0.3)) == 1  # 3 m < 0.3 × 15 m
    assert choose_cluster(np.array([15.0, 6.0]), np.array([200, 10]), PredictiveConfig(near_fallback_ratio=0.3)) == 0
    per_metre = PredictiveConfig(cost_decay_per_m=0.0, gain_exponent=1.0, near_fallback_ratio=0.0)
    assert choose_cluster(paths_m, gains, per_metre) == 2
    assert choose_cluster(np.array([9.0, 4.0]), np.array([5, 7]), strict) == 1  # none worth it: the nearest
    assert choose_cluster(np.zeros(0), np.zeros(0, dtype=int), strict) is None


def test_the_default_score_trades_a_factor_e_of_gain_per_metre_of_path():
    config = PredictiveConfig(cost_decay_per_m=1.0, near_fallback_ratio=0.0)  # score ln(1 + gain) − 1/m × path
    gains = np.array([40, 400])  # the far view shows ten times more: worth ln(401 / 41) ≈ 2.3 m of extra path
    assert choose_cluster(np.array([3.0, 5.0]), gains, config) == 1
    assert choose_cluster(np.array([3.0, 5.5]), gains, config) == 0
    assert choose_cluster(np.array([3.0, 5.5]), gains, PredictiveConfig(cost_decay_per_m=0.2)) == 1
    assert choose_cluster(np.array([3.0, 5.5]), np.array([20, 400]), config) == 1  # 20 cells are not worth a look
    with pytest.raises(ValueError, match="cost_decay_per_m"):
        PredictiveConfig(cost_decay_per_m=-1.0)


def test_gain_counts_unknown_cells_in_range_and_in_sight():
    grid = GridSpec((0.0, 0.0), 0.2, (21, 21))
    unknown = np.zeros(grid.shape, dtype=bool)
    unknown[10, 15:] = True  # six cells east of the viewpoint, 1.0–2.0 m away
    unknown[2, 10] = True  # one cell 1.6 m north
    blocking = np.zeros(grid.shape, dtype=bool)
    here = np.array(grid.center_of(10, 10), dtype=float)
    assert len(visible_unknown(here, unknown, blocking, grid, range_m=4.5)) == 7
    assert len(visible_unknown(here, unknown, blocking, grid, range_m=1.5)) == 3  # (10, 15) … (10, 17): 1.0–1.4 m
    blocking[9:12, 13] = True  # a wall between the viewpoint and the eastern cells
    seen = visible_unknown(here, unknown, blocking, grid, range_m=4.5)
    assert len(seen) == 1 and seen[0][1] < here[1]  # only the northern one remains


def test_goal_is_the_unseen_room_reached_through_observed_space():
    rooms = rasterize(two_room_plan(), 0.05)
    maps = west_room_seen(rooms)
    planner = PredictiveFrontier()
    pose = (1.0, 1.5, 0.0)
    view = planner.view(maps, pose, None)
    goal = planner.select_goal(view, pose)
    assert goal is not None
    assert view.traversable.contains_path(goal.path_xy_m)  # every path cell observed free with clearance
    assert goal.path_xy_m[-1, 0] > 1.8 and abs(math.cos(goal.yaw_rad)) > 0.5  # at the door, looking through it
    assert goal.yaw_rad < math.pi / 2 and goal.yaw_rad > -math.pi / 2  # … east, into the unseen room


def test_a_fully_predicted_map_falls_back_to_the_observed_frontier():
    rooms = rasterize(two_room_plan(), 0.05)
    maps = west_room_seen(rooms)
    fused = rooms.coarsened(0.2).truth_codes()  # a perfect predictor: nothing is unknown in the fused map
    fused[fused == UNKNOWN] = OCCUPIED
    planner = PredictiveFrontier()
    view = planner.view(maps, (1.0, 1.5, 0.0), fused)
    assert view.frontier.any()  # the observed frontier: the flight can still confirm the prediction


@pytest.mark.slow
def test_the_expert_explores_the_two_rooms_without_collision():
    rooms = rasterize(two_room_plan(), 0.05)
    env = ExplorationEnv([rooms], EnvConfig(coverage_goal=1.0, max_steps=400))
    _, info = env.reset(seed=3, options={"start_pose": (1.0, 1.5, -math.pi / 2)})
    planner = build_planner("predfrontier", env.table)
    assert isinstance(planner.local, PredictiveFrontier)
    previous = 0
    for _ in range(400):
        action = planner.act(env.maps, env.pose, previous, env.thresholded_low)
        if action is None or info["coverage"] >= 0.95:
            break
        _, _, _, _, info = env.step(action)
        assert not info["collided"]
        previous = action
    assert info["coverage"] >= 0.95  # the east room seen, through the door or from inside it
