"""PPO of the goal policy with MaskablePPO (edge_explorer.learn.train_goal_ppo) on a tiny generated dataset."""

import json

import numpy as np
import pytest
import torch

from edge_explorer.learn.goal_env import NUM_GOALS
from edge_explorer.learn.goal_net import GoalNet, load_goal_net, save_goal_net
from edge_explorer.learn.train_goal_ppo import GoalActorCritic, PPOConfig, train
from edge_explorer.world.dataset import generate_dataset
from tests.learn.test_goal_policy_training import TINY_NET


@pytest.fixture(scope="module")
def tiny_plans(tmp_path_factory):
    out = tmp_path_factory.mktemp("plans")
    generate_dataset(out, 4, 0, (2, 1, 1), workers=1)
    return out


def test_the_actor_critic_is_the_goal_network_itself():
    import gymnasium as gym

    from edge_explorer.sim.env import ExplorationEnv
    from edge_explorer.world.raster import rasterize
    from tests.conftest import two_room_plan

    space = ExplorationEnv([rasterize(two_room_plan(), 0.05)]).observation_space
    policy = GoalActorCritic(
        space, gym.spaces.Discrete(NUM_GOALS), lambda _: 1e-4, features_extractor_kwargs={"net_config": {}}
    )
    net = policy.goal_net
    obs = {"high": torch.zeros(1, 237, 237), "thres": torch.zeros(1, 237, 237), "last_action": torch.zeros(1, 6)}
    obs["thres"][0, 100:140, 100:140] = -1.0
    mask = np.zeros((1, NUM_GOALS), dtype=bool)
    mask[0, [5, 700, 1800]] = True
    dist = policy.get_distribution(obs, action_masks=mask)
    logits, value = net(obs["high"], obs["thres"], obs["last_action"])
    expected = torch.softmax(logits.flatten(1)[0, [5, 700, 1800]], 0)
    torch.testing.assert_close(dist.distribution.probs[0, [5, 700, 1800]], expected)
    torch.testing.assert_close(policy.predict_values(obs)[:, 0], value)


@pytest.mark.slow
def test_ppo_trains_checkpoints_and_resumes(tiny_plans, tmp_path):
    init = tmp_path / "bc.safetensors"
    save_goal_net(GoalNet(TINY_NET), init)
    config = PPOConfig(
        init_weights=str(init),
        plans=str(tiny_plans),
        train_plans=2,
        val_first=0,
        predictor="",
        n_envs=1,
        n_steps=4,
        batch_size=4,
        n_epochs=1,
        total_decisions=4,
        checkpoint_every=4,
        eval_every=4,
        eval_plans=1,
        max_steps=150,
    )
    assert train(config, tmp_path / "run") >= 4
    run = tmp_path / "run"
    assert (run / "checkpoint.zip").exists() and (run / "best.safetensors").exists()
    assert json.loads((run / "state.json").read_text())["decisions"] >= 4
    assert "successes" in (run / "val_log.csv").read_text()
    resumed = PPOConfig(**{**config.__dict__, "total_decisions": 8})
    assert train(resumed, run, resume=True) >= 8
    assert load_goal_net(run / "latest.safetensors").config == TINY_NET


@pytest.mark.slow
def test_ppo_collects_its_rollouts_from_ray_actors(tiny_plans, tmp_path, ray_cluster):
    config = PPOConfig(
        plans=str(tiny_plans),
        train_plans=2,
        val_first=0,
        predictor="",
        n_envs=2,
        n_steps=2,
        batch_size=4,
        n_epochs=1,
        total_decisions=4,
        checkpoint_every=4,
        eval_every=1000,
        max_steps=150,
    )
    assert train(config, tmp_path / "ray", ray="auto") >= 4
    assert (tmp_path / "ray" / "latest.safetensors").exists()
