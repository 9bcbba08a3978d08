"""Shipping the DRL policy: copy a run's best actor into ``models/policy/``, write its card, plot its learning curves.

``card.json`` holds what a user of the weights needs to trust and rebuild them: the architecture (config, params,
MACs) and the observation encoding, the input/output contract of :mod:`edge_explorer.plan.policy`, how it was trained
(command, config, the BC and PPO stages with their evaluations, steps, wall time, hardware), the reward settings, the
building evaluation of ``edge-explorer eval policy`` (which must have scored these very weights), the single-thread
fp32 latency on this host, and the SHA-256 of the weights file. Shipping the same weights again keeps the keys
others added to the card (the export's ``artifacts``); new weights start a new card.
"""

from __future__ import annotations

import csv
import json
import os
import platform
import shutil
import statistics
import time
from pathlib import Path

import torch

from edge_explorer.backends.card import sha256_of
from edge_explorer.errors import EdgeExplorerError
from edge_explorer.learn.policy_net import PolicyActor, load_policy_module, read_metadata
from edge_explorer.learn.predictor_card import CARD_FORMAT
from edge_explorer.mapping.ego import NUM_ACTIONS

WEIGHTS_NAME = "policy.safetensors"


def count_macs(actor: PolicyActor) -> int:
    """Multiply-accumulates of one forward pass (convolutions and linear layers)."""
    macs = 0

    def conv_hook(module: torch.nn.Conv2d, _inputs: tuple, output: torch.Tensor) -> None:
        nonlocal macs
        kh, kw = module.kernel_size
        macs += output.numel() * module.in_channels * kh * kw // module.groups

    def linear_hook(module: torch.nn.Linear, _inputs: tuple, output: torch.Tensor) -> None:
        nonlocal macs
        macs += output.numel() * module.in_features

    handles = []
    for m in actor.modules():
        if isinstance(m, torch.nn.Conv2d):
            handles.append(m.register_forward_hook(conv_hook))
        elif isinstance(m, torch.nn.Linear):
            handles.append(m.register_forward_hook(linear_hook))
    size = actor.config.window_cells
    with torch.no_grad():
        actor(torch.zeros(1, size, size), torch.zeros(1, size, size), torch.zeros(1, NUM_ACTIONS))
    for h in handles:
        h.remove()
    return macs


def latency_ms(actor: PolicyActor, repeats: int = 30) -> dict:
    """Median / p90 wall time of one decision (batch 1, fp32, one torch thread) on this host."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    size = actor.config.window_cells
    x, last = torch.zeros(1, size, size), torch.zeros(1, NUM_ACTIONS)
    times = []
    with torch.no_grad():
        for k in range(repeats + 5):
            t0 = time.perf_counter()
            actor(x, x, last)
            if k >= 5:
                times.append(1e3 * (time.perf_counter() - t0))
    torch.set_num_threads(previous)
    times.sort()
    return {
        "median_ms": statistics.median(times),
        "p90_ms": times[int(0.9 * (len(times) - 1))],
        "threads": 1,
        "repeats": repeats,
        "load_average_1min": os.getloadavg()[0],
    }


def _read_csv(path: Path) -> list[dict[str, str]]:
    if not path.exists():
        return []
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def _number(text: str) -> str | float | None:
    """A CSV cell as a number where it is one (empty: None)."""
    if text == "":
        return None
    try:
        return float(text)
    except ValueError:
        return text


def _floats(rows: list[dict[str, str]], x: str, y: str) -> tuple[list[float], list[float]]:
    xs, ys = [], []
    for row in rows:
        if row.get(x) not in (None, "") and row.get(y) not in (None, ""):
            xs.append(float(row[x]))
            ys.append(float(row[y]))
    return xs, ys


def _progress_files(run_dir: Path) -> list[Path]:
    """SB3's progress.csv and the parts a resume set aside (progress-until-STEPS.csv), in training order."""
    return [*sorted(run_dir.glob("progress-until-*.csv")), run_dir / "progress.csv"]


def plot_learning_curves(run_dir: Path, png: Path) -> None:
    """Three panels: BC held-out accuracy per epoch; PPO mean episode return (scaled) and coverage per rollout;
    the val evaluation (success rate, mean coverage) before BC, after BC and during PPO."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    bc, evals = _read_csv(run_dir / "bc.csv"), _read_csv(run_dir / "eval.csv")
    progress = [row for path in _progress_files(run_dir) for row in _read_csv(path)]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    ax = axes[0]
    ax.plot(*_floats(bc, "epoch", "held_out_accuracy"), "o-", label="held-out accuracy (argmax = expert)")
    ax.plot(*_floats(bc, "epoch", "train_nll"), "s--", label="train NLL")
    ax.set(xlabel="BC epoch", title="behaviour cloning (frontier expert)")
    ax.legend()
    ax = axes[1]
    ax.plot(*_floats(progress, "time/total_timesteps", "rollout/ep_rew_mean"), label="episode return (×reward_scale)")
    twin = ax.twinx()
    twin.plot(*_floats(progress, "time/total_timesteps", "rollout/coverage"), "g-", label="episode-end coverage")
    twin.set_ylim(0, 1)
    ax.set(xlabel="PPO env steps", title="PPO rollouts (train plans)")
    ax.legend(loc="upper left")
    twin.legend(loc="lower right")
    ax = axes[2]
    steps = [float(r["timesteps"]) for r in evals]
    for key, style in (("success_rate", "o-"), ("mean_coverage", "s-"), ("goal_rate", "^:")):
        ax.plot(steps, [float(r[key]) for r in evals], style, label=key)
    for r, s in zip(evals, steps, strict=True):
        if r["stage"] in ("init", "bc"):
            ax.annotate(r["stage"], (s, float(r["mean_coverage"])), textcoords="offset points", xytext=(4, 4))
    ax.set(xlabel="PPO env steps (init, bc at 0)", ylim=(0, 1.02), title="val evaluation (deterministic)")
    ax.legend(loc="upper right")
    twin = ax.twinx()
    twin.semilogy(steps, [max(float(r["collisions_per_episode"]), 0.1) for r in evals], "rx--", label="collisions/ep")
    twin.legend(loc="center right")
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    plt.close(fig)


FLIGHT_READY_SUCCESS = 0.95  # DESIGN.md / issue #7: ≥ 95 % of runs reach 95 % coverage, and no collision at all


def flight_ready(buildings: dict | None) -> dict:
    """Whether the daemon may fly this policy by default (``edge-explorer run --planner auto``), and why.

    Ready means the building evaluation of these weights reached 95 % coverage in at least
    :data:`FLIGHT_READY_SUCCESS` of its runs without a single collision; otherwise ``auto`` flies the frontier
    planner and ``--planner drl`` must be asked for explicitly.
    """
    if buildings is None:
        return {"ready": False, "why": "no building evaluation of these weights (ship-policy --eval)"}
    drl = next((v for k, v in buildings["summary_all"].items() if k.startswith("drl")), None)
    if drl is None:
        return {"ready": False, "why": "the building evaluation has no drl method"}
    ready = drl["success_rate"] >= FLIGHT_READY_SUCCESS and drl["collisions"] == 0
    why = (
        f"building evaluation: success {drl['success_rate']:.0%} (needs ≥ {FLIGHT_READY_SUCCESS:.0%}), "
        f"{drl['collisions']} collisions (needs 0) over {drl['runs']} runs"
    )
    return {"ready": ready, "why": why}


def ship_policy(run_dir: Path, out_dir: Path, evaluation: Path | None, command: str, docs_dir: Path | None) -> dict:
    """Copy ``run_dir/best.safetensors`` to ``out_dir`` with ``card.json``; curves and logs to ``docs_dir``."""
    best = run_dir / "best.safetensors"
    if not best.exists():
        raise EdgeExplorerError(f"{run_dir}: no best.safetensors; train first")
    state = json.loads((run_dir / "state.json").read_text())
    config = json.loads((run_dir / "config.json").read_text())
    weights_sha = sha256_of(best)
    buildings = None
    if evaluation is not None:
        report = json.loads(evaluation.read_text())
        if report.get("model_sha256") != weights_sha:
            raise EdgeExplorerError(f"{evaluation} evaluated another model (sha256 differs from {best})")
        buildings = {k: report[k] for k in ("command", "plans", "runs_per_plan", "seed", "methods", "ratios", "table")}
        buildings["summary_all"] = report["summary"]["all"]
    actor = load_policy_module(best)
    out_dir.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(best, out_dir / WEIGHTS_NAME)
    evals = [{k: _number(v) for k, v in row.items()} for row in _read_csv(run_dir / "eval.csv")]
    card = {
        "format": CARD_FORMAT,
        "model": "DRL exploration policy (PPO actor, deterministic)",
        "weights": WEIGHTS_NAME,
        "sha256": weights_sha,
        "architecture": {
            "class": "edge_explorer.learn.policy_net.PolicyActor",
            "load": "edge_explorer.learn.policy_net.load_policy_module(path)",
            "config": actor.config.to_dict(),
            "layers": "encode codes → 6 channels; 3× (Conv2d + ReLU); flatten ‖ one-hot last action; "
            f"policy MLP {list(actor.config.pi_layers)} ReLU; Linear → 6 logits",
            "features_dim": actor.features_extractor.features_dim,
            "macs": count_macs(actor),
            "params": sum(p.numel() for p in actor.parameters()),
        },
        "input": {
            "high": "float32 [B, 237, 237]: heading-up 0.05 m inflated observed map, codes FREE −1, UNKNOWN 0, "
            "OCCUPIED 1, NON_FLIGHT 2 (mapping.ego.encode_observation)",
            "thres": "float32 [B, 237, 237]: the same at 0.20 m of the inflated thresholded map M_thres",
            "last_action": "float32 [B, 6]: one-hot of the previous action",
            "encoding_inside_network": "free = relu(x) − x, occupied = relu(x) − 2·relu(x − 1), non-flight = "
            "relu(x − 1) per layer (policy_net.encode_codes)",
        },
        "output": {
            "shape": [1, NUM_ACTIONS],
            "meaning": "action logits; the action is the argmax (0 hover, 1 turn "
            "right, 2 turn left, 3 forward, 4 right + forward, 5 left + forward)",
        },  # fmt: skip
        "reward": {
            "collision_penalty_l": config["collision_penalty"],
            "f1_weight_omega": config["f1_weight"],
            "reward_scale_for_learning": config["reward_scale"],
            "coverage_goal": config["coverage_goal"],
            "max_steps": config["max_steps"],
            "motion_and_sensor_noise": True,
        },
        "training": {
            "command": command,
            "config": config,
            "stage": state["stage"],
            "expert": config["expert"],
            "expert_episodes": config["expert_episodes"],
            "bc": state.get("bc"),
            "ppo_env_steps": state["timesteps"],
            "phase2_steps_planned": config["phase2_steps"],
            "best_at_ppo_steps": state["best_timesteps"],
            "best_stage": read_metadata(best).get("stage"),
            "val_evaluations": evals,
            "wall_time_h": state["wall_s"] / 3600,
            "hardware": f"{platform.processor() or platform.machine()}, {os.cpu_count()} shared cores, CPU only, "
            f"{config['threads']} torch thread(s) per process, {config['n_envs']} env workers",
        },
        "evaluation_buildings": buildings,
        "flight_ready": flight_ready(buildings),
        "latency_torch_fp32_this_host": latency_ms(actor),
        "host": {"machine": platform.machine(), "python": platform.python_version(), "torch": torch.__version__},
    }
    card_path = out_dir / "card.json"
    if card_path.exists():  # keys others added for these very weights (the export's artifacts) stay
        previous = json.loads(card_path.read_text())
        if previous.get("sha256") == weights_sha:
            card.update({k: v for k, v in previous.items() if k not in card})
    card_path.write_text(json.dumps(card, indent=1) + "\n")
    if docs_dir is not None:
        docs_dir.mkdir(parents=True, exist_ok=True)
        plot_learning_curves(run_dir, docs_dir / "learning_curves.png")
        for path in [run_dir / "bc.csv", run_dir / "eval.csv", *_progress_files(run_dir)]:
            if path.exists():
                shutil.copyfile(path, docs_dir / path.name)
    return card
