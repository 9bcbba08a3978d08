"""Training the map predictor: weighted BCE, AdamW, cosine schedule, checkpoints that resume exactly.

Read top to bottom, :func:`train` is the whole loop (CleanRL style): load the shards, build the U-Net, then for each
step take the next batch of a per-epoch permutation, augment, compute the loss, step AdamW, and every so often log,
validate and checkpoint.

Loss: per-cell BCE on the logits, weighted by :func:`edge_explorer.predict.encoding.loss_weights` — unobserved
interior cells count 1 (``wall_weight`` where the truth is occupied), unobserved exterior cells (target "occupied")
``exterior_weight``, observed cells
``observed_weight`` (default 0: the observation always overrides the prediction, so learning to copy it is wasted
capacity) — summed and divided by the batch's total weight. ``init_weights`` starts from another run's checkpoint
(fine-tuning); ``quantization_aware`` rounds every ReLU tensor to int8 levels in the loop
(:mod:`edge_explorer.learn.fake_quant`), for weights that survive the int8 export.

Validation (every ``val_every_steps``): weighted BCE and the paper's F1 (docs/design.md §7) of the observed map plus the
dynamically thresholded prediction (§5), over ``val_samples`` fixed samples of the val split, inside the ego window
(which holds the whole building). The model with the best :func:`selection_score` — the mean val F1 at 50–80 %,
80–95 % and ≥ 95 % coverage, so a model must be useful early and not only at the end, and the many low-coverage
samples (where every model scores low) do not decide — is kept as ``best.safetensors``.

Run folder ``OUT``::

    config.toml               the config this run was started with (a resume must use the same)
    checkpoint.safetensors    model weights (with BatchNorm) of the last checkpoint
    optimizer.safetensors     AdamW moments; its param groups live in state.json
    state.json                step, epoch, best val F1, samples seen, wall time, written last
    best.safetensors          the best model by selection_score (BatchNorm folded: the shippable form)
    train_log.csv, val_log.csv

Data order is a function of (seed, epoch) and augmentation of (seed, epoch, sample), so a resumed run continues
with the very batches the uninterrupted run would have seen. No pickles: tensors in safetensors, the rest in JSON.

Under ``torchrun`` (``WORLD_SIZE`` > 1) the same loop runs data-parallel (:mod:`edge_explorer.learn.ddp`): the config's
batch stays the global batch, each rank takes its share of it, the schedule and the files are the same, and rank 0
alone validates and writes; ``--resume`` works with any process count.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from edge_explorer.errors import EdgeExplorerError
from edge_explorer.learn import ddp, toml_config
from edge_explorer.learn.csv_log import append_csv_row, drop_rows_after
from edge_explorer.learn.fake_quant import attach_fake_quant
from edge_explorer.learn.hardware import hardware_description
from edge_explorer.learn.predictor_dataset import LossWeighting, PredictorDataset
from edge_explorer.learn.predictor_shards import load_shards, shard_paths
from edge_explorer.learn.unet import UNet, UNetConfig, save_unet
from edge_explorer.mapping.metrics import map_metrics
from edge_explorer.predict.thresholding import ThresholdConfig, thresholded_map
from edge_explorer.world.grid import UNKNOWN


@dataclass(frozen=True)
class PredictorTrainConfig:
    """Everything a training run depends on; loaded from TOML by :func:`load_config` (flat keys)."""

    train_data: str = "data/predictor/train"
    val_data: str = "data/predictor/val"
    channels: tuple[int, ...] = (12, 24, 48, 96, 128)
    head_channels: int = 8
    exterior_weight: float = 0.1
    observed_weight: float = 0.0
    wall_weight: float = 1.0  # unobserved interior OCCUPIED cells (walls) against 1 for free ones; 1 = unweighted
    augment: bool = True
    init_weights: str = ""  # a checkpoint.safetensors to start from (fine-tuning); "" = random initialisation
    quantization_aware: bool = False  # round every ReLU tensor to int8 levels in the loop (learn.fake_quant)
    batch_size: int = 16
    learning_rate: float = 2e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 200
    total_steps: int = 5000
    seed: int = 0
    threads: int = 1
    log_every_steps: int = 25
    val_every_steps: int = 500
    val_samples: int = 512
    checkpoint_every_steps: int = 100

    def __post_init__(self) -> None:
        positive = (
            "head_channels",
            "batch_size",
            "total_steps",
            "threads",
            "log_every_steps",
            "val_every_steps",
            "val_samples",
            "checkpoint_every_steps",
        )
        for name in positive:
            if getattr(self, name) < 1:
                raise EdgeExplorerError(f"config: {name} must be ≥ 1, got {getattr(self, name)}")
        if self.learning_rate <= 0 or self.weight_decay < 0 or self.warmup_steps < 0:
            raise EdgeExplorerError("config: learning_rate must be > 0, weight_decay and warmup_steps ≥ 0")
        if self.exterior_weight < 0 or self.observed_weight < 0 or self.wall_weight <= 0:
            raise EdgeExplorerError("config: exterior_weight and observed_weight must be ≥ 0, wall_weight > 0")

    @property
    def unet(self) -> UNetConfig:
        return UNetConfig(channels=self.channels, head_channels=self.head_channels)

    @property
    def weighting(self) -> LossWeighting:
        return LossWeighting(self.exterior_weight, self.observed_weight, self.wall_weight)

    def to_dict(self) -> dict:
        return {**dataclasses.asdict(self), "channels": list(self.channels)}


def config_from_dict(data: dict, source: str = "<config>") -> PredictorTrainConfig:
    """A config from flat TOML keys; unknown keys, wrong types and bad values are errors naming the key."""
    return toml_config.config_from_dict(PredictorTrainConfig, data, source)


def load_config(path: str | Path) -> PredictorTrainConfig:
    return toml_config.load_toml_config(PredictorTrainConfig, path)


def learning_rate(config: PredictorTrainConfig, step: int) -> float:
    """Linear warm-up to ``learning_rate``, then cosine decay to zero at ``total_steps``."""
    if step < config.warmup_steps:
        return config.learning_rate * (step + 1) / config.warmup_steps
    progress = (step - config.warmup_steps) / max(config.total_steps - config.warmup_steps, 1)
    return 0.5 * config.learning_rate * (1.0 + math.cos(math.pi * min(progress, 1.0)))


def weighted_bce_terms(
    logits: torch.Tensor, target: torch.Tensor, weight: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """(Σ w·BCE(σ(logits), target), Σ w) over the batch."""
    bce = F.binary_cross_entropy_with_logits(logits, target, reduction="none")
    return (weight * bce).sum(), weight.sum()


def weighted_bce(logits: torch.Tensor, target: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Σ w·BCE(σ(logits), target) / Σ w over the batch."""
    numerator, weight_sum = weighted_bce_terms(logits, target, weight)
    return numerator / weight_sum.clamp_min(1e-6)


def stacked(dataset: PredictorDataset, indices: list[int]) -> tuple[torch.Tensor, ...]:
    """(input, target, weight) of ``indices``, stacked on the CPU."""
    return tuple(torch.stack(column) for column in zip(*(dataset[i] for i in indices), strict=True))


def to_device(tensors: tuple[torch.Tensor, ...], device: str) -> tuple[torch.Tensor, ...]:
    """The tensors on ``device``, channels-last (faster convolutions on CPU and GPU)."""
    non_blocking = device == "cuda"
    return tuple(t.to(device, non_blocking=non_blocking).contiguous(memory_format=torch.channels_last) for t in tensors)


def batch(dataset: PredictorDataset, indices: list[int], device: str) -> tuple[torch.Tensor, ...]:
    """(input, target, weight) of ``indices`` on ``device``."""
    return to_device(stacked(dataset, indices), device)


def step_indices(config: PredictorTrainConfig, step: int, steps_per_epoch: int, set_size: int) -> tuple[int, list[int]]:
    """(epoch, sample indices) of training step ``step``: position ``step`` of the permutation of its epoch."""
    epoch, position = divmod(step, steps_per_epoch)
    order = torch.randperm(set_size, generator=torch.Generator().manual_seed(config.seed * 100_003 + epoch))
    return epoch, order[position * config.batch_size : (position + 1) * config.batch_size].tolist()


class StepBatches(torch.utils.data.Dataset):
    """Item ``k`` is the CPU batch of training step ``first_step + k`` — a pure function of the step, so batches
    built in DataLoader worker processes (``--loader-workers``, to keep a GPU fed) are the very batches the
    in-process loop builds, and a resumed run continues with them."""

    def __init__(
        self, dataset: PredictorDataset, config: PredictorTrainConfig, ranks: ddp.Ranks, first_step: int, stop_step: int
    ) -> None:
        self.dataset, self.config, self.ranks = dataset, config, ranks
        self.first_step, self.stop_step = first_step, stop_step
        self.steps_per_epoch = len(dataset) // config.batch_size

    def __len__(self) -> int:
        return self.stop_step - self.first_step

    def __getitem__(self, k: int) -> tuple[int, int, tuple[torch.Tensor, ...]]:
        step = self.first_step + k
        epoch, indices = step_indices(self.config, step, self.steps_per_epoch, len(self.dataset))
        self.dataset.set_epoch(epoch)
        return epoch, len(indices), stacked(self.dataset, self.ranks.shard(indices))


def step_batches(
    dataset: PredictorDataset, config: PredictorTrainConfig, ranks: ddp.Ranks, steps: range, workers: int, device: str
):
    """Iterate (epoch, global batch size, CPU tensors) for ``steps``, in-process or from ``workers`` processes."""
    source = StepBatches(dataset, config, ranks, steps.start, steps.stop)
    if workers == 0:
        return (source[k] for k in range(len(source)))
    return iter(
        torch.utils.data.DataLoader(
            source,
            batch_size=None,  # items are whole batches
            shuffle=False,
            num_workers=workers,
            pin_memory=device == "cuda",
            prefetch_factor=4,
            persistent_workers=False,
        )
    )


# ---- validation --------------------------------------------------------------------------------------------------
COVERAGE_BINS = (0.0, 0.5, 0.8, 0.95, 1.01)


@torch.no_grad()
def validate(model: UNet, dataset: PredictorDataset, indices: list[int], batch_size: int, device: str) -> dict:
    """Weighted BCE and F1 (observed + thresholded prediction, and observed only) over ``indices``."""
    model.eval()
    losses, f1, f1_observed, coverage = [], [], [], []
    thresholds = ThresholdConfig()
    for start in range(0, len(indices), batch_size):
        chunk = indices[start : start + batch_size]
        x, target, weight = batch(dataset, chunk, device)
        logits = model.logits(x)
        losses.append(weighted_bce(logits, target, weight).item())
        probabilities = torch.sigmoid(logits)[:, 0].cpu().numpy()
        for k, index in enumerate(chunk):
            observed, truth = dataset.windows(index)
            interior = truth != UNKNOWN
            area_m2 = float(dataset.store.observed_area_m2[index])
            thres = thresholded_map(probabilities[k], observed, area_m2, thresholds)
            f1.append(map_metrics(observed, truth, interior, thres).f1)
            observed_only = map_metrics(observed, truth, interior)
            f1_observed.append(observed_only.f1)
            coverage.append(observed_only.coverage)
    model.train()
    f1_arr, coverage_arr = np.array(f1), np.array(coverage)
    result = {
        "val_loss": float(np.mean(losses)),
        "val_f1": float(f1_arr.mean()),
        "val_f1_observed": float(np.mean(f1_observed)),
    }
    for lo, hi in zip(COVERAGE_BINS[:-1], COVERAGE_BINS[1:], strict=True):
        in_bin = (coverage_arr >= lo) & (coverage_arr < hi)
        result[f"val_f1_cov{lo:.2f}"] = float(f1_arr[in_bin].mean()) if in_bin.any() else None
    return result


SELECTION_BINS = ("val_f1_cov0.50", "val_f1_cov0.80", "val_f1_cov0.95")


def selection_score(val: dict) -> float:
    """The number that picks ``best.safetensors``: mean val F1 over the coverage bins from 50 % up."""
    scores = [val[key] for key in SELECTION_BINS if val.get(key) is not None]
    return float(np.mean(scores)) if scores else val["val_f1"]


# ---- checkpoints -------------------------------------------------------------------------------------------------
@dataclass
class TrainState:
    step: int = 0
    samples: int = 0  # training samples seen
    train_set_size: int = 0  # a resume must see the same data
    wall_s: float = 0.0
    best_score: float = -1.0  # selection_score of best.safetensors
    best_step: int = -1
    last_val: dict | None = None
    stretches: list[dict] = dataclasses.field(default_factory=list)  # one per train() call: steps, wall, hardware


def _replace_atomically(write, path: Path) -> None:
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    os.replace(tmp, path)


def save_checkpoint(out: Path, model: UNet, optimizer: torch.optim.Optimizer, state: TrainState) -> None:
    """Weights and AdamW moments as safetensors, then state.json (last, so it never points past the weights)."""
    from safetensors.torch import save_file

    opt = optimizer.state_dict()
    moments = {f"{pid}.{key}": v.detach().cpu().contiguous() for pid, s in opt["state"].items() for key, v in s.items()}
    _replace_atomically(lambda p: save_unet(model, p), out / "checkpoint.safetensors")
    _replace_atomically(lambda p: save_file(moments, str(p)), out / "optimizer.safetensors")
    payload = {**dataclasses.asdict(state), "param_groups": opt["param_groups"]}
    _replace_atomically(lambda p: p.write_text(json.dumps(payload, indent=1)), out / "state.json")


def load_checkpoint(out: Path, model: UNet, optimizer: torch.optim.Optimizer, device: str) -> TrainState:
    from safetensors.torch import load_file

    payload = json.loads((out / "state.json").read_text())
    param_groups = payload.pop("param_groups")
    if "best_val_f1" in payload:  # runs started before selection_score: their best was picked by overall val F1
        payload["best_score"] = payload.pop("best_val_f1")
    model.load_state_dict(load_file(str(out / "checkpoint.safetensors"), device=device))
    moments = load_file(str(out / "optimizer.safetensors"), device=device)
    per_param: dict[int, dict] = {}
    for name, tensor in moments.items():
        pid, key = name.split(".", 1)
        per_param.setdefault(int(pid), {})[key] = tensor
    optimizer.load_state_dict({"state": per_param, "param_groups": param_groups})
    return TrainState(**payload)


# ---- the loop ----------------------------------------------------------------------------------------------------
PRECISIONS = ("auto", "bf16", "fp32")  # the forward pass: bfloat16 autocast on CUDA only, always, never


def train(
    config: PredictorTrainConfig,
    out: str | Path,
    resume: bool = False,
    device: str = "cpu",
    config_path: str | Path | None = None,
    max_steps: int | None = None,
    loader_workers: int = 0,
    max_minutes: float | None = None,
    precision: str = "auto",
) -> TrainState:
    """Train (or, with ``resume``, continue training) the predictor into ``out``; returns the final state.

    ``max_steps`` stops after that many steps of this call and ``max_minutes`` after that much wall time of it
    (both checkpointed), for time-boxed sessions. ``loader_workers`` processes build the batches (the same
    batches; what keeps a GPU busy). ``precision`` "bf16" runs the forward pass in bfloat16 autocast (mixed precision;
    the weights, optimizer and loss stay float32), "fp32" does not, "auto" (default) does on CUDA only. On a CPU with
    native bfloat16 (AVX512-BF16 or AMX) "bf16" trains ~1.6x faster (docs/predictor/at_scale.md, session 29).
    Under torchrun every rank calls this; only rank 0 validates and writes into ``out``.
    """
    from tqdm import tqdm

    out = Path(out)
    if precision not in PRECISIONS:
        raise EdgeExplorerError(f"precision {precision!r}: choose one of {', '.join(PRECISIONS)}")
    bfloat16 = precision == "bf16" or (precision == "auto" and device == "cuda")
    if device == "cuda" and not torch.cuda.is_available():
        raise EdgeExplorerError("--device cuda: no CUDA device is available")
    ranks = ddp.init_from_env(device, config.batch_size)
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    out.mkdir(parents=True, exist_ok=True)
    saved_config = out / "config.json"
    if resume:
        if not (out / "state.json").exists():
            raise EdgeExplorerError(f"{out}: nothing to resume (no state.json); drop --resume to start a run")
        if config_from_dict(json.loads(saved_config.read_text()), str(saved_config)) != config:
            raise EdgeExplorerError(f"{out}: the run was started with another config ({saved_config}); use it")
    elif (out / "state.json").exists():
        raise EdgeExplorerError(f"{out} already holds a run; pass --resume to continue it or choose a new --out")
    elif ranks.is_main:
        saved_config.write_text(json.dumps(config.to_dict(), indent=1))
        if config_path is not None:
            shutil.copyfile(config_path, out / "config.toml")

    train_set = PredictorDataset(
        load_shards(shard_paths(config.train_data)), config.weighting, config.augment, config.seed
    )
    val_set = PredictorDataset(load_shards(shard_paths(config.val_data)), config.weighting)
    val_indices = np.linspace(0, len(val_set) - 1, min(config.val_samples, len(val_set))).astype(int).tolist()
    steps_per_epoch = len(train_set) // config.batch_size
    if steps_per_epoch == 0:
        raise EdgeExplorerError(f"{len(train_set)} training samples are fewer than one batch of {config.batch_size}")

    model = UNet(config.unet).to(device, memory_format=torch.channels_last)
    if config.init_weights and not resume:
        from safetensors.torch import load_file

        model.load_state_dict(load_file(config.init_weights, device=device))
    if config.quantization_aware:
        attach_fake_quant(model)  # for the whole run, validation included: the model is selected as int8 runs it
    optimizer = torch.optim.AdamW(model.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay)
    state = load_checkpoint(out, model, optimizer, device) if resume else TrainState(train_set_size=len(train_set))
    if resume and ranks.is_main:
        for log in ("train_log.csv", "val_log.csv"):
            drop_rows_after(out / log, state.step)  # rows of a stretch killed after its last checkpoint
    if state.train_set_size != len(train_set):
        raise EdgeExplorerError(
            f"{out}: the run trained on {state.train_set_size} samples, {config.train_data} now "
            f"holds {len(train_set)}; resume with the same data or start a new run"
        )
    model.train()
    net = ddp.data_parallel_logits(model, device) if ranks.distributed else model.logits
    stop_step = config.total_steps if max_steps is None else min(config.total_steps, state.step + max_steps)

    bar = tqdm(total=stop_step, initial=state.step, unit="step", desc="train predictor", disable=not ranks.is_main)
    running_loss, running_n = 0.0, 0
    t_start = t_last = time.perf_counter()
    first_step, first_wall_s = state.step, state.wall_s
    deadline = math.inf if max_minutes is None else t_start + 60.0 * max_minutes
    autocast = torch.autocast(device, dtype=torch.bfloat16, enabled=bfloat16)
    batches = step_batches(train_set, config, ranks, range(state.step, stop_step), loader_workers, device)
    for epoch, batch_size, tensors in batches:
        x, target, weight = to_device(tensors, device)
        for group in optimizer.param_groups:
            group["lr"] = learning_rate(config, state.step)
        with autocast:
            logits = net(x)
        logits = logits.float()
        if ranks.distributed:
            loss, loss_value = ddp.global_weighted_mean(*weighted_bce_terms(logits, target, weight), ranks)
        else:
            loss = weighted_bce(logits, target, weight)
            loss_value = loss.item()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()

        state.step += 1
        state.samples += batch_size
        now = time.perf_counter()
        state.wall_s += now - t_last
        t_last = now
        running_loss += loss_value
        running_n += 1
        bar.update(1)
        bar.set_postfix(loss=f"{loss_value:.4f}", epoch=epoch)
        if not ranks.is_main:
            continue  # the other ranks only compute gradients

        if state.step % config.log_every_steps == 0:
            append_csv_row(
                out / "train_log.csv",
                {
                    "step": state.step,
                    "epoch": epoch,
                    "samples": state.samples,
                    "lr": learning_rate(config, state.step - 1),
                    "train_loss": running_loss / running_n,
                    "wall_s": round(state.wall_s, 1),
                },
            )
            running_loss, running_n = 0.0, 0
        if state.step % config.val_every_steps == 0 or state.step == config.total_steps:
            val = validate(model, val_set, val_indices, config.batch_size, device)
            state.last_val = {"step": state.step, **val}
            append_csv_row(out / "val_log.csv", {"step": state.step, "samples": state.samples, **val})
            tqdm.write(
                f"step {state.step}: val loss {val['val_loss']:.4f}, F1 {val['val_f1']:.4f} "
                f"(observed only {val['val_f1_observed']:.4f})"
            )
            if selection_score(val) > state.best_score:
                state.best_score, state.best_step = selection_score(val), state.step
                _replace_atomically(lambda p: save_unet(model.fused(), p), out / "best.safetensors")
            t_last = time.perf_counter()  # validation time is not training time
        out_of_time = time.perf_counter() > deadline
        if state.step % config.checkpoint_every_steps == 0 or state.step == stop_step or out_of_time:
            save_checkpoint(out, model, optimizer, state)
        if out_of_time:
            break
    del batches  # stops the loader's workers when the wall-time box ended the loop early
    bar.close()
    if ranks.is_main and state.step > first_step:
        state.stretches.append(
            {
                "from_step": first_step,
                "to_step": state.step,
                "wall_s": round(state.wall_s - first_wall_s, 1),
                "hardware": hardware_description(device, loader_workers, config.threads, bfloat16),
                "processes": ranks.world_size,
            }
        )
        save_checkpoint(out, model, optimizer, state)
    ddp.finish(ranks)
    return state
