"""Goal selection as a gymnasium environment (edge_explorer.learn.goal_env)."""

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from edge_explorer.learn.goal_env import NUM_GOALS, GoalEnv
from edge_explorer.plan.predictive import PredictiveConfig
from edge_explorer.sim.env import EnvConfig
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan

START = {"start_pose": (1.0, 1.5, -math.pi / 2)}  # in the open, as the benchmark starts (0.5 m from the walls)


@pytest.fixture(scope="module")
def rooms():
    return rasterize(two_room_plan(), 0.05)


def test_the_expert_s_goals_explore_the_rooms_with_the_paper_s_reward(rooms):
    env = GoalEnv([rooms], EnvConfig(max_steps=400))
    observation, info = env.reset(seed=3, options=START)
    assert observation["thres"].shape == (237, 237) and env.action_space.n == NUM_GOALS
    total, decisions, terminated, truncated = 0.0, 0, False, False
    f1_start = info["f1"]
    while not (terminated or truncated):
        mask = env.action_masks()
        assert mask.any() and mask.shape == (NUM_GOALS,)
        cells = env.action_view_cells()  # what each goal's view shows: the mask keeps the ones worth a look
        worth = cells >= PredictiveConfig().min_gain_cells
        assert (mask == worth).all() if worth.any() else (cells[~mask] == 0).all()
        cell = env.expert_action()
        assert cell is not None  # the expert's goal is reachable; it may not be worth a look (its near fallback)
        path_before = info["path_length_m"]
        observation, reward, terminated, truncated, info = env.step(cell)
        assert info["goal_replaced"] == (not mask[cell])
        flown = info["path_length_m"] - path_before
        assert reward == pytest.approx(100.0 * (info["f1"] - f1_start) - flown - 10.0 * info["collisions"])
        f1_start = info["f1"]
        total += reward
        decisions += 1
    assert terminated and info["coverage"] >= 0.95 and decisions >= 2 and info["collisions"] == 0
    assert not env.action_masks().any() and not env.action_view_cells().any()


def test_a_masked_goal_is_replaced_by_the_nearest_valid_one(rooms):
    env = GoalEnv([rooms], EnvConfig(max_steps=400))
    env.reset(seed=3, options=START)
    invalid = int(np.flatnonzero(~env.action_masks())[0])
    *_, info = env.step(invalid)
    assert info["goal_replaced"] and info["collisions"] == 0
    with pytest.raises(gym.error.InvalidAction, match="outside"):
        env.step(NUM_GOALS)


def test_gymnasium_checker_accepts_the_env(rooms):
    check_env(GoalEnv([rooms], EnvConfig(max_steps=60)), skip_render_check=True)
