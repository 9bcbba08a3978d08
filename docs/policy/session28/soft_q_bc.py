"""Fine-tune the goal policy towards the rollout Q estimates of ``branch_q.py`` (issue #21, session 28).

Session 27 imitated hard labels (the best of four tried cells) and the policy learnt a broad bias away from its own
choices. Here the target keeps what the shipped policy knows and changes only what the rollouts measured: at a
branched decision the target distribution is the shipped policy's own softmax over the valid cells, except that the
probability mass it gave the tried cells is shared among them as ``softmax(−Q / τ)`` (Q = mean path at 95 %
coverage of the cell's flights; a failed flight counts as the decision's worst flight + ``--fail-penalty-m``). Where
the policy already put its mass on the greedy cell, most of that mass moves to the cells that flew shortest; the
untried cells keep theirs. Anchor decisions (other decisions of the same flights) are plain distillation: the
target is the shipped policy's softmax. Loss: cross-entropy of the masked softmax against the target, anchors
weighted by ``--anchor-weight``; left–right mirroring as in ``train goal-bc``::

    python docs/policy/session28/soft_q_bc.py runs/s28/branchq --init models/policy/policy.safetensors \
        --steps 600 --out runs/s28/sq_A
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from edge_explorer.learn.goal_net import GoalNet, load_goal_net, save_goal_net
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS

_MIRRORED_ACTION = np.array([0, 2, 1, 3, 5, 4])  # hover, right↔left, forward, right+fwd↔left+fwd


def softmax(scores: np.ndarray) -> np.ndarray:
    """Row softmax of scores with −inf where masked."""
    finite = np.where(np.isfinite(scores), scores, -np.inf)
    shifted = np.exp(finite - finite.max(axis=1, keepdims=True))
    return shifted / shifted.sum(axis=1, keepdims=True)


def q_values(base: float, paths: list[list[float | None]], fail_penalty_m: float) -> np.ndarray:
    """Mean path at 95 % per tried cell (the first cell, the greedy one, also counts the base flight)."""
    flown = [p for cell in paths for p in cell if p is not None] + [base]
    worst = max(flown) + fail_penalty_m
    samples = [[worst if p is None else p for p in cell] for cell in paths]
    samples[0] = [*samples[0], base]
    return np.array([np.mean(s) for s in samples])


def improved_target(policy_probs: np.ndarray, cells: list[int], q: np.ndarray, tau_m: float) -> np.ndarray:
    """The shipped policy's distribution with its mass on ``cells`` re-shared as softmax(−q / τ)."""
    target = policy_probs.copy()
    mass = target[cells].sum()
    share = np.exp(-(q - q.min()) / tau_m)
    target[cells] = mass * share / share.sum()
    return target


def load_branches(folders: list[Path], tau_m: float, fail_penalty_m: float) -> dict[str, np.ndarray]:
    """Every branched and anchor decision of the folders with its target distribution and weight flag."""
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("high", "thres", "last", "mask", "target", "anchor")}
    for folder in folders:
        for meta in sorted(folder.glob("block-*.json")):
            rows = json.loads(meta.read_text())
            with np.load(meta.with_suffix(".npz")) as data:
                arrays = {k: data[k] for k in data.files}
            points = [(row["base"], p) for row in rows for p in row["points"]]
            for kind in ("point", "anchor"):
                if f"{kind}_high" not in arrays:
                    continue
                probs = softmax(arrays[f"{kind}_scores"].astype(np.float64))
                if kind == "point":
                    probs = np.stack(
                        [
                            improved_target(probs[k], p["cells"], q_values(base, p["paths"], fail_penalty_m), tau_m)
                            for k, (base, p) in enumerate(points)
                        ]
                    )
                for key in ("high", "thres", "last", "mask"):
                    parts[key].append(arrays[f"{kind}_{key}"])
                parts["target"].append(probs.astype(np.float32))
                parts["anchor"].append(np.full(len(probs), kind == "anchor"))
    return {k: np.concatenate(v) for k, v in parts.items()}


def batch(data: dict[str, np.ndarray], idx: np.ndarray, mirror: np.ndarray) -> tuple[torch.Tensor, ...]:
    """(high, thres, last one-hot, mask, target, anchor) of rows ``idx``, those flagged in ``mirror`` mirrored."""
    g = GOAL_GRID_CELLS
    high, thres = data["high"][idx].astype(np.float32), data["thres"][idx].astype(np.float32)
    mask = data["mask"][idx].reshape(-1, g, g).copy()
    target = data["target"][idx].reshape(-1, g, g).copy()
    last = data["last"][idx].copy()
    high[mirror], thres[mirror] = high[mirror][..., ::-1], thres[mirror][..., ::-1]
    mask[mirror], target[mirror] = mask[mirror][..., ::-1], target[mirror][..., ::-1]
    last[mirror] = _MIRRORED_ACTION[last[mirror]]
    n = len(idx)
    return (
        torch.from_numpy(np.ascontiguousarray(high)),
        torch.from_numpy(np.ascontiguousarray(thres)),
        F.one_hot(torch.from_numpy(last).long(), 6).float(),
        torch.from_numpy(np.ascontiguousarray(mask).reshape(n, -1)),
        torch.from_numpy(np.ascontiguousarray(target).reshape(n, -1)),
        torch.from_numpy(data["anchor"][idx]),
    )


def loss_of(model: GoalNet, tensors: tuple[torch.Tensor, ...], anchor_weight: float) -> torch.Tensor:
    high, thres, last, mask, target, anchor = tensors
    logits, _ = model(high, thres, last)
    log_probs = torch.log_softmax(logits.reshape(len(high), -1).masked_fill(~mask, -1e9), dim=1)
    per_row = -(target * log_probs.masked_fill(~mask, 0.0)).sum(dim=1)
    weights = torch.where(anchor, anchor_weight, 1.0)
    return (weights * per_row).sum() / weights.sum()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", help="branch_q.py output folders, comma-separated")
    parser.add_argument("--init", default="models/policy/policy.safetensors")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--lr", type=float, default=1e-4)
    parser.add_argument("--tau-m", type=float, default=2.0, help="temperature of softmax(−Q/τ), metres")
    parser.add_argument("--fail-penalty-m", type=float, default=10.0)
    parser.add_argument("--anchor-weight", type=float, default=1.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(args.seed)
    data = load_branches([Path(f) for f in args.folders.split(",")], args.tau_m, args.fail_penalty_m)
    n, points = len(data["target"]), int((~data["anchor"]).sum())
    print(f"{n} decisions ({points} branched, {n - points} anchors)")
    model = load_goal_net(args.init).train()
    optimizer = torch.optim.AdamW(model.parameters(), lr=args.lr, weight_decay=1e-4)
    rng = np.random.default_rng(args.seed)
    args.out.mkdir(parents=True, exist_ok=True)
    log = []
    for step in tqdm(range(args.steps), desc="soft-Q BC"):
        for group in optimizer.param_groups:
            group["lr"] = 0.5 * args.lr * (1 + np.cos(np.pi * step / args.steps))
        idx = rng.choice(n, size=args.batch_size, replace=False)
        loss = loss_of(model, batch(data, idx, rng.random(len(idx)) < 0.5), args.anchor_weight)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        log.append(loss.item())
    save_goal_net(model.eval(), args.out / "checkpoint.safetensors")
    (args.out / "summary.json").write_text(
        json.dumps(
            {
                "args": {k: str(v) for k, v in vars(args).items()},
                "decisions": n,
                "branched": points,
                "loss_first_50": float(np.mean(log[:50])),
                "loss_last_50": float(np.mean(log[-50:])),
            },
            indent=1,
        )
    )
    print(f"loss {np.mean(log[:50]):.3f} -> {np.mean(log[-50:]):.3f}; wrote {args.out / 'checkpoint.safetensors'}")


if __name__ == "__main__":
    main()
