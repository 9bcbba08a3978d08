"""Behaviour cloning of the goal policy on the expert's labelled decisions (:mod:`edge_explorer.learn.goal_demos`).

Read top to bottom, :func:`train` is the whole loop (CleanRL style): load the demonstrations, build the
:class:`~edge_explorer.learn.goal_net.GoalNet`, then per step take the next batch of a per-epoch permutation,
mirror half of it (a left–right mirror of the heading-up frame is another valid decision: the windows' columns and
the goal cells flip, and the turning motions of the last action swap), compute the masked cross-entropy — invalid
goal cells get −∞ before the softmax, so the network only learns to rank valid goals — and step AdamW under a
cosine schedule. Every ``val_every_steps`` the val agreement (the policy's best valid cell is the expert's) is
logged; every ``checkpoint_every_steps`` weights, optimizer and state are written, and ``--resume`` continues with
the very batches the uninterrupted run would have seen (data order is a function of (seed, epoch)).

On a GPU (``device = "cuda"``) the demonstrations are copied to the device once (int8 windows, ~0.11 MB a decision)
and the batches are cut there, under bfloat16 autocast; ``max_minutes`` ends a call with a checkpoint when its wall
time is spent (a lent machine's box), and ``--resume`` goes on from it.

Run folder ``OUT``: ``config.json``, ``checkpoint.safetensors`` + ``optimizer.safetensors`` + ``state.json`` (the
last checkpoint), ``best.safetensors`` (best val agreement), ``train_log.csv``, ``val_log.csv``.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from edge_explorer.errors import EdgeExplorerError
from edge_explorer.learn.csv_log import append_csv_row
from edge_explorer.learn.goal_demos import Demos, load_demos
from edge_explorer.learn.goal_net import GoalNet, GoalNetConfig, load_goal_net, save_goal_net
from edge_explorer.learn.hardware import hardware_description
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS

_MIRRORED_ACTION = torch.tensor([0, 2, 1, 3, 5, 4])  # hover, right↔left, forward, right+fwd↔left+fwd


@dataclass(frozen=True)
class BCConfig:
    """A behaviour-cloning run."""

    train_demos: str = "data/goal_demos/train"  # shard folder(s), comma-separated
    val_demos: str = "data/goal_demos/val"
    init: str = ""  # a goal-policy .safetensors to start from (DAgger rounds, new demonstrations); "" = random
    batch_size: int = 32
    learning_rate: float = 1e-3
    weight_decay: float = 1e-4
    total_steps: int = 4000
    seed: int = 0
    threads: int = 1
    mirror: bool = True
    log_every_steps: int = 25
    val_every_steps: int = 250
    checkpoint_every_steps: int = 100
    device: str = "cpu"  # "cuda" on a GPU machine

    def __post_init__(self) -> None:
        if min(self.batch_size, self.total_steps, self.threads, self.val_every_steps, self.checkpoint_every_steps) < 1:
            raise EdgeExplorerError("batch_size, total_steps, threads and the *_every_steps must be ≥ 1")
        if self.learning_rate <= 0 or self.weight_decay < 0:
            raise EdgeExplorerError("learning_rate must be > 0 and weight_decay ≥ 0")


@dataclass(frozen=True)
class DemoTensors:
    """:class:`Demos` as torch tensors on one device (the same dtypes; zero-copy on the CPU)."""

    high: torch.Tensor
    thres: torch.Tensor
    last_action: torch.Tensor
    mask: torch.Tensor
    label: torch.Tensor

    @classmethod
    def of(cls, demos: Demos, device: str = "cpu") -> DemoTensors:
        return cls(*(torch.from_numpy(getattr(demos, k)).to(device) for k in cls.__dataclass_fields__))

    def __len__(self) -> int:
        return len(self.label)


def batch_tensors(demos: DemoTensors, indices: np.ndarray, mirror: np.ndarray) -> tuple[torch.Tensor, ...]:
    """(high, thres, last_action one-hot, mask, label) of ``indices``, the rows flagged in ``mirror`` mirrored."""
    device = demos.label.device
    rows = torch.from_numpy(np.asarray(indices, dtype=np.int64)).to(device)
    high = demos.high[rows].float()
    thres = demos.thres[rows].float()
    action = demos.last_action[rows].long()
    mask = demos.mask[rows].reshape(-1, GOAL_GRID_CELLS, GOAL_GRID_CELLS)
    label = demos.label[rows].long()
    flip = torch.from_numpy(mirror).to(device)
    if flip.any():
        high[flip] = high[flip].flip(-1)
        thres[flip] = thres[flip].flip(-1)
        mask[flip] = mask[flip].flip(-1)
        action[flip] = _MIRRORED_ACTION.to(device)[action[flip]]
        row, col = label[flip] // GOAL_GRID_CELLS, label[flip] % GOAL_GRID_CELLS
        label[flip] = row * GOAL_GRID_CELLS + (GOAL_GRID_CELLS - 1 - col)
    return high, thres, F.one_hot(action, 6).float(), mask.reshape(len(indices), -1), label


def masked_logits(
    model: GoalNet, high: torch.Tensor, thres: torch.Tensor, last: torch.Tensor, mask: torch.Tensor
) -> torch.Tensor:
    """Flat goal-cell logits with the invalid cells at −1e9 (B, 3481)."""
    with torch.autocast(high.device.type, dtype=torch.bfloat16, enabled=high.device.type == "cuda"):
        logits, _ = model(high, thres, last)
    return logits.float().reshape(len(high), -1).masked_fill(~mask, -1e9)


@torch.no_grad()
def agreement(model: GoalNet, demos: DemoTensors, batch_size: int) -> float:
    """Share of decisions where the policy's best valid cell is the expert's."""
    model.eval()
    hits = 0
    for start in range(0, len(demos), batch_size):
        idx = np.arange(start, min(start + batch_size, len(demos)))
        high, thres, last, mask, label = batch_tensors(demos, idx, np.zeros(len(idx), bool))
        hits += int((masked_logits(model, high, thres, last, mask).argmax(1) == label).sum())
    model.train()
    return hits / max(len(demos), 1)


def learning_rate(config: BCConfig, step: int) -> float:
    return 0.5 * config.learning_rate * (1.0 + math.cos(math.pi * min(step / config.total_steps, 1.0)))


def _save(out: Path, model: GoalNet, optimizer: torch.optim.Optimizer, state: dict) -> None:
    from safetensors.torch import save_file

    save_goal_net(model, out / "checkpoint.safetensors")
    flat = {}
    for k, s in optimizer.state_dict()["state"].items():
        for name, value in s.items():
            flat[f"{k}.{name}"] = torch.as_tensor(value).detach().cpu().contiguous()
    save_file(flat, str(out / "optimizer.safetensors"))
    (out / "state.json").write_text(json.dumps(state))  # written last: a checkpoint is complete when it exists


def _load(out: Path, model: GoalNet, optimizer: torch.optim.Optimizer) -> dict:
    from safetensors.torch import load_file

    model.load_state_dict(load_file(str(out / "checkpoint.safetensors")))
    flat = load_file(str(out / "optimizer.safetensors"))
    state: dict[int, dict] = {}
    for key, value in flat.items():
        k, name = key.split(".", 1)
        state.setdefault(int(k), {})[name] = value
    optimizer.load_state_dict({"state": state, "param_groups": optimizer.state_dict()["param_groups"]})
    return json.loads((out / "state.json").read_text())


def train(
    config: BCConfig,
    out: Path,
    resume: bool = False,
    net: GoalNetConfig | None = None,
    stop_at_step: int | None = None,
    max_minutes: float | None = None,
) -> dict:
    """Train (or continue) a behaviour-cloning run into ``out`` (network ``net``, default widths; with
    ``config.init``, that file's network and weights to start from); returns the final state. ``stop_at_step``
    ends this call early with a checkpoint, as a session that runs out of time does; so does ``max_minutes`` of
    wall time in this call."""
    net = net if net is not None else GoalNetConfig()
    from tqdm import tqdm

    if resume and not (out / "state.json").exists():
        raise EdgeExplorerError(f"{out}: nothing to resume (no state.json); drop --resume to start a run")
    if not resume and (out / "state.json").exists():
        raise EdgeExplorerError(f"{out} already holds a run; pass --resume to continue it or choose a new --out")
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    if config.device.startswith("cuda") and not torch.cuda.is_available():
        raise EdgeExplorerError(f"device {config.device!r}: no CUDA GPU here; use --device cpu")
    train_set = DemoTensors.of(load_demos(config.train_demos), config.device)
    val_set = DemoTensors.of(load_demos(config.val_demos), config.device)
    start = load_goal_net(config.init) if config.init else None
    net = start.config if start is not None else net
    model = GoalNet(net)
    if start is not None and not resume:
        model.load_state_dict(start.state_dict())
    model.to(config.device)
    optimizer = torch.optim.AdamW(model.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay)
    if resume:
        state = _load(out, model, optimizer)
        if state["train_decisions"] != len(train_set):
            raise EdgeExplorerError(
                f"{out}: the run trained on {state['train_decisions']} decisions, {config.train_demos} now holds "
                f"{len(train_set)}; resume with the same demonstrations or start a new run"
            )
    else:
        state = {"step": 0, "best_agreement": -1.0, "wall_s": 0.0, "train_decisions": len(train_set)}
        (out / "config.json").write_text(json.dumps({"bc": asdict(config), "net": asdict(net)}, indent=1))
    per_epoch = len(train_set) // config.batch_size
    if per_epoch == 0:
        raise EdgeExplorerError(f"{len(train_set)} decisions are fewer than one batch of {config.batch_size}")
    state["hardware"] = hardware_description(config.device, 0, config.threads)  # where this call trains
    started = time.perf_counter() - state["wall_s"]
    deadline = time.perf_counter() + 60.0 * max_minutes if max_minutes is not None else math.inf
    with tqdm(total=config.total_steps, initial=state["step"], desc="goal BC", unit="step") as bar:
        end = config.total_steps if stop_at_step is None else min(stop_at_step, config.total_steps)
        while state["step"] < end:
            step = state["step"]
            epoch, k = divmod(step, per_epoch)
            rng = np.random.default_rng([config.seed, epoch])
            order = rng.permutation(len(train_set))
            mirror = rng.random(len(train_set)) < 0.5
            idx = order[k * config.batch_size : (k + 1) * config.batch_size]
            high, thres, last, mask, label = batch_tensors(train_set, idx, mirror[idx] & config.mirror)
            for group in optimizer.param_groups:
                group["lr"] = learning_rate(config, step)
            loss = F.cross_entropy(masked_logits(model, high, thres, last, mask), label)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            state["step"] = step + 1
            state["wall_s"] = time.perf_counter() - started
            bar.update(1)
            if state["step"] % config.log_every_steps == 0:
                append_csv_row(
                    out / "train_log.csv", {"step": state["step"], "loss": loss.item(), "wall_s": state["wall_s"]}
                )
                bar.set_postfix(loss=f"{loss.item():.3f}")
            out_of_time = time.perf_counter() >= deadline
            if state["step"] % config.val_every_steps == 0 or state["step"] in (config.total_steps, end) or out_of_time:
                score = agreement(model, val_set, 64)
                append_csv_row(
                    out / "val_log.csv", {"step": state["step"], "agreement": score, "wall_s": state["wall_s"]}
                )
                if score > state["best_agreement"]:
                    state["best_agreement"] = score
                    save_goal_net(model, out / "best.safetensors")
            if state["step"] % config.checkpoint_every_steps == 0 or state["step"] == end or out_of_time:
                _save(out, model, optimizer, state)
            if out_of_time:
                break
    return state
