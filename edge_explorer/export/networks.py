"""The torch networks the exporter starts from, with their I/O contract and the metadata written into every file.

* ``predictor``: :func:`edge_explorer.learn.unet.load_unet` then :meth:`~edge_explorer.learn.unet.UNet.fused`
  (BatchNorm folded) — input ``map`` [1, 2, 256, 256] (:func:`~edge_explorer.predict.encoding.encode_windows`),
  output ``occupancy`` [1, 1, 256, 256] probabilities; the contract of :mod:`edge_explorer.predict.predictor`.
* ``policy``: :func:`edge_explorer.learn.policy_net.load_policy_module` — inputs ``high``, ``thres``
  [1, 237, 237] and ``last_action`` [1, 6] (raw codes and one-hot as float32), output ``logits`` [1, 6]; the
  contract of :mod:`edge_explorer.plan.policy`.

The batch is fixed at 1 (what the daemon runs, and what full-integer TFLite needs).
"""

from __future__ import annotations

import hashlib
import json
import subprocess
from dataclasses import dataclass
from pathlib import Path

import torch

from edge_explorer.export.recipe import Recipe, RecipeError
from edge_explorer.mapping.ego import NUM_ACTIONS, OBSERVATION_WINDOW_CELLS, PREDICTOR_WINDOW_CELLS
from edge_explorer.predict.encoding import INPUT_CHANNELS
from edge_explorer.predict.thresholding import ThresholdConfig
from edge_explorer.sim.dynamics import TABLE_VERSION

PREDICTOR_ENCODING = (
    "edge_explorer.predict.encoding.encode_windows: NCHW float32, channel 0 = observed FREE, channel 1 = observed "
    "OCCUPIED (0/1), UNKNOWN = (0, 0); north-up 0.20 m ego window of mapping.ego.pad_shift, robot cell (128, 128)"
)
POLICY_ENCODING = (
    "edge_explorer.mapping.ego.encode_observation: high / thres = heading-up 237x237 code windows as float32 "
    "(FREE -1, UNKNOWN 0, OCCUPIED 1, NON_FLIGHT 2), vehicle cell (118, 118); last_action = one-hot of 6"
)


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
        "edge_explorer.input_encoding": PREDICTOR_ENCODING if kind == "predictor" else POLICY_ENCODING,
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


def policy_network(module: torch.nn.Module, checkpoint: Path | None = None) -> ExportNetwork:
    """The export view of a deterministic policy actor ``forward(high, thres, last_action) → logits``."""
    size = OBSERVATION_WINDOW_CELLS
    return ExportNetwork(
        "policy",
        module.eval(),
        {"high": (1, size, size), "thres": (1, size, size), "last_action": (1, NUM_ACTIONS)},
        ("logits",),
        {**base_metadata("policy", checkpoint), "edge_explorer.output": "action logits [1, 6]; action = argmax"},
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
    from edge_explorer.learn.policy_net import load_policy_module

    return policy_network(load_policy_module(recipe.checkpoint), recipe.checkpoint)
