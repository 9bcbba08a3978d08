"""The torch networks the exporter starts from, with their I/O contract and the metadata written into every file.

* ``predictor``: :func:`edge_explorer.learn.unet.load_unet` then :meth:`~edge_explorer.learn.unet.UNet.fused`
  (BatchNorm folded) — input ``map`` [1, 2, 256, 256] (:func:`~edge_explorer.predict.encoding.encode_windows`),
  output ``occupancy`` [1, 1, 256, 256] probabilities; the contract of :mod:`edge_explorer.predict.predictor`.
* ``policy``: :func:`edge_explorer.learn.goal_net.load_goal_net` wrapped in :class:`GoalLogits` — inputs
  ``high``, ``thres`` [1, 237, 237] (cell codes as float32) and ``last_action`` [1, 6] (one-hot), output ``logits``
  [1, 59, 59], the spatial action map of :mod:`edge_explorer.plan.goal_grid`; the chosen goal is the argmax over
  the valid cells (:func:`~edge_explorer.plan.goal_policy.choose_cell`). The value head is PPO's critic only and
  is left out of the graph. Every format, ONNX and TFLite, takes the float codes and encodes them with the net's
  own ReLUs (:func:`~edge_explorer.learn.goal_net.encode_codes`), which map onto the Edge TPU (it has no EQUAL,
  SELECT or CAST).

The batch is fixed at 1 (what the daemon runs, and what full-integer TFLite needs).
"""

from __future__ import annotations

import hashlib
import json
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from edge_explorer.export.calibration import Feed
from edge_explorer.export.recipe import Recipe, RecipeError
from edge_explorer.mapping.ego import NUM_ACTIONS, OBSERVATION_WINDOW_CELLS, PREDICTOR_WINDOW_CELLS
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS, GOAL_POOL
from edge_explorer.predict.encoding import INPUT_CHANNELS
from edge_explorer.predict.thresholding import ThresholdConfig
from edge_explorer.sim.dynamics import TABLE_VERSION

PREDICTOR_ENCODING = (
    "edge_explorer.predict.encoding.encode_windows: NCHW float32, channel 0 = observed FREE, channel 1 = observed "
    "OCCUPIED (0/1), UNKNOWN = (0, 0); north-up 0.20 m ego window of mapping.ego.pad_shift, robot cell (128, 128)"
)
GOAL_POLICY_ENCODING = (
    "edge_explorer.mapping.ego.encode_observation: high / thres = heading-up 237x237 code windows (FREE -1, "
    "UNKNOWN 0, OCCUPIED 1, NON_FLIGHT 2; float32 in ONNX, quantized int8 in TFLite), vehicle cell (118, 118); "
    "last_action = one-hot of 6 (float32)"
)
GOAL_GRID_CONTRACT = json.dumps(
    {
        "cells": GOAL_GRID_CELLS,
        "pool": GOAL_POOL,
        "layout": "heading-up ego goal cell (i, j) covers observation rows [pool*i, pool*i + pool) and columns "
        "[pool*j, pool*j + pool) (edge_explorer.plan.goal_grid)",
        "choice": "goal = argmax of the logits over the valid goal cells only (masked argmax, "
        "edge_explorer.plan.goal_policy.choose_cell)",
    }
)
ENCODINGS = {"predictor": PREDICTOR_ENCODING, "policy": GOAL_POLICY_ENCODING}


@dataclass(frozen=True)
class ExportNetwork:
    """A torch module in eval mode and what the exported graph must look like."""

    kind: str  # predictor | policy
    module: torch.nn.Module
    inputs: dict[str, tuple[int, ...]]  # name → shape, ONNX (torch) layout, batch 1
    outputs: tuple[str, ...]
    metadata: dict[str, str]  # written into the ONNX metadata_props and the TFLite metadata

    def example(self) -> tuple[torch.Tensor, ...]:
        return tuple(torch.zeros(shape) for shape in self.inputs.values())

    def cast(self, feed: Feed) -> Feed:
        """``feed``'s inputs of this network as float32 arrays."""
        return {name: np.asarray(feed[name], dtype=np.float32) for name in self.inputs}


class GoalLogits(torch.nn.Module):
    """A :class:`~edge_explorer.learn.goal_net.GoalNet` with its goal logits [B, 59, 59] as the only output (the
    value head is training-only; the exporter drops the computation nothing reads)."""

    def __init__(self, net: torch.nn.Module) -> None:
        super().__init__()
        self.net = net

    def forward(self, high: torch.Tensor, thres: torch.Tensor, last_action: torch.Tensor) -> torch.Tensor:
        logits, _value = self.net(high, thres, last_action)
        return logits


def git_revision() -> str:
    """``git rev-parse HEAD`` of the working tree (``+dirty`` when it has changes), or ``unknown``."""
    try:
        rev = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain"], capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return rev + ("+dirty" if dirty.strip() else "")


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _training_config_hash(checkpoint: Path) -> str:
    """SHA-256 of the training config: the card beside the checkpoint's ``training.config``, else the weights'
    own safetensors metadata (architecture and whatever the trainer stored)."""
    from safetensors import safe_open

    card = checkpoint.parent / "card.json"
    if card.is_file():
        training = json.loads(card.read_text()).get("training", {})
        if isinstance(training, dict) and "config" in training:
            return hashlib.sha256(json.dumps(training["config"], sort_keys=True).encode()).hexdigest()
    with safe_open(str(checkpoint), framework="pt") as fh:
        metadata = fh.metadata() or {}
    return hashlib.sha256(json.dumps(metadata, sort_keys=True).encode()).hexdigest()


def base_metadata(kind: str, checkpoint: Path | None) -> dict[str, str]:
    thresholds = ThresholdConfig()
    return {
        "edge_explorer.model": kind,
        "edge_explorer.input_encoding": ENCODINGS[kind],
        "edge_explorer.thresholds": json.dumps({"t_f_max": thresholds.t_f_max, "t_o": thresholds.t_o}),
        "edge_explorer.action_table_version": str(TABLE_VERSION),
        "edge_explorer.training_config_sha256": _training_config_hash(checkpoint) if checkpoint else "none",
        "edge_explorer.checkpoint_sha256": _sha256(checkpoint) if checkpoint else "none",
        "edge_explorer.git_revision": git_revision(),
    }


def predictor_network(module: torch.nn.Module, checkpoint: Path | None = None) -> ExportNetwork:
    """The export view of a (fused) U-Net."""
    size = PREDICTOR_WINDOW_CELLS
    return ExportNetwork(
        "predictor",
        module.eval(),
        {"map": (1, INPUT_CHANNELS, size, size)},
        ("occupancy",),
        {**base_metadata("predictor", checkpoint), "edge_explorer.output": "P(occupied) per cell, [1, 1, S, S]"},
    )


def policy_network(net: torch.nn.Module, checkpoint: Path | None = None) -> ExportNetwork:
    """The export view of a :class:`~edge_explorer.learn.goal_net.GoalNet`: float-code inputs, the goal logits
    only (:class:`GoalLogits`), the goal-grid contract in the metadata."""
    size = OBSERVATION_WINDOW_CELLS
    metadata = {
        **base_metadata("policy", checkpoint),
        "edge_explorer.output": f"goal-cell logits [1, {GOAL_GRID_CELLS}, {GOAL_GRID_CELLS}]; goal = masked argmax",
        "edge_explorer.goal_grid": GOAL_GRID_CONTRACT,
    }
    return ExportNetwork(
        "policy",
        GoalLogits(net).eval(),
        {"high": (1, size, size), "thres": (1, size, size), "last_action": (1, NUM_ACTIONS)},
        ("logits",),
        metadata,
    )


def load_network(recipe: Recipe) -> ExportNetwork:
    """Load the recipe's checkpoint (safetensors, never pickles) as an :class:`ExportNetwork`."""
    if recipe.model == "predictor":
        from edge_explorer.learn.unet import load_unet

        try:
            unet = load_unet(recipe.checkpoint)
        except (ValueError, RuntimeError) as exc:
            raise RecipeError(f"{recipe.checkpoint}: not a predictor checkpoint ({exc})") from None
        if unet.config.in_channels != INPUT_CHANNELS:
            raise RecipeError(f"{recipe.checkpoint}: the predictor must take {INPUT_CHANNELS} input channels")
        return predictor_network(unet.fused(), recipe.checkpoint)
    from edge_explorer.learn.goal_net import load_goal_net

    try:
        net = load_goal_net(recipe.checkpoint)
    except (ValueError, RuntimeError) as exc:
        raise RecipeError(f"{recipe.checkpoint}: not a goal policy checkpoint ({exc})") from None
    return policy_network(net, recipe.checkpoint)
