"""The goal-policy trainer's environment workers as Ray actors (edge_explorer.learn.ray_vec_env)."""

import math

import numpy as np
import pytest

from edge_explorer.learn.goal_env import GoalEnv
from edge_explorer.sim.env import EnvConfig
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan

pytest.importorskip("ray", reason="Ray is not installed (pip install -e '.[cluster]')")
START = {"start_pose": (1.0, 1.5, -math.pi / 2)}


def make_env() -> GoalEnv:
    return GoalEnv([rasterize(two_room_plan(), 0.05)], EnvConfig(max_steps=300))


def expert_actions(venv) -> np.ndarray:
    """Each env's expert goal (its first valid cell when the expert has none)."""
    masks = np.stack(venv.env_method("action_masks"))
    cells = venv.env_method("expert_action")
    return np.array([c if c is not None else int(np.flatnonzero(m)[0]) for c, m in zip(cells, masks, strict=True)])


@pytest.mark.slow
def test_ray_actors_step_like_the_in_process_envs(ray_cluster):
    from stable_baselines3.common.vec_env import DummyVecEnv

    from edge_explorer.learn.ray_vec_env import RayVecEnv

    local, remote = DummyVecEnv([make_env, make_env]), RayVecEnv([make_env, make_env], "auto")
    try:
        for venv in (local, remote):
            venv.seed(7)
            venv.set_options(START)
        obs_local, obs_remote = local.reset(), remote.reset()
        np.testing.assert_array_equal(obs_local["thres"], obs_remote["thres"])
        for _ in range(3):  # the same goals give the same transitions, episode ends and resets included
            actions = expert_actions(local)
            np.testing.assert_array_equal(actions, expert_actions(remote))
            a, b = local.step(actions), remote.step(actions)
            np.testing.assert_array_equal(a[0]["high"], b[0]["high"])
            np.testing.assert_allclose(a[1], b[1])
            np.testing.assert_array_equal(a[2], b[2])
        assert remote.get_attr("action_space")[0].n == local.action_space.n
    finally:
        local.close()
        remote.close()
