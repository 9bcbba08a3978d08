"""Policy training: config validation, expert demonstrations, the reward wrapper, a tiny end-to-end run + resume."""

import json

import numpy as np
import pytest
import torch

from edge_explorer.errors import EdgeExplorerError
from edge_explorer.learn.policy_net import load_policy_module
from edge_explorer.learn.train_policy import (
    Demonstrations,
    PolicyTrainConfig,
    TrainingWrapper,
    config_from_dict,
    discounted_returns,
    fly_expert,
    load_config,
    train,
)
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.world.catalog import plan_to_raster
from edge_explorer.world.plan import FloorPlan, Rect
from tests.conftest import two_room_plan

TINY = {
    "train_plans": 2,
    "n_envs": 1,  # in-process: no worker start-up in a unit test
    "val_plans": 1,
    "conv_channels": [2, 4, 4],
    "pi_layers": [8],
    "vf_layers": [8],
    "expert_episodes": 2,
    "bc_epochs": 1,
    "bc_holdout": 0.5,
    "max_steps": 20,
    "phase1_steps": 64,
    "n_steps": 16,
    "batch_size": 16,
    "n_epochs": 1,
    "eval_every_steps": 32,
    "eval_episodes": 1,
    "checkpoint_every_steps": 32,
}


def test_shipped_config_loads():
    config = load_config("edge_explorer/learn/configs/policy.toml")
    assert config.expert == "frontier" and config.n_envs == 2


def test_pooled_configs_differ_from_the_shipped_one_only_in_their_levers():
    base = load_config("edge_explorer/learn/configs/policy.toml").to_dict()
    pool2 = {"input_pool", "curriculum_steps", "phase1_steps", "eval_every_steps", "checkpoint_every_steps"}
    for name, levers in (("policy-pool2", pool2), ("policy-pool2-w500", pool2 | {"f1_weight"})):
        config = load_config(f"edge_explorer/learn/configs/{name}.toml")
        assert {k for k, v in config.to_dict().items() if base[k] != v} == levers
        assert config.net_config.input_pool == 2


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"phase1_step": 10}, "unknown key"),
        ({"n_envs": "2"}, "n_envs must be int"),
        ({"conv_channels": [8, 16]}, "three positive"),
        ({"expert": "oracle"}, "expert must be one of"),
        ({"n_envs": 0}, "n_envs must be ≥ 1"),
        ({"anneal_start_t_f_max": 0.5, "anneal_start_t_o": 0.4}, "t_f_max ≤ t_o"),
        ({"coverage_goal": 1.5}, "coverage_goal"),
        ({"pi_layers": [8.5]}, "list of integers"),
    ],
)
def test_bad_configs_are_one_line_errors(data, message):
    with pytest.raises(EdgeExplorerError, match=message):
        config_from_dict(data, "policy.toml")


def test_missing_and_malformed_config_files(tmp_path):
    with pytest.raises(EdgeExplorerError, match="no such config"):
        load_config(tmp_path / "none.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("n_envs = = 2\n")
    with pytest.raises(EdgeExplorerError, match="not valid TOML"):
        load_config(bad)


def test_integers_are_accepted_for_float_keys():
    assert config_from_dict({"learning_rate": 1}).learning_rate == 1.0


def test_discounted_returns():
    assert np.allclose(discounted_returns(np.array([1.0, 0.0, 2.0]), 0.5), [1.5, 1.0, 2.0])


def test_wrapper_scales_reward_and_counts_collisions():
    raster = plan_to_raster(two_room_plan())
    wrapped = TrainingWrapper(ExplorationEnv([raster], EnvConfig(motion_noise=False)), reward_scale=0.1)
    bare = ExplorationEnv([raster], EnvConfig(motion_noise=False))
    wrapped.reset(seed=3)
    bare.reset(seed=3)
    collisions = 0
    for _ in range(15):  # fly straight ahead: into a wall sooner or later
        _, r_wrapped, *_, info = wrapped.step(3)
        _, r_bare, *_, info_bare = bare.step(3)
        collisions += int(info_bare["collided"])
        assert r_wrapped == pytest.approx(0.1 * r_bare)
        assert info["collisions"] == collisions
    assert collisions > 0


def test_curriculum_fraction_grows_linearly_to_all_plans():
    config = config_from_dict({"curriculum_steps": 100, "curriculum_start_fraction": 0.2})
    assert [config.curriculum_fraction(t) for t in (0, 50, 100, 1000)] == pytest.approx([0.2, 0.6, 1.0, 1.0])
    assert config_from_dict({}).curriculum_fraction(0) == 1.0  # off by default
    with pytest.raises(EdgeExplorerError, match="curriculum_start_fraction"):
        config_from_dict({"curriculum_start_fraction": 0.0})


def test_curriculum_draws_the_smallest_plans_first():
    big = plan_to_raster(two_room_plan(name="big"))
    walls = (Rect(0.0, 0.0, 2.0, 0.1), Rect(0.0, 1.4, 2.0, 1.5), Rect(0.0, 0.0, 0.1, 1.5), Rect(1.9, 0.0, 2.0, 1.5))
    small = plan_to_raster(FloorPlan("small", ((0.0, 0.0), (2.0, 0.0), (2.0, 1.5), (0.0, 1.5)), walls))
    wrapped = TrainingWrapper(ExplorationEnv([big, small], EnvConfig(max_steps=5)), reward_scale=1.0, seed=0)
    assert wrapped.by_area.tolist() == [1, 0]
    wrapped.set_curriculum(0.5)

    def plan_after_reset(**kwargs) -> str:
        wrapped.reset(**kwargs)
        return wrapped.step(0)[-1]["plan"]

    assert {plan_after_reset(seed=k) for k in range(6)} == {"small"}
    wrapped.set_curriculum(1.0)
    assert {plan_after_reset() for _ in range(20)} == {"small", "big"}
    wrapped.set_curriculum(0.5)
    assert plan_after_reset(options={"plan_index": 0}) == "big"  # an explicit plan wins over the curriculum


def test_expert_episode_records_what_the_policy_sees(tmp_path):
    episode = fly_expert(two_room_plan(), "frontier", EnvConfig(max_steps=25), seed=0)
    n = len(episode["action"])
    assert 0 < n <= 25
    assert episode["high"].shape == (n, 237, 237) and episode["high"].dtype == np.int8
    assert episode["last_action"][0] == 0  # hover before the first step
    assert np.array_equal(episode["last_action"][1:], episode["action"][:-1])
    assert set(np.unique(episode["action"])) <= set(range(6))
    np.savez(tmp_path / "episode-00000.npz", **episode)
    demos = Demonstrations.load([tmp_path / "episode-00000.npz"], gamma=0.9, reward_scale=0.5)
    assert np.allclose(demos.returns, discounted_returns(episode["reward"] * 0.5, 0.9))
    obs, action, returns = demos.batch(np.arange(min(n, 4)), "cpu")
    assert obs["last_action"].shape == (min(n, 4), 6) and action.dtype.is_floating_point is False


@pytest.mark.slow
def test_tiny_run_trains_resumes_and_refuses_to_overwrite(tmp_path):
    config = config_from_dict(TINY)
    out = tmp_path / "run"
    state = train(config, out)
    assert state.stage == "done" and state.timesteps >= 64
    stages = [row.split(",")[0] for row in (out / "eval.csv").read_text().splitlines()[1:]]
    assert stages[:2] == ["init", "bc"] and "phase1" in stages
    assert (out / "checkpoint.zip").exists() and (out / "bc.csv").exists() and (out / "progress.csv").exists()
    assert len(list((out / "expert").glob("episode-*.npz"))) == 2
    actor = load_policy_module(out / "best.safetensors")
    assert actor.config.conv_channels == (2, 4, 4)

    with pytest.raises(EdgeExplorerError, match="already holds a run"):
        train(config, out)
    longer = config_from_dict({**TINY, "phase1_steps": 96})
    with pytest.raises(EdgeExplorerError, match="another config"):
        train(longer, out, resume=True)
    (out / "config.json").write_text(json.dumps(longer.to_dict()))
    state = json.loads((out / "state.json").read_text())
    state["stage"] = "phase1"  # the longer run's phase 1 is not finished: resume goes on from the checkpoint
    (out / "state.json").write_text(json.dumps(state))
    resumed = train(longer, out, resume=True)
    assert resumed.stage == "done" and resumed.timesteps >= 96
    assert len(list(out.glob("progress-until-*.csv"))) == 1  # the first call's log survives the resume


def test_resume_without_a_run_is_an_error(tmp_path):
    with pytest.raises(EdgeExplorerError, match="nothing to resume"):
        train(PolicyTrainConfig(), tmp_path, resume=True)


@pytest.mark.slow
def test_phase2_flies_with_the_predictor_and_anneals_the_thresholds(tmp_path):
    import csv

    from edge_explorer.learn.unet import UNet, UNetConfig, save_unet

    torch.manual_seed(0)
    weights = tmp_path / "predictor.safetensors"
    save_unet(UNet(UNetConfig(channels=(2, 4, 4), head_channels=2)).eval(), weights)
    phases = {"expert": "none", "phase1_steps": 32, "phase2_steps": 64, "predictor": str(weights)}
    state = train(config_from_dict({**TINY, **phases}), tmp_path / "run")
    assert state.stage == "done" and state.timesteps >= 96
    with (tmp_path / "run" / "progress.csv").open() as fh:
        rows = [r for r in csv.DictReader(fh) if r.get("train/t_f_max")]
    t_f = [float(r["train/t_f_max"]) for r in rows]
    t_o = [float(r["train/t_o"]) for r in rows]
    assert t_f == sorted(t_f) and t_f[-1] > t_f[0] >= 0.001
    assert t_o == sorted(t_o, reverse=True) and t_o[-1] < t_o[0] <= 0.999


def test_phase2_without_a_predictor_fails_before_training(tmp_path):
    config = config_from_dict({**TINY, "phase2_steps": 10, "predictor": str(tmp_path / "none.safetensors")})
    with pytest.raises(EdgeExplorerError, match="no such file"):
        train(config, tmp_path / "run")
