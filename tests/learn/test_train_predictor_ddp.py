"""`train predictor` under torchrun (2 gloo processes on CPU): the single-process run's losses, resumable alone."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

import pytest

from edge_explorer.learn.train_predictor import load_config, train

STEPS = 4
# BatchNorm normalises over each rank's half of the batch (the one difference from one process, see learn/ddp.py);
# measured on this config: 2e-5 relative at step 1, 1.6e-3 at step 4 (one step costs the loss ~1 %).
RELATIVE_TOLERANCE = 5e-3


def losses(run: Path) -> list[float]:
    with (run / "train_log.csv").open(newline="") as fh:
        return [float(row["train_loss"]) for row in csv.DictReader(fh)]


@pytest.mark.slow
def test_two_processes_match_one_with_the_same_global_batch(shard_dir, tmp_path):
    config_path = tmp_path / "tiny.toml"
    config_path.write_text(
        f'train_data = "{shard_dir / "train"}"\nval_data = "{shard_dir / "val"}"\n'
        f"channels = [4, 8]\nhead_channels = 2\nbatch_size = 4\ntotal_steps = {STEPS}\nwarmup_steps = 1\n"
        f"val_every_steps = {STEPS}\nval_samples = 2\ncheckpoint_every_steps = 1\nlog_every_steps = 1\n"
    )
    config = load_config(config_path)
    single = train(config, tmp_path / "single")

    env = {k: v for k, v in os.environ.items() if k not in ("WORLD_SIZE", "RANK", "LOCAL_RANK")}
    torchrun = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2"]
    command = [*torchrun, "-m", "edge_explorer.cli", "train", "predictor", "--config", str(config_path)]
    ddp = tmp_path / "ddp"
    done = subprocess.run(
        [*command, "--out", str(ddp), "--max-steps", str(STEPS - 1)], env=env, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.count("step 3:") == 1  # rank 0 alone reports
    assert len(losses(ddp)) == STEPS - 1  # and alone logs

    resumed = train(config, ddp, resume=True)  # a torchrun checkpoint resumes in one process
    assert resumed.step == single.step == STEPS and resumed.samples == single.samples
    assert losses(ddp) == pytest.approx(losses(tmp_path / "single"), rel=RELATIVE_TOLERANCE)
