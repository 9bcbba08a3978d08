"""Goal-policy demonstrations, behaviour cloning and a flight of the cloned policy (edge_explorer.learn.goal_*)."""

import json
import math

import numpy as np
import pytest
import torch

from edge_explorer.bench import explore as bench
from edge_explorer.bench.summary import summarize
from edge_explorer.export import calibration, pipeline
from edge_explorer.export.recipe import load_recipe
from edge_explorer.learn.goal_card import ship_goal_policy
from edge_explorer.learn.goal_demos import DemoConfig, fly_demo, load_demos, write_demos
from edge_explorer.learn.goal_net import GoalNet, GoalNetConfig, TorchGoalPolicy, load_goal_net, save_goal_net
from edge_explorer.learn.train_goal_bc import BCConfig, DemoTensors, batch_tensors, train
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS
from edge_explorer.runtime.daemon import choose_models
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
    demos = DemoTensors.of(load_demos(demo_dirs / "train"))
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


def test_a_spent_wall_time_box_ends_the_call_with_a_checkpoint_that_resumes(demo_dirs, tmp_path):
    config = BCConfig(
        train_demos=str(demo_dirs / "train"), val_demos=str(demo_dirs / "val"), batch_size=2, total_steps=4
    )
    state = train(config, tmp_path / "box", net=TINY_NET, max_minutes=0.0)  # the box is spent after one step
    assert state["step"] == 1 and json.loads((tmp_path / "box" / "state.json").read_text())["step"] == 1
    assert train(config, tmp_path / "box", resume=True, net=TINY_NET)["step"] == 4


@pytest.mark.slow
def test_train_ship_export_and_fly_the_exported_policy_on_the_two_rooms(demo_dirs, rooms, tmp_path, monkeypatch):
    """The whole path of a goal policy, tiny: behaviour cloning → bench with the torch weights → ship (card, with the
    bench that flew them) → export to ONNX with its parity check (the int8 gates: tests/export) → the exported
    policy flies the benchmark and the daemon's model loader takes it as flight-ready."""
    config = BCConfig(
        train_demos=str(demo_dirs / "train"), val_demos=str(demo_dirs / "val"), batch_size=4, total_steps=30
    )
    train(config, tmp_path / "bc", net=TINY_NET)
    weights = tmp_path / "bc" / "best.safetensors"
    policy = bench.load_policy(str(weights))
    assert isinstance(policy, TorchGoalPolicy)
    spec = bench.RunSpec("drl", rooms.name, 0, 3, (1.0, 1.5, -math.pi / 2), 0.95, 400, None, str(weights))
    record = bench.run_episode(rooms, spec, None, policy)
    assert record["ending"] == "goal" and record["collisions"] == 0  # goals reachable by construction
    assert record["path_at_coverage_m"] is not None

    evaluation = tmp_path / "bench.json"
    summary = summarize([record], ["drl"])
    evaluation.write_text(json.dumps({"command": "test", "plans": rooms.name, "methods": ["drl"], "runs_per_plan": 1,
                                      "seed": 0, "paired": [], "config": {"policy": str(weights)},
                                      "summary": summary}))  # fmt: skip
    models = tmp_path / "models"
    card = ship_goal_policy(weights, [tmp_path / "bc"], models / "policy", evaluation, "test", tmp_path / "docs")
    assert card["flight_ready"]["ready"] and card["training"]["stages"][0]["kind"] == "bc"
    assert "CPU only" in card["training"]["hardware"][0]  # where the stage trained, from its own state
    assert card["architecture"]["macs"] > 0 and (tmp_path / "docs" / "learning_curves.png").is_file()

    monkeypatch.setattr(calibration, "val_rasters", lambda c: ([rooms] * c.plans, [rooms] * c.held_back_plans))
    (tmp_path / "quantize").mkdir()
    recipe_path = tmp_path / "quantize" / "policy.toml"
    recipe_path.write_text(
        'model = "policy"\ncheckpoint = "models/policy/policy.safetensors"\n[calibration]\nplans = 1\n'
        'held_back_plans = 1\nper_plan = 4\n[formats]\nproduce = ["onnx_fp32"]\n[gates]\n'
        "min_top1_agreement = 0.5\n[latency]\nrepeats = 2\n"
    )
    report = pipeline.run_export(load_recipe(recipe_path), models, log=lambda *_: None)
    assert report.passed, report.table()
    exported = bench.load_policy(str(models / "policy"))
    record = bench.run_episode(rooms, spec, None, exported)
    assert record["ending"] == "goal" and record["collisions"] == 0
    choice = choose_models(models, "auto", ("onnxruntime-cpu",))
    assert choice.policy is not None and choice.notes[0].startswith("planner: drl")


def test_a_workers_share_of_the_split_is_every_nth_plan_from_its_rank(tmp_path):
    from edge_explorer.learn.goal_demos import split_rasters
    from edge_explorer.world.dataset import generate_dataset

    generate_dataset(tmp_path, count=8, dataset_seed=5, split_fractions=(6, 1, 1), workers=1)
    every = [r.name for r in split_rasters(str(tmp_path), "train", 0, 6)]
    shares = [[r.name for r in split_rasters(str(tmp_path), "train", 0, 6, every=2, offset=k)] for k in (0, 1)]
    assert shares == [every[0::2], every[1::2]]
