"""One planner for every stage: the training environment, the benchmark and the daemon fly the learned goal policy
through the same goal-planner loop, so a policy does in flight what it did in training and in the benchmark."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge_explorer.bench import explore
from edge_explorer.learn.goal_env import GoalEnv
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS as G
from edge_explorer.plan.goal_grid import GoalOptions
from edge_explorer.plan.goal_policy import GoalPolicyPlanner, weighted_scores, with_view_gain
from edge_explorer.plan.predictive import PredictiveConfig, PredictiveFrontier
from edge_explorer.plan.window import WindowedPlanner
from edge_explorer.runtime.daemon import Daemon, DaemonConfig
from edge_explorer.runtime.mavlink_link import LinkConfig, MavlinkLink
from edge_explorer.sim.env import EnvConfig
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan
from tests.plan.test_policy import nearest_first_scores

START = (1.0, 1.5, -math.pi / 2)


@pytest.fixture(scope="module")
def rooms():
    return rasterize(two_room_plan(), 0.05)


def policy(observation: dict[str, np.ndarray]) -> np.ndarray:
    return nearest_first_scores()


@pytest.mark.slow
def test_the_goal_env_and_the_benchmark_fly_the_same_policy_the_same_way(rooms):
    spec = explore.RunSpec("drl", rooms.name, 0, 7, START, 0.95, 400, None, "nearest")
    record = explore.run_episode(rooms, spec, None, policy)
    env = GoalEnv([rooms], EnvConfig(coverage_goal=0.95, max_steps=400))
    observation, info = env.reset(seed=7, options={"start_pose": START})
    decisions, done = 0, False
    while not done:
        options = GoalOptions(np.where(env.action_masks(), 0, -1).reshape(G, G), env.action_costs_m().reshape(G, G))
        config = PredictiveConfig()
        scores = weighted_scores(policy(observation), options, config.policy_cost_weight_per_m)
        scores = with_view_gain(scores, env.action_view_cells().reshape(G, G), config.policy_gain_weight)
        observation, _, terminated, truncated, info = env.step(int(np.argmax(scores)))
        decisions, done = decisions + 1, terminated or truncated
    assert record["ending"] == "goal" and terminated and decisions > 1
    assert info["steps"] == record["steps"] and info["path_length_m"] == pytest.approx(record["path_length_m"])


def test_the_daemon_explores_with_the_benchmark_s_goal_policy_planner(rooms):
    link = MavlinkLink(LinkConfig(connect="udpout:127.0.0.1:9"))
    runtime = type("Runtime", (), {"scores": staticmethod(policy)})()
    daemon = Daemon(DaemonConfig(), link, source=None, policy=runtime)  # type: ignore[arg-type]
    assert isinstance(daemon.frontier, WindowedPlanner)  # the hierarchy the benchmark flies too …
    assert type(daemon.frontier.local) is GoalPolicyPlanner and daemon.planner_name == "drl"  # … around the policy
    assert isinstance(daemon.frontier.local, PredictiveFrontier)  # the expert's view and loop, the policy's goals
    without = Daemon(DaemonConfig(exploration_planner="predfrontier"), link, source=None)  # type: ignore[arg-type]
    assert type(without.frontier.local) is PredictiveFrontier and without.planner_name == "predfrontier"
