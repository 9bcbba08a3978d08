"""Shipping the learned goal policy: copy the chosen weights into ``models/policy/``, write its card, plot its curves.

``card.json`` holds what a user of the weights needs to trust and rebuild them: the architecture (config, params,
MACs), the input/output contract of :mod:`edge_explorer.plan.policy`, every training stage that led to the weights
(behaviour cloning, DAgger rounds, PPO: each run's config, final state and val log, in order), the reward of the
goal environment, the building evaluation of ``edge-explorer bench explore`` (which must have flown these very
weights: the SHA-256 of its ``--policy`` file is checked), the :func:`flight_ready` verdict the daemon reads, the
single-thread fp32 latency on this host and the SHA-256 of the weights. Shipping the same weights again keeps the
keys others added to the card (the export's ``artifacts``); new weights start a new card.
"""

from __future__ import annotations

import csv
import json
import platform
import shutil
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch

from edge_explorer.backends.card import sha256_of
from edge_explorer.errors import EdgeExplorerError
from edge_explorer.learn.goal_net import GoalNet, load_goal_net
from edge_explorer.learn.hardware import torch_latency_ms
from edge_explorer.learn.predictor_card import CARD_FORMAT
from edge_explorer.mapping.ego import NUM_ACTIONS, OBSERVATION_WINDOW_CELLS
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS
from edge_explorer.plan.predictive import PredictiveConfig
from edge_explorer.sim.env import EnvConfig

WEIGHTS_NAME = "policy.safetensors"
FLIGHT_READY_SUCCESS = 0.98  # issue #21: ≥ 98 % of the evaluation's runs reach 95 % coverage, and no collision


def _example() -> tuple[torch.Tensor, ...]:
    size = OBSERVATION_WINDOW_CELLS
    return torch.zeros(1, size, size), torch.zeros(1, size, size), torch.zeros(1, NUM_ACTIONS)


def count_macs(net: GoalNet) -> int:
    """Multiply-accumulates of one forward pass (convolutions and linear layers, the value head included)."""
    macs = 0

    def hook(module: torch.nn.Module, _inputs: tuple, output: torch.Tensor) -> None:
        nonlocal macs
        if isinstance(module, torch.nn.Conv2d):
            kh, kw = module.kernel_size
            macs += output.numel() * module.in_channels * kh * kw // module.groups
        else:
            macs += output.numel() * module.in_features

    handles = [m.register_forward_hook(hook) for m in net.modules() if isinstance(m, torch.nn.Conv2d | torch.nn.Linear)]
    with torch.no_grad():
        net(*_example())
    for h in handles:
        h.remove()
    return macs


def latency_ms(net: GoalNet, repeats: int = 30) -> dict[str, Any]:
    """Median / p90 wall time of one decision's network (batch 1, fp32 torch, one thread) on this host."""
    return torch_latency_ms(lambda: net(*_example()), repeats)


def _rows(path: Path) -> list[dict[str, float | str]]:
    """A CSV log as rows of numbers (text where a cell is not one)."""
    if not path.exists():
        return []
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))

    def number(text: str) -> float | str:
        try:
            return float(text)
        except ValueError:
            return text

    return [{k: number(v) for k, v in row.items()} for row in rows]


def stage_record(run_dir: Path) -> dict[str, Any]:
    """One training stage (a ``train goal-bc`` or ``train goal-ppo`` run folder): its config, state and val log."""
    try:
        config = json.loads((run_dir / "config.json").read_text())
        state = json.loads((run_dir / "state.json").read_text())
    except (OSError, ValueError) as exc:
        raise EdgeExplorerError(
            f"{run_dir}: not a finished training run ({exc}); pass a goal-bc/goal-ppo folder"
        ) from None
    kind = "ppo" if "reward_scale" in config else "bc"
    return {
        "run": str(run_dir),
        "kind": kind,
        "config": config,
        "state": state,
        "val_log": _rows(run_dir / "val_log.csv"),
    }


def decision_settings(config: PredictiveConfig | None = None) -> dict[str, Any]:
    """The planner settings that turn the policy's scores into a goal (the card's ``decision``; ``config`` defaults to
    today's :class:`PredictiveConfig`): the path-cost weight, the worth-a-look threshold, the detour cap, the
    view-gain weight, and the expert's path decay for the fallback taken when no goal on the policy's grid is valid."""
    config = config or PredictiveConfig()
    return {
        "policy_cost_weight_per_m": config.policy_cost_weight_per_m,
        "min_gain_cells": config.min_gain_cells,
        "policy_max_detour_m": config.policy_max_detour_m,
        "policy_detour_min_cells": config.policy_detour_min_cells,
        "policy_gain_weight": config.policy_gain_weight,
        "fallback_cost_decay_per_m": config.cost_decay_per_m,
    }


def flight_ready(summary_all: dict[str, Any] | None) -> dict[str, Any]:
    """Whether the daemon flies this policy by default (``edge-explorer run --planner auto``), and why: the building
    evaluation's ``drl`` runs reached 95 % coverage in at least :data:`FLIGHT_READY_SUCCESS` of the runs, with no
    collision at all."""
    if summary_all is None:
        return {"ready": False, "why": "no building evaluation of these weights (ship-policy --eval)"}
    drl = next((v for k, v in summary_all.items() if k.startswith("drl")), None)
    if drl is None:
        return {"ready": False, "why": "the building evaluation has no drl method"}
    ready = drl["success_rate"] >= FLIGHT_READY_SUCCESS and drl["collisions"] == 0
    why = (
        f"building evaluation: success {drl['success_rate']:.0%} (needs ≥ {FLIGHT_READY_SUCCESS:.0%}), "
        f"{drl['collisions']} collisions (needs 0) over {drl['runs']} runs"
    )
    return {"ready": ready, "why": why}


def building_evaluation(path: Path, weights_sha: str) -> dict[str, Any]:
    """The parts of a ``bench explore --json`` report the card keeps; it must have flown these weights."""
    report = json.loads(path.read_text())
    flown = (report.get("config") or {}).get("policy")
    if not flown or not Path(flown).is_file() or sha256_of(Path(flown)) != weights_sha:
        raise EdgeExplorerError(f"{path} did not fly these weights (its --policy {flown!r} differs); re-run the bench")
    return {k: report[k] for k in ("command", "plans", "methods", "runs_per_plan", "seed", "paired")} | {
        "summary_all": report["summary"]["all"]
    }


def plot_learning_curves(stages: Sequence[dict[str, Any]], png: Path) -> None:
    """Val curves of every stage against cumulative wall time: BC/DAgger agreement with the expert, PPO successes
    and mean path at 95 % on the val plans."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (agree, success) = plt.subplots(1, 2, figsize=(11, 4))
    offset_h = 0.0
    for k, stage in enumerate(stages):
        rows = [r for r in stage["val_log"] if isinstance(r.get("wall_s"), float)]
        hours = [offset_h + float(r["wall_s"]) / 3600 for r in rows]
        label = f"{k + 1}: {stage['kind']} ({Path(stage['run']).name})"
        if stage["kind"] == "bc":
            agree.plot(hours, [r["agreement"] for r in rows], marker=".", label=label)
        else:
            success.plot(hours, [r["successes"] for r in rows], marker=".", label=label)
        offset_h += float(stage["state"].get("wall_s", 0.0)) / 3600
    agree.set(xlabel="wall time (h, stages end to end)", ylabel="val agreement with the expert", title="BC / DAgger")
    success.set(xlabel="wall time (h, stages end to end)", ylabel="val successes", title="PPO")
    for ax in (agree, success):
        ax.grid(alpha=0.3)
        if ax.lines:
            ax.legend(fontsize=8)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    plt.close(fig)


def ship_goal_policy(
    weights: Path,
    stage_dirs: Sequence[Path],
    out_dir: Path,
    evaluation: Path | None,
    command: str,
    docs_dir: Path | None = None,
) -> dict[str, Any]:
    """Copy ``weights`` (a goal-policy .safetensors) to ``out_dir`` with ``card.json``; curves to ``docs_dir``."""
    try:
        net = load_goal_net(weights)
    except (OSError, ValueError) as exc:
        raise EdgeExplorerError(
            f"{weights}: not a goal policy ({exc}); pass a train goal-bc/goal-ppo .safetensors"
        ) from None
    weights_sha = sha256_of(weights)
    stages = [stage_record(d) for d in stage_dirs]
    buildings = building_evaluation(evaluation, weights_sha) if evaluation is not None else None
    env = EnvConfig()
    card = {
        "format": CARD_FORMAT,
        "model": "learned goal policy (spatial action map over the ego goal grid, masked argmax)",
        "weights": WEIGHTS_NAME,
        "sha256": weights_sha,
        "architecture": {
            "class": "edge_explorer.learn.goal_net.GoalNet",
            "load": "edge_explorer.learn.goal_net.load_goal_net(path)",
            "config": asdict(net.config),
            "macs": count_macs(net),
            "params": sum(p.numel() for p in net.parameters()),
        },
        "input": {
            "high": "float32 [1, 237, 237]: heading-up 0.05 m inflated observed map, codes FREE −1, UNKNOWN 0, "
            "OCCUPIED 1, NON_FLIGHT 2 (mapping.ego.observation_from_maps)",
            "thres": "float32 [1, 237, 237]: the same at 0.20 m of the inflated fused map (observed ∪ M_thres)",
            "last_action": "float32 [1, 6]: one-hot of the previous motion",
        },
        "output": {
            "shape": [1, GOAL_GRID_CELLS, GOAL_GRID_CELLS],
            "meaning": "goal-cell logits on the heading-up 0.8 m goal grid (plan.goal_grid); the goal is the valid "
            "cell of the highest logit − decision.policy_cost_weight_per_m × path cost in m "
            "+ decision.policy_gain_weight × ln(1 + cells unknown in the fused map in view from it) "
            "among the goals worth a look: ≥ decision.min_gain_cells cells unknown in the fused map in view, "
            "unless that is a detour of more than decision.policy_max_detour_m from the best-ranked cell "
            "(plan.goal_policy.best_cell_worth_a_look), "
            "flown along observed free space",
        },
        "decision": decision_settings(),
        "reward": {
            "per_decision": "ω·ΔF1(M_thres) − metres flown − l·collisions (sim.goal_env)",
            "f1_weight_omega": env.f1_weight,
            "collision_penalty_l": env.collision_penalty,
        },
        "training": {
            "command": command,
            "stages": stages,
            "wall_time_h": sum(float(s["state"].get("wall_s", 0.0)) for s in stages) / 3600,
            "hardware": [
                s["state"].get("hardware", "not recorded (runs before 2026-11-26: this host's CPU)") for s in stages
            ],
        },
        "evaluation_buildings": buildings,
        "flight_ready": flight_ready(buildings["summary_all"] if buildings else None),
        "latency_torch_fp32_this_host": latency_ms(net),
        "host": {"machine": platform.machine(), "python": platform.python_version(), "torch": torch.__version__},
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    card_path = out_dir / "card.json"
    if card_path.exists():  # keys others added for these very weights (the export's artifacts) stay
        previous = json.loads(card_path.read_text())
        if previous.get("sha256") == weights_sha:
            card.update({k: v for k, v in previous.items() if k not in card})
    if weights.resolve() != (out_dir / WEIGHTS_NAME).resolve():
        shutil.copyfile(weights, out_dir / WEIGHTS_NAME)
    card_path.write_text(json.dumps(card, indent=1) + "\n")
    if docs_dir is not None:
        plot_learning_curves(stages, docs_dir / "learning_curves.png")
    return card
