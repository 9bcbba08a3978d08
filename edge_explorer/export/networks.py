"""The torch networks the exporter starts from, with their I/O contract and the metadata written into every file.

* ``predictor``: :func:`edge_explorer.learn.unet.load_unet` then :meth:`~edge_explorer.learn.unet.UNet.fused`
  (BatchNorm folded) — input ``map`` [1, 2, 256, 256] (:func:`~edge_explorer.predict.encoding.encode_windows`),
  output ``occupancy`` [1, 1, 256, 256] probabilities; the contract of :mod:`edge_explorer.predict.predictor`.
* ``policy``: :func:`edge_explorer.learn.goal_net.load_goal_net` wrapped in :class:`GoalLogits` — inputs
  ``high``, ``thres`` [1, 237, 237] (cell codes as float32) and ``last_action`` [1, 6] (one-hot), output ``logits``
  [1, 59, 59], the spatial action map of :mod:`edge_explorer.plan.goal_grid`; the chosen goal is the argmax over
  the valid cells (:func:`~edge_explorer.plan.goal_policy.weighted_scores`). The value head is PPO's critic only and
  is left out of the graph. Every format, ONNX and TFLite, takes the float codes and encodes them with the net's
  own ReLUs (:func:`~edge_explorer.learn.goal_net.encode_codes`), which map onto the Edge TPU (it has no EQUAL,
  SELECT or CAST).

The batch is fixed at 1 (what the daemon runs, and what full-integer TFLite needs).
"""

from __future__ import annotations

import copy
import hashlib
import json
import subprocess
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from edge_explorer.export.calibration import Feed
from edge_explorer.export.recipe import Recipe, RecipeError
from edge_explorer.export.unet_equalization import choose_equalization
from edge_explorer.mapping.ego import NUM_ACTIONS, OBSERVATION_WINDOW_CELLS, PREDICTOR_WINDOW_CELLS
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS, GOAL_POOL
from edge_explorer.predict.encoding import INPUT_CHANNELS
from edge_explorer.predict.thresholding import ThresholdConfig
from edge_explorer.vehicle.dynamics import TABLE_VERSION

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
        "edge_explorer.plan.goal_policy.weighted_scores; the planner keeps to goals worth a look)",
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

    # The function whose *decisions* the gates judge, when the exported graph computes an equivalent one (the goal
    # policy: the unwrapped net's logits; the export outputs a monotone transform of them). None: ``module``.
    decision_reference: torch.nn.Module | None = None
    # A calibration-dependent rewrite into an equivalent network (the goal policy's equalization), applied by the
    # pipeline once the calibration observations exist. None: export ``module`` as it is.
    prepare: Callable[[list[Feed]], ExportNetwork] | None = None

    def example(self) -> tuple[torch.Tensor, ...]:
        return tuple(torch.zeros(shape) for shape in self.inputs.values())

    def cast(self, feed: Feed) -> Feed:
        """``feed``'s inputs of this network as float32 arrays."""
        return {name: np.asarray(feed[name], dtype=np.float32) for name in self.inputs}


class WindowedScores(torch.nn.Module):
    """The goal net's score convolution (one logit per cell) followed by a per-decision *window*: its output is a
    strictly increasing function of the logit within each decision, so every argmax — over the valid cells or any
    other set — is the logit's own, while an int8 output spends its 256 levels on the logits that can win.

    With ``x`` the logits and ``M`` their maximum over the ``cells`` × ``cells`` goal grid (a per-decision scalar):

    * ``mid  = clamp(k_mid  · (x − M + window),          0, 6)``, ``k_mid  = 6 / (window + margin)``;
    * ``tail = clamp(k_tail · (x − M + window + tail), 0, 6)``, ``k_tail = 6 / tail``;
    * ``score = mid + tail_weight · tail``.

    ``score`` rises with slope ``k_mid + tail_weight · k_tail`` over the top ``window`` logits below ``M`` and with
    ``tail_weight · k_tail`` over the ``tail`` logits below them; it is flat only more than ``window + tail``
    below the maximum (ties there cannot change a decision unless every valid cell is that far below the best
    cell of the grid). ``x ≤ M`` always, so the upper clamp never cuts a logit; ``margin`` keeps it so when int8
    rounds ``M`` below a cell's value.

    ``x − M`` is not computed on the coarse int8 logits: ``M`` (a reduce-max, broadcast back by a nearest resize)
    joins the score convolution's input features as one more channel, so the subtraction happens in the next
    1 × 1 convolution's 32-bit accumulator, and the 0…6 clamp is that convolution's fused ReLU6. The coarse
    logits only place the window (their rounding shifts every cell of a decision alike). Ops: Conv, ReduceMax,
    Resize (nearest), Concat, Clip(0, 6): all int8, all Edge TPU operations.
    """

    def __init__(self, score: torch.nn.Conv2d, cells: int, window: float, margin: float, tail: float,
                 tail_weight: float) -> None:  # fmt: skip
        super().__init__()
        if score.out_channels != 1 or score.kernel_size != (1, 1):
            raise ValueError("the score layer must be a 1 × 1 convolution to one channel")
        self.score = score
        self.cells = cells
        features = score.in_channels
        k_mid, k_tail = 6.0 / (window + margin), 6.0 / tail
        w, b = score.weight.detach()[0, :, 0, 0], float(score.bias.detach()[0])
        self.pieces = torch.nn.Conv2d(features + 1, 2, 1)
        self.combine = torch.nn.Conv2d(2, 1, 1, bias=False)
        with torch.no_grad():
            for k, (gain, offset) in enumerate(((k_mid, window), (k_tail, window + tail))):
                self.pieces.weight[k, :features, 0, 0] = gain * w
                self.pieces.weight[k, features, 0, 0] = -gain
                self.pieces.bias[k] = gain * (b + offset)
            self.combine.weight[0, :, 0, 0] = torch.tensor([1.0, tail_weight])
        for p in self.parameters():
            p.requires_grad_(False)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        logits = self.score(features)
        best = logits[:, :, : self.cells, : self.cells].amax(dim=(2, 3), keepdim=True)
        best = torch.nn.functional.interpolate(best, size=features.shape[-2:], mode="nearest")
        pieces = torch.clamp(self.pieces(torch.cat([features, best], dim=1)), 0.0, 6.0)
        # The calibrated int8 range of the scores must reach above the best cell's fp32 score (its int8 value lands
        # within a rounding of it, either side; clipped at the range's top, near-best cells would tie): the column
        # beyond the goal grid (cropped away by the net) gets ``mid`` = ``tail`` = 6, the highest score there is.
        ceiling = torch.full_like(pieces[..., :1], 6.0)
        return self.combine(torch.cat([pieces[..., : self.cells], ceiling], dim=-1))


@torch.no_grad()
def equalize_goal_net(
    net: torch.nn.Module, feeds: list[Feed], strength: float = 0.5, cap: float = 16.0
) -> torch.nn.Module:
    """A copy of a :class:`~edge_explorer.learn.goal_net.GoalNet` with every ReLU layer's output channels rescaled
    towards a common range (cross-layer equalization) — the same function, since ``relu(s·x) = s·relu(x)`` for
    ``s > 0`` and every consumer's input weights are divided by the same ``s``.

    int8 activations have one scale per tensor: a channel whose values span a tenth of the tensor's range gets a
    tenth of its 256 levels. Channel ``c`` of a tensor whose channel maxima (over ``feeds``) are ``r`` is scaled by
    ``s_c = min(cap, (max(r) / r_c) ** strength)``; the skip concatenations (one int8 scale for both parts in
    TFLite) are equalized as one tensor. The motion bias added to ``down4``'s output is scaled with it."""
    net = copy.deepcopy(net).eval()
    ranges: dict[str, torch.Tensor] = {}
    hooks = [getattr(net, name).register_forward_hook(
                 lambda _m, _i, out, name=name: ranges.__setitem__(
                     name, torch.maximum(ranges.get(name, torch.zeros(out.shape[1])), out.amax(dim=(0, 2, 3)))))
             for name in ("down1", "down2", "down3", "down4", "mix", "up1", "up2")]  # fmt: skip
    for feed in feeds:
        net(*(torch.from_numpy(np.asarray(feed[n], np.float32)) for n in ("high", "thres", "last_action")))
    for hook in hooks:
        hook.remove()
    # tensors that share one int8 scale: up(mix) ‖ down3 (up1's input), up(up1) ‖ down2 (up2's input)
    groups = {"down1": None, "down4": None, "up2": None, "mix": "down3", "down3": "mix", "up1": "down2",
              "down2": "up1"}  # fmt: skip
    scales = {}
    for name, r in ranges.items():
        top = torch.maximum(r.max(), ranges[groups[name]].max()) if groups[name] else r.max()
        s = torch.where(r > 0, (top / r.clamp_min(1e-12)) ** strength, torch.ones_like(r))
        scales[name] = s.clamp(max=cap)

    def scale_out(conv: torch.nn.Conv2d, s: torch.Tensor) -> None:
        conv.weight.mul_(s[:, None, None, None])
        conv.bias.mul_(s)

    def scale_in(conv: torch.nn.Conv2d, s: torch.Tensor, start: int) -> None:
        conv.weight[:, start : start + len(s)] /= s[None, :, None, None]

    s = scales
    scale_out(net.down1[0], s["down1"])
    scale_in(net.down2[0], s["down1"], 0)  # noqa: E702
    scale_out(net.down2[0], s["down2"])
    scale_in(net.down3[0], s["down2"], 0)  # noqa: E702
    scale_in(net.up2[0], s["down2"], net.up1[0].out_channels)
    scale_out(net.down3[0], s["down3"])
    scale_in(net.down4[0], s["down3"], 0)  # noqa: E702
    scale_in(net.up1[0], s["down3"], net.mix[0].out_channels)
    scale_out(net.down4[0], s["down4"])
    scale_in(net.mix[0], s["down4"], 0)  # noqa: E702
    net.motion.weight.mul_(s["down4"][:, None])
    net.motion.bias.mul_(s["down4"])  # noqa: E702
    scale_out(net.mix[0], s["mix"])
    scale_in(net.up1[0], s["mix"], 0)  # noqa: E702
    net.value.weight.div_(s["mix"][None, :])  # the critic reads mean(mix): kept exact too (not exported)
    scale_out(net.up1[0], s["up1"])
    scale_in(net.up2[0], s["up1"], 0)  # noqa: E702
    scale_out(net.up2[0], s["up2"])
    scale_in(net.score, s["up2"], 0)  # noqa: E702
    return net


@dataclass(frozen=True)
class ScoreWindow:
    """:class:`WindowedScores`' parameters, in logits (``tail_weight``: the tail's share of the output range)."""

    window: float = 8.0
    margin: float = 0.25
    tail: float = 32.0
    tail_weight: float = 0.125


class GoalLogits(torch.nn.Module):
    """A :class:`~edge_explorer.learn.goal_net.GoalNet` with its goal scores [B, 59, 59] as the only output (the
    value head is training-only; the exporter drops the computation nothing reads).

    With ``window`` (the default for export) the scores are the net's logits through :class:`WindowedScores`:
    per decision a strictly increasing function of the logits, so the masked argmax — the goal — is the same;
    ``window=None`` outputs the raw logits. :meth:`logits` always gives the unwrapped net's logits."""

    def __init__(self, net: torch.nn.Module, window: ScoreWindow | None = ScoreWindow()) -> None:
        super().__init__()
        self.net = net
        self.scored = net
        if window is not None:
            # the same layers (shared, not copied) with the score convolution wrapped
            self.scored = copy.copy(net)
            self.scored._modules = dict(net._modules)
            self.scored.score = WindowedScores(net.score, GOAL_GRID_CELLS, window.window, window.margin,
                                               window.tail, window.tail_weight)  # fmt: skip

    def forward(self, high: torch.Tensor, thres: torch.Tensor, last_action: torch.Tensor) -> torch.Tensor:
        scores, _value = self.scored(high, thres, last_action)
        return scores

    def logits(self, high: torch.Tensor, thres: torch.Tensor, last_action: torch.Tensor) -> torch.Tensor:
        logits, _value = self.net(high, thres, last_action)
        return logits


class GoalNetLogits(torch.nn.Module):
    """A goal net's logits [B, 59, 59] only: the function whose masked argmax every exported format must match."""

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


def predictor_network(module: torch.nn.Module, checkpoint: Path | None = None, equalize: bool = True) -> ExportNetwork:
    """The export view of a (fused) U-Net. With ``equalize`` the network's ``prepare`` picks the cross-layer
    equalization that suits int8 best on the calibration observations
    (:func:`~edge_explorer.export.unet_equalization.choose_equalization`) and exports that equivalent network."""
    size = PREDICTOR_WINDOW_CELLS
    metadata = {**base_metadata("predictor", checkpoint), "edge_explorer.output": "P(occupied) per cell, [1, 1, S, S]"}
    prepare = None
    if equalize:

        def prepare(feeds: list[Feed]) -> ExportNetwork:
            chosen, choice, errors = choose_equalization(module, [f["map"] for f in feeds])
            record = {
                "choice": choice,
                "fake_quant_error": {label: round(error, 5) for label, error in errors.items()},
                "calibration_observations": len(feeds),
                "what": "edge_explorer.export.unet_equalization (same function, rescaled ReLU channels; '+ grid': "
                "interior values of unobserved areas aligned to the int8 grid, computed with the weights rounded; "
                "'+ int8 grid': with the upstream tensors rounded too)",
            }
            network = predictor_network(chosen, checkpoint, equalize=False)
            meta = {**network.metadata, "edge_explorer.equalization": json.dumps(record)}
            return ExportNetwork(network.kind, network.module, network.inputs, network.outputs, meta)

    return ExportNetwork(
        "predictor", module.eval(), {"map": (1, INPUT_CHANNELS, size, size)}, ("occupancy",), metadata, None, prepare
    )


EQUALIZATION_STRENGTH = 0.5  # equalize_goal_net's strength for the export (measured: docs/policy/export_int8.md)


def policy_network(
    net: torch.nn.Module,
    checkpoint: Path | None = None,
    window: ScoreWindow | None = ScoreWindow(),
    equalization: float | None = EQUALIZATION_STRENGTH,
    reference: torch.nn.Module | None = None,
) -> ExportNetwork:
    """The export view of a :class:`~edge_explorer.learn.goal_net.GoalNet`: float-code inputs, the goal scores
    only (:class:`GoalLogits`; windowed unless ``window`` is None), the goal-grid contract in the metadata. The
    gates judge the decisions of ``reference`` (default: ``net``'s own logits). With ``equalization`` the
    network's ``prepare`` equalizes ``net`` on the calibration observations (:func:`equalize_goal_net`)."""
    size = OBSERVATION_WINDOW_CELLS
    cells = f"[1, {GOAL_GRID_CELLS}, {GOAL_GRID_CELLS}]"
    if window is None:
        output = f"goal-cell logits {cells}; goal = masked argmax"
    else:
        output = (
            f"goal-cell scores {cells}: per decision a strictly increasing function of the logits (window "
            f"{json.dumps(asdict(window))}, edge_explorer.export.networks.WindowedScores); goal = masked argmax"
        )
    metadata = {
        **base_metadata("policy", checkpoint),
        "edge_explorer.output": output,
        "edge_explorer.goal_grid": GOAL_GRID_CONTRACT,
    }
    reference = reference if reference is not None else GoalNetLogits(net).eval()
    prepare = None
    if equalization:

        def prepare(feeds: list[Feed]) -> ExportNetwork:
            network = policy_network(equalize_goal_net(net, feeds, equalization), checkpoint, window, None, reference)
            record = {
                "strength": equalization,
                "calibration_observations": len(feeds),
                "what": "edge_explorer.export.networks.equalize_goal_net (same function, rescaled ReLU channels)",
            }
            meta = {**network.metadata, "edge_explorer.equalization": json.dumps(record)}
            return ExportNetwork(network.kind, network.module, network.inputs, network.outputs, meta, reference)

    return ExportNetwork(
        "policy",
        GoalLogits(net, window).eval(),
        {"high": (1, size, size), "thres": (1, size, size), "last_action": (1, NUM_ACTIONS)},
        ("logits",),
        metadata,
        reference,
        prepare,
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
