"""Policy evaluation on the benchmark's runs, and shipping the policy with its card."""

import json

import pytest
import torch

from edge_explorer.backends.card import sha256_of
from edge_explorer.bench import explore as bench
from edge_explorer.errors import EdgeExplorerError
from edge_explorer.learn.eval_policy import compare_runs, fly_policy, path_ratios
from edge_explorer.learn.policy_card import count_macs, ship_policy
from edge_explorer.learn.policy_net import PolicyActor, PolicyNetConfig, save_policy
from edge_explorer.world.catalog import plan_to_raster
from tests.conftest import two_room_plan

TINY = PolicyNetConfig(conv_channels=(2, 4, 4), pi_layers=(8,), vf_layers=(8,))


class _Always(torch.nn.Module):
    """An actor that always answers ``action``."""

    def __init__(self, action: int) -> None:
        super().__init__()
        self.action = action

    def forward(self, high, thres, last_action):
        return torch.nn.functional.one_hot(torch.tensor([self.action]), 6).float()


@pytest.fixture(scope="module")
def raster():
    return plan_to_raster(two_room_plan())


def _spec(raster, max_steps=12):
    pose = bench.start_pose(raster, 0)
    return bench.RunSpec("drl", raster.name, 0, 5, pose, 0.95, max_steps, None)


def test_policy_run_is_a_benchmark_record(raster):
    record = fly_policy(_Always(2), raster, _spec(raster), None)  # turning on the spot: no path, no collision
    assert record["format"] == bench.RECORD_FORMAT and record["ending"] == "step_cap"
    assert record["steps"] == 12 and record["collisions"] == 0
    assert len(record["curves"]["coverage"]) == 13 and record["path_length_m"] < 0.5
    summary = bench.summarize(
        [record, {**record, "spec": {**record["spec"], "method": "frontier"}}], ["drl", "frontier"]
    )
    assert summary["all"]["drl"]["runs"] == 1


def test_flying_into_walls_counts_collisions(raster):
    record = fly_policy(_Always(3), raster, _spec(raster, max_steps=40), None)
    assert record["collisions"] > 0


def test_path_ratio():
    group = {"drl": {"path_at_coverage_m": {"avg": 30.0}}, "frontier": {"path_at_coverage_m": {"avg": 60.0}}}
    missing = {"drl": {"path_at_coverage_m": {"avg": None}}, "frontier": {"path_at_coverage_m": {"avg": 60.0}}}
    summary = {"plans": {"A": group, "B": missing}, "all": group}
    assert path_ratios(summary, ["drl", "frontier"]) == {"A": 0.5, "B": None, "all": 0.5}


def test_macs_of_a_known_network():
    actor = PolicyActor(TINY)
    # conv1 58²·2·6·64, conv2 28²·4·2·16, conv3 13²·4·4·9, linears (4·13²+6)·8 and 8·6
    expected = 58 * 58 * 2 * 6 * 64 + 28 * 28 * 4 * 2 * 16 + 13 * 13 * 4 * 4 * 9 + (4 * 169 + 6) * 8 + 8 * 6
    assert count_macs(actor) == expected


def _run_dir(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    save_policy(PolicyActor(TINY), TINY, run / "best.safetensors", {"stage": "bc"})
    config = {
        "collision_penalty": 10.0, "f1_weight": 100.0, "reward_scale": 0.05, "coverage_goal": 0.95, "max_steps": 500,
        "expert": "frontier", "expert_episodes": 2, "phase2_steps": 0, "threads": 1, "n_envs": 2,
    }  # fmt: skip
    (run / "config.json").write_text(json.dumps(config))
    state = {"stage": "done", "timesteps": 64, "wall_s": 36.0, "best_timesteps": 0, "bc": {"held_out_accuracy": 0.5}}
    (run / "state.json").write_text(json.dumps(state))
    (run / "eval.csv").write_text(
        "stage,timesteps,wall_s,episodes,success_rate,goal_rate,mean_path_success_m,mean_coverage,"
        "collisions_per_episode\ninit,0,1,2,0.0,0.0,,0.1,30.0\nbc,0,2,2,0.5,0.5,20.0,0.6,0.0\n"
    )
    (run / "bc.csv").write_text("epoch,train_nll,held_out_nll,held_out_accuracy\n1,1.2,1.3,0.5\n")
    return run


def test_ship_writes_weights_card_and_curves(tmp_path):
    run = _run_dir(tmp_path)
    card = ship_policy(run, tmp_path / "models", None, "edge-explorer train policy …", tmp_path / "docs")
    shipped = tmp_path / "models" / "policy.safetensors"
    assert card["sha256"] == sha256_of(shipped) == sha256_of(run / "best.safetensors")
    assert json.loads((tmp_path / "models" / "card.json").read_text())["training"]["best_stage"] == "bc"
    assert card["architecture"]["config"] == TINY.to_dict()
    assert (tmp_path / "docs" / "learning_curves.png").stat().st_size > 0
    assert (tmp_path / "docs" / "eval.csv").exists()
    assert card["training"]["val_evaluations"][1]["mean_coverage"] == 0.6

    card_path = tmp_path / "models" / "card.json"
    card_path.write_text(json.dumps({**card, "artifacts": {"policy_fp32.onnx": {}}}))  # what export adds
    again = ship_policy(run, tmp_path / "models", None, "", None)
    assert again["artifacts"] == {"policy_fp32.onnx": {}}  # same weights: kept


def test_ship_refuses_an_evaluation_of_other_weights(tmp_path):
    run = _run_dir(tmp_path)
    report = tmp_path / "eval.json"
    report.write_text(json.dumps({"model_sha256": "0" * 64}))
    with pytest.raises(EdgeExplorerError, match="another model"):
        ship_policy(run, tmp_path / "models", report, "", None)


def test_compare_runs_reports_bc_and_ppo_figures_of_each_run(tmp_path):
    plain = _run_dir(tmp_path)
    with (plain / "eval.csv").open("a") as fh:
        fh.write("phase1,64,32,2,0.0,0.0,,0.4,1.5\n")
    (plain / "progress.csv").write_text("time/fps,time/total_timesteps\n30,32\n25,64\n")
    figures = compare_runs({"plain": plain}, tmp_path / "curves.png", tmp_path / "curves.json")["plain"]
    assert figures["ppo_steps"] == 64 and figures["ppo_steps_per_s"] == 25.0
    assert figures["after_bc"]["mean_coverage"] == 0.6 and figures["after_bc"]["train_wall_s"] == 1.0
    assert figures["after_ppo"]["collisions_per_episode"] == 1.5 and figures["after_ppo"]["train_wall_s"] == 31.0
    assert json.loads((tmp_path / "curves.json").read_text())["runs"]["plain"]["ppo_steps"] == 64
    assert (tmp_path / "curves.png").stat().st_size > 0
    with pytest.raises(EdgeExplorerError, match="no eval.csv"):
        compare_runs({"none": tmp_path / "missing"}, tmp_path / "x.png", tmp_path / "x.json")
