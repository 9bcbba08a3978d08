"""The policy network: code encoding, extractor shapes, SB3 wiring, safetensors round trip of the actor."""

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO

from edge_explorer.errors import EdgeExplorerError
from edge_explorer.learn.policy_net import (
    MapEncoder,
    PolicyActor,
    PolicyFeatures,
    PolicyNetConfig,
    encode_codes,
    encode_codes_by_comparison,
    load_policy_module,
    read_metadata,
    save_policy,
    sb3_policy_kwargs,
)
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.world.catalog import plan_to_raster
from tests.conftest import two_room_plan

TINY = PolicyNetConfig(conv_channels=(4, 8, 8), pi_layers=(16,), vf_layers=(8,))


@pytest.fixture(scope="module")
def env() -> ExplorationEnv:
    return ExplorationEnv([plan_to_raster(two_room_plan())], EnvConfig(max_steps=20))


def test_codes_become_free_occupied_nonflight_channels():
    codes = torch.tensor([[[-1.0, 0.0, 1.0, 2.0]]])
    channels = encode_codes(codes)[0, :, 0]
    expected = torch.tensor([[1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=torch.float32)
    assert torch.equal(channels, expected)


def test_the_comparison_encoding_of_int8_codes_equals_the_relu_encoding():
    codes = torch.tensor([[[-1, 0, 1, 2]]], dtype=torch.int8)
    assert torch.equal(encode_codes_by_comparison(codes), encode_codes(codes.float()))
    both = encode_codes_by_comparison(codes, codes.flip(2))
    assert torch.equal(both, torch.cat([encode_codes(codes.float()), encode_codes(codes.flip(2).float())], dim=1))


def test_the_int8_code_export_view_answers_the_actors_logits():
    from edge_explorer.export.networks import policy_network

    torch.manual_seed(5)
    actor = PolicyActor(TINY).eval()
    network = policy_network(actor)
    assert network.tflite_source is not None and network.tflite_source.module is actor
    codes = torch.randint(-1, 3, (2, 1, 237, 237), dtype=torch.int8)
    last = torch.eye(6)[[3]]
    with torch.no_grad():
        expected = actor(codes[0].float(), codes[1].float(), last)
        assert torch.allclose(network.module(codes[0], codes[1], last), expected, atol=1e-6)
    assert [t.dtype for t in network.example()] == [torch.int8, torch.int8, torch.float32]


def test_default_extractor_flattens_small_and_appends_the_last_action(env):
    extractor = PolicyFeatures(env.observation_space, PolicyNetConfig().to_dict())
    assert extractor.features_dim == 64 * 13 * 13 + 6  # strides 4/2/2 on 237×237
    obs, _ = env.reset(seed=0)
    batch = {k: torch.as_tensor(np.stack([v, v])).float() for k, v in obs.items()}
    features = extractor(batch)
    assert features.shape == (2, extractor.features_dim)
    assert torch.equal(features[:, -6:], batch["last_action"])


def test_extractor_rejects_a_wrong_window(env):
    with pytest.raises(ValueError, match="expected"):
        PolicyFeatures(env.observation_space, {**TINY.to_dict(), "window_cells": 100})


def test_config_round_trips_and_rejects_unknown_keys():
    assert PolicyNetConfig.from_dict(TINY.to_dict()) == TINY
    with pytest.raises(ValueError, match="unknown"):
        PolicyNetConfig.from_dict({"conv_chanels": [1, 2, 3]})
    with pytest.raises(ValueError, match="three positive"):
        PolicyNetConfig(conv_strides=(4, 2))


def test_saved_sb3_actor_loads_with_the_same_logits(env, tmp_path):
    torch.manual_seed(0)
    model = PPO("MultiInputPolicy", env, policy_kwargs=sb3_policy_kwargs(TINY), n_steps=8, batch_size=8, seed=0)
    path = tmp_path / "policy.safetensors"
    save_policy(model.policy, TINY, path, {"note": "test"})
    actor = load_policy_module(path)
    assert isinstance(actor, PolicyActor) and not actor.training
    assert read_metadata(path)["note"] == "test"

    obs, _ = env.reset(seed=1)
    tensors, _ = model.policy.obs_to_tensor(obs)
    with torch.no_grad():
        expected = model.policy.get_distribution(tensors).distribution.logits
        raw = {k: torch.as_tensor(v, dtype=torch.float32)[None] for k, v in obs.items()}
        logits = actor(raw["high"], raw["thres"], raw["last_action"])
    assert logits.shape == (1, 6)
    # SB3 normalises logits (log-softmax); the argmax and the softmax agree
    assert torch.allclose(torch.softmax(logits, 1), torch.softmax(expected, 1), atol=1e-6)
    assert int(logits.argmax()) == int(model.predict(obs, deterministic=True)[0])


def test_actor_file_round_trip(tmp_path):
    torch.manual_seed(1)
    actor = PolicyActor(TINY).eval()
    path = tmp_path / "actor.safetensors"
    save_policy(actor, TINY, path)
    again = load_policy_module(path)
    x = torch.randint(-1, 3, (2, 237, 237)).float()
    last = torch.eye(6)[[0, 3]]
    with torch.no_grad():
        assert torch.equal(actor(x, x, last), again(x, x, last))


def test_loading_rejects_files_that_are_not_policies(tmp_path):
    from safetensors.torch import save_file

    other = tmp_path / "other.safetensors"
    save_file({"w": torch.zeros(1)}, str(other))
    with pytest.raises(EdgeExplorerError, match="not a policy"):
        load_policy_module(other)
    with pytest.raises(EdgeExplorerError, match="no such"):
        load_policy_module(tmp_path / "missing.safetensors")


def test_input_pool_keeps_single_occupied_and_nonflight_cells_visible():
    encoder = MapEncoder(PolicyNetConfig(conv_channels=(2, 2, 2), input_pool=2))
    codes = torch.full((1, 237, 237), -1.0)  # all free
    codes[0, 236, 236] = 1.0  # one occupied cell in the zero-padded last block
    codes[0, 10, 10], codes[0, 10, 11] = 2.0, 1.0  # non-flight next to occupied in one block
    channels = torch.cat([encode_codes(codes), encode_codes(torch.zeros(1, 237, 237))], dim=1)
    pooled = encoder.pool(channels)
    assert pooled.shape == (1, 6, 119, 119)
    assert pooled[0, :3, 118, 118].tolist() == [0, 1, 0]  # the padding reads as unknown, not as free
    assert pooled[0, :3, 5, 5].tolist() == [1, 1, 1]  # free, occupied and non-flight in one block: none hidden
    assert pooled[0, 1].sum() == 2 and pooled[0, 2].sum() == 1 and pooled[0, 3:].sum() == 0
    with pytest.raises(ValueError, match="input_pool"):
        PolicyNetConfig(input_pool=0)


def test_pooled_actor_has_the_same_keys_fewer_features_and_round_trips(tmp_path):
    pooled = PolicyNetConfig(conv_channels=(4, 8, 8), pi_layers=(16,), vf_layers=(8,), input_pool=2)
    torch.manual_seed(2)
    actor = PolicyActor(pooled).eval()
    assert actor.state_dict().keys() == PolicyActor(TINY).state_dict().keys()
    assert actor.features_extractor.features_dim == 8 * 6 * 6 + 6  # 119 → 28 → 13 → 6
    path = tmp_path / "pooled.safetensors"
    save_policy(actor, pooled, path)
    again = load_policy_module(path)
    assert again.config.input_pool == 2
    x = torch.randint(-1, 3, (2, 237, 237)).float()
    last = torch.eye(6)[[1, 4]]
    with torch.no_grad():
        assert torch.equal(actor(x, x, last), again(x, x, last))


@pytest.mark.slow
def test_pooled_actor_exports_to_onnx_with_the_same_logits(tmp_path):
    import onnxruntime as ort

    from edge_explorer.export.networks import policy_network
    from edge_explorer.export.onnx_formats import export_fp32

    torch.manual_seed(3)
    actor = PolicyActor(PolicyNetConfig(conv_channels=(4, 8, 8), pi_layers=(16,), input_pool=2)).eval()
    path = tmp_path / "policy.onnx"
    export_fp32(policy_network(actor), path)
    session = ort.InferenceSession(str(path))
    x = torch.randint(-1, 3, (1, 237, 237)).float()
    last = torch.eye(6)[[2]]
    feeds = {"high": x.numpy().astype(np.int8), "thres": x.flip(1).numpy().astype(np.int8), "last_action": last.numpy()}
    with torch.no_grad():
        expected = actor(x, x.flip(1), last).numpy()
    assert np.allclose(session.run(None, feeds)[0], expected, atol=1e-5)
