"""Average checkpoints of one training run (stochastic weight averaging, Izmailov et al. 2018) and refresh the
BatchNorm statistics, so a run still at a high learning rate can be scored as if it had been decayed
(docs/predictor/at_scale.md, session 33).

The long host run (``runs/predictor_host_wide``) overwrites ``checkpoint.safetensors`` every 250 steps; copies taken
along the way (``runs/s33/ckpts/step_*.safetensors``) are averaged parameter by parameter. BatchNorm's running means
and variances of an average are not the average of the running statistics, so they are recomputed as SWA does
(``torch.optim.swa_utils.update_bn``: a cumulative average over ``--bn-batches`` training batches, in train mode,
without gradients). The result is a ``save_unet`` file that ``f1_bound.py collect --model`` scores::

    python docs/predictor/session33/average_checkpoints.py runs/s33/ckpts/step_2[4-9]*.safetensors \
        --config edge_explorer/learn/configs/predictor_host_wide.toml --out runs/s33/swa.safetensors
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from edge_explorer.learn.predictor_dataset import PredictorDataset
from edge_explorer.learn.predictor_shards import load_shards, shard_paths
from edge_explorer.learn.train_predictor import load_config, stacked
from edge_explorer.learn.unet import load_unet, save_unet


def average(paths: list[Path]) -> torch.nn.Module:
    """The first checkpoint's model with every floating-point tensor replaced by the mean over ``paths``."""
    models = [load_unet(p) for p in paths]
    states = [m.state_dict() for m in models]
    mean = {
        key: torch.stack([s[key] for s in states]).mean(0) if value.is_floating_point() else value
        for key, value in states[0].items()
    }
    models[0].load_state_dict(mean)
    return models[0]


@torch.no_grad()
def refresh_batchnorm(model: torch.nn.Module, dataset: PredictorDataset, batches: int, batch_size: int) -> None:
    """Recompute every BatchNorm's running statistics as a cumulative average over ``batches`` random batches."""
    norms = [m for m in model.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    for norm in norms:
        norm.reset_running_stats()
        norm.momentum = None  # cumulative moving average
    model.train()
    rng = np.random.default_rng(0)
    for _ in tqdm(range(batches), desc="BatchNorm statistics"):
        indices = rng.choice(len(dataset), batch_size, replace=False).tolist()
        inputs = stacked(dataset, indices)[0].contiguous(memory_format=torch.channels_last)
        model(inputs)
    model.eval()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", type=Path, nargs="+")
    parser.add_argument("--config", type=Path, required=True, help="the run's training config (its train data)")
    parser.add_argument("--bn-batches", type=int, default=100)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    config = load_config(args.config)
    model = average(sorted(args.checkpoints)).to(memory_format=torch.channels_last)
    dataset = PredictorDataset(load_shards(shard_paths(config.train_data)), config.weighting, config.augment, 1)
    refresh_batchnorm(model, dataset, args.bn_batches, config.batch_size)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_unet(model, args.out)
    count = len(args.checkpoints)
    print(f"{count} checkpoints averaged, BatchNorm refreshed on {args.bn_batches} batches → {args.out}")


if __name__ == "__main__":
    main()
