"""Goal-policy demonstrations, behaviour cloning and a flight of the cloned policy (edge_explorer.learn.goal_*)."""

import math

import numpy as np
import pytest
import torch

from edge_explorer.bench import explore as bench
from edge_explorer.learn.goal_demos import DemoConfig, fly_demo, load_demos, write_demos
from edge_explorer.learn.goal_net import GoalNet, GoalNetConfig, load_goal_net, save_goal_net
from edge_explorer.learn.train_goal_bc import BCConfig, batch_tensors, train
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan

TINY_NET = GoalNetConfig(encoder=(4, 4, 4, 4), decoder=(4, 4))


@pytest.fixture(scope="module")
def rooms():
    return rasterize(two_room_plan(), 0.05)


@pytest.fixture(scope="module")
def demo_dirs(rooms, tmp_path_factory):
    """Expert demonstrations on the two-room plan (no predictor: the fused map is the observed one)."""
    root = tmp_path_factory.mktemp("demos")
    for split, seeds in (("train", (1, 2, 3)), ("val", (4,))):
        (root / split).mkdir()
        records = [r for seed in seeds for r in fly_demo(rooms, None, seed, DemoConfig(max_steps=300))]
        write_demos(root / split / "shard-000000.npz", records)
        (root / split / "shard-000000.json").write_text("{}")
    return root


def test_every_label_is_a_valid_goal_cell(demo_dirs):
    demos = load_demos(demo_dirs / "train")
    assert len(demos) >= 3  # the expert decides several times on the way through the two rooms
    assert demos.mask.shape == (len(demos), GOAL_GRID_CELLS**2)
    assert demos.mask[np.arange(len(demos)), demos.label].all()
    assert demos.high.dtype == np.int8 and demos.high.shape[1:] == (237, 237)


def test_mirroring_flips_windows_goals_and_turns(demo_dirs):
    demos = load_demos(demo_dirs / "train")
    idx = np.arange(min(len(demos), 4))
    plain = batch_tensors(demos, idx, np.zeros(len(idx), bool))
    mirrored = batch_tensors(demos, idx, np.ones(len(idx), bool))
    torch.testing.assert_close(mirrored[1], plain[1].flip(-1))
    col = plain[4] % GOAL_GRID_CELLS
    assert (mirrored[4] % GOAL_GRID_CELLS == GOAL_GRID_CELLS - 1 - col).all()
    assert (mirrored[3][np.arange(len(idx)), mirrored[4]]).all()  # the mirrored label stays valid
    turned = plain[2][:, [0, 2, 1, 3, 5, 4]]
    torch.testing.assert_close(mirrored[2], turned)


def test_network_scores_every_goal_cell_and_round_trips(tmp_path):
    model = GoalNet(TINY_NET)
    codes = torch.zeros(2, 237, 237)
    logits, value = model(codes, codes, torch.zeros(2, 6))
    assert logits.shape == (2, GOAL_GRID_CELLS, GOAL_GRID_CELLS) and value.shape == (2,)
    save_goal_net(model, tmp_path / "g.safetensors")
    again = load_goal_net(tmp_path / "g.safetensors")
    torch.testing.assert_close(
        again(codes, codes, torch.zeros(2, 6))[0], model.eval()(codes, codes, torch.zeros(2, 6))[0]
    )


@pytest.mark.slow
def test_resume_equals_an_uninterrupted_run(demo_dirs, tmp_path):
    config = BCConfig(
        train_demos=str(demo_dirs / "train"),
        val_demos=str(demo_dirs / "val"),
        batch_size=2,
        total_steps=6,
        val_every_steps=3,
        checkpoint_every_steps=3,
        log_every_steps=1,
    )
    train(config, tmp_path / "whole", net=TINY_NET)
    train(config, tmp_path / "split", net=TINY_NET, stop_at_step=3)  # the session ends after step 3 …
    train(config, tmp_path / "split", resume=True, net=TINY_NET)  # … and the next one resumes the run
    whole = load_goal_net(tmp_path / "whole" / "checkpoint.safetensors").state_dict()
    split = load_goal_net(tmp_path / "split" / "checkpoint.safetensors").state_dict()
    for key in whole:
        torch.testing.assert_close(split[key], whole[key])


@pytest.mark.slow
def test_a_cloned_policy_flies_the_two_rooms_in_the_benchmark(demo_dirs, rooms, tmp_path):
    config = BCConfig(
        train_demos=str(demo_dirs / "train"), val_demos=str(demo_dirs / "val"), batch_size=4, total_steps=30
    )
    train(config, tmp_path / "bc", net=TINY_NET)
    policy = bench.load_policy(str(tmp_path / "bc" / "best.safetensors"))
    assert isinstance(policy, bench.GoalPolicyRef)
    spec = bench.RunSpec("drl", rooms.name, 0, 3, (1.0, 1.5, -math.pi / 2), 0.95, 400, None, "bc")
    record = bench.run_episode(rooms, spec, None, policy)
    assert record["ending"] == "goal" and record["collisions"] == 0  # goals reachable by construction
    assert record["path_at_coverage_m"] is not None
