"""Predictor training: TOML config, a 2-step run on a tiny dataset, exact resume, refusals."""

import json
from pathlib import Path

import pytest
from safetensors.torch import load_file

from edge_explorer.errors import EdgeExplorerError
from edge_explorer.learn.train_predictor import PredictorTrainConfig, learning_rate, load_config, train
from edge_explorer.learn.unet import load_unet


def _config(shard_dir, **overrides) -> PredictorTrainConfig:
    values = dict(
        train_data=str(shard_dir / "train"),
        val_data=str(shard_dir / "val"),
        channels=(4, 8),
        head_channels=2,
        batch_size=2,
        total_steps=2,
        warmup_steps=1,
        val_every_steps=2,
        val_samples=2,
        checkpoint_every_steps=1,
        log_every_steps=1,
    )
    return PredictorTrainConfig(**{**values, **overrides})


def test_default_config_file_loads():
    config = load_config("edge_explorer/learn/configs/predictor.toml")
    assert config.channels == (12, 24, 48, 96, 128) and config.exterior_weight == 0.1


@pytest.mark.parametrize("path", sorted(Path("edge_explorer/learn/configs").glob("predictor*.toml")), ids=str)
def test_every_bundled_predictor_config_loads(path):
    config = load_config(path)
    assert config.total_steps > config.warmup_steps and config.unet.channels == config.channels


def test_config_errors_name_the_key(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("batch_sise = 4\n")
    with pytest.raises(EdgeExplorerError, match="batch_sise"):
        load_config(path)
    path.write_text('batch_size = "4"\n')
    with pytest.raises(EdgeExplorerError, match="batch_size must be int"):
        load_config(path)
    path.write_text("wall_weight = 0\n")
    with pytest.raises(EdgeExplorerError, match="wall_weight > 0"):
        load_config(path)
    path.write_text("learning_rate = 1\nchannels = [4, 8]\n")
    assert load_config(path).learning_rate == 1.0 and load_config(path).channels == (4, 8)


def test_schedule_warms_up_then_decays_to_zero():
    config = PredictorTrainConfig(warmup_steps=10, total_steps=110, learning_rate=1.0)
    assert learning_rate(config, 0) == pytest.approx(0.1)
    assert learning_rate(config, 10) == pytest.approx(1.0)
    assert learning_rate(config, 60) == pytest.approx(0.5)
    assert learning_rate(config, 110) == pytest.approx(0.0)


def test_two_steps_in_one_go_equal_one_step_and_a_resume(shard_dir, tmp_path):
    config = _config(shard_dir)
    straight = train(config, tmp_path / "straight")
    assert straight.step == 2 and straight.samples == 4 and straight.last_val["step"] == 2
    split = tmp_path / "split"
    assert train(config, split, max_steps=1).step == 1
    with pytest.raises(EdgeExplorerError, match="--resume"):
        train(config, split)
    resumed = train(config, split, resume=True)
    assert resumed.step == 2
    a = load_file(str(tmp_path / "straight" / "checkpoint.safetensors"))
    b = load_file(str(split / "checkpoint.safetensors"))
    assert all(bool((a[k] == b[k]).all()) for k in a)
    state = json.loads((split / "state.json").read_text())
    assert state["step"] == 2 and "param_groups" in state
    assert not load_unet(split / "best.safetensors").config.batchnorm  # shipped folded
    assert (split / "train_log.csv").read_text().count("\n") == 3  # header + 2 steps


def test_quantization_aware_training_resumes_exactly_and_differs_from_plain(shard_dir, tmp_path):
    config = _config(shard_dir, quantization_aware=True)
    train(config, tmp_path / "straight")
    train(config, tmp_path / "split", max_steps=1)
    train(config, tmp_path / "split", resume=True)
    train(_config(shard_dir), tmp_path / "plain")
    a, b, plain = (load_file(str(tmp_path / run / "checkpoint.safetensors")) for run in ("straight", "split", "plain"))
    assert all(bool((a[k] == b[k]).all()) for k in a)
    assert any(not bool((a[k] == plain[k]).all()) for k in a)


def test_bfloat16_on_the_cpu_resumes_exactly_differs_from_fp32_and_says_so(shard_dir, tmp_path):
    config = _config(shard_dir)
    train(config, tmp_path / "straight", precision="bf16")
    train(config, tmp_path / "split", max_steps=1, precision="bf16")
    train(config, tmp_path / "split", resume=True, precision="bf16")
    train(config, tmp_path / "fp32", precision="fp32")
    a, b, fp32 = (load_file(str(tmp_path / run / "checkpoint.safetensors")) for run in ("straight", "split", "fp32"))
    assert all(bool((a[k] == b[k]).all()) for k in a)
    assert any(not bool((a[k] == fp32[k]).all()) for k in a)
    stretches = json.loads((tmp_path / "split" / "state.json").read_text())["stretches"]
    assert all("bfloat16 autocast" in s["hardware"] for s in stretches)
    assert "bfloat16" not in json.loads((tmp_path / "fp32" / "state.json").read_text())["stretches"][0]["hardware"]
    with pytest.raises(EdgeExplorerError, match="precision 'fp16'"):
        train(config, tmp_path / "bad", precision="fp16")


def test_loader_workers_build_the_same_batches_as_the_loop(shard_dir, tmp_path):
    config = _config(shard_dir, total_steps=3)
    train(config, tmp_path / "inline")
    train(config, tmp_path / "workers", loader_workers=2)
    a = load_file(str(tmp_path / "inline" / "checkpoint.safetensors"))
    b = load_file(str(tmp_path / "workers" / "checkpoint.safetensors"))
    assert all(bool((a[k] == b[k]).all()) for k in a)


def test_a_wall_time_box_stops_with_a_checkpoint_that_resumes(shard_dir, tmp_path):
    config = _config(shard_dir, total_steps=3, checkpoint_every_steps=100)
    boxed = train(config, tmp_path, max_minutes=1e-9)  # out of time after the first step
    assert boxed.step == 1 and json.loads((tmp_path / "state.json").read_text())["step"] == 1
    assert train(config, tmp_path, resume=True).step == 3


def test_a_resume_drops_log_rows_a_killed_stretch_wrote_after_its_checkpoint(shard_dir, tmp_path):
    config = _config(shard_dir, total_steps=3)
    train(config, tmp_path / "straight")
    train(config, tmp_path / "split", max_steps=1)
    with (tmp_path / "split" / "train_log.csv").open("a") as fh:
        fh.write("2,0,4,0.001,9.9,1.0\n")  # logged, then killed before the step-2 checkpoint
    train(config, tmp_path / "split", resume=True)
    straight, split = ((tmp_path / run / "train_log.csv").read_text().splitlines() for run in ("straight", "split"))
    assert [row.split(",")[0] for row in split] == [row.split(",")[0] for row in straight] == ["step", "1", "2", "3"]
    assert "9.9" not in "".join(split)


def test_resume_refuses_another_config(shard_dir, tmp_path):
    train(_config(shard_dir), tmp_path, max_steps=1)
    with pytest.raises(EdgeExplorerError, match="another config"):
        train(_config(shard_dir, learning_rate=1e-2), tmp_path, resume=True)
    with pytest.raises(EdgeExplorerError, match="nothing to resume"):
        train(_config(shard_dir), tmp_path / "new", resume=True)


def test_ship_copies_the_best_weights_with_a_card(shard_dir, tmp_path):
    from edge_explorer.backends.card import sha256_of
    from edge_explorer.learn.predictor_card import ship_predictor

    run = tmp_path / "run"
    train(_config(shard_dir), run)
    sha = sha256_of(run / "best.safetensors")
    report = {
        "model_sha256": sha,
        "plans": "x",
        "n_plans": 1,
        "explorer": "e",
        "seed": 0,
        "thresholds": {},
        "levels": {"0.98": {"f1": 0.95, "n": 1}},
    }
    (tmp_path / "eval.json").write_text(json.dumps(report))
    card = ship_predictor(run, tmp_path / "models", {"test": tmp_path / "eval.json"}, "edge-explorer train …")
    assert sha256_of(tmp_path / "models" / card["weights"]) == card["sha256"] == sha
    assert card["architecture"]["macs"] > 0 and card["training"]["steps"] == 2
    assert card["metrics"]["test"]["levels"]["0.98"]["f1"] == 0.95
    assert json.loads((tmp_path / "models" / "card.json").read_text())["sha256"] == sha
    assert "envelope_m" not in card  # learned on the 21 × 11 m plans: the default envelope
    whole = ship_predictor(run, tmp_path / "whole", {}, "", whole_floors=True)
    assert whole["envelope_m"] is None
    assert json.loads((tmp_path / "whole" / "card.json").read_text())["envelope_m"] is None
    (tmp_path / "eval.json").write_text(json.dumps({**report, "model_sha256": "0" * 64}))
    with pytest.raises(EdgeExplorerError, match="another model"):
        ship_predictor(run, tmp_path / "models", {"test": tmp_path / "eval.json"}, "")


def test_fine_tuning_starts_from_init_weights(shard_dir, tmp_path):
    first = tmp_path / "first"
    train(_config(shard_dir), first)
    tuned = _config(shard_dir, init_weights=str(first / "checkpoint.safetensors"), total_steps=1, learning_rate=1e-9)
    train(tuned, tmp_path / "tuned")
    fresh = _config(shard_dir, seed=1, total_steps=1, learning_rate=1e-9)
    train(fresh, tmp_path / "fresh")
    a, b, c = (load_file(str(tmp_path / run / "checkpoint.safetensors")) for run in ("first", "tuned", "fresh"))
    kernels = [k for k in a if a[k].ndim == 4]  # convolution weights (BatchNorm statistics move in any step)
    assert all(float((a[k] - b[k]).abs().max()) < 1e-6 for k in kernels)
    assert any(float((a[k] - c[k]).abs().max()) > 1e-3 for k in kernels)


def test_the_card_lists_every_stretch_back_through_init_weights(shard_dir, tmp_path):
    from edge_explorer.learn.predictor_card import training_stretches

    first = tmp_path / "first"
    train(_config(shard_dir), first, max_steps=1)
    train(_config(shard_dir), first, resume=True)  # two stretches of one run
    tuned = tmp_path / "tuned"
    train(_config(shard_dir, init_weights=str(first / "checkpoint.safetensors"), total_steps=1), tuned)
    stretches = training_stretches(tuned)
    assert [(s["run"], s["from_step"], s["to_step"]) for s in stretches] == [
        (str(first), 0, 1),
        (str(first), 1, 2),
        (str(tuned), 0, 1),
    ]
    assert all("CPU only" in s["hardware"] and s["samples"] == 2 for s in stretches)
