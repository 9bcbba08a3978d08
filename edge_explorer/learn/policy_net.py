"""The DRL planner's network (the paper's Fig. 3) for stable-baselines3, and its torch-only deterministic actor.

Observation → features (:class:`PolicyFeatures`, an SB3 ``BaseFeaturesExtractor``):

* ``high`` and ``thres`` arrive as the float32 cell codes of the shared observation
  (:func:`edge_explorer.mapping.ego.encode_observation`: FREE −1, UNKNOWN 0, OCCUPIED 1, NON_FLIGHT 2), each
  [B, 237, 237]. :func:`encode_codes` turns every layer into three 0/1 channels — free, occupied, non-flight
  (unknown is all zeros) — *inside* the network, with ReLUs and sums only, so an exported ONNX/TFLite graph takes
  the raw codes (the contract of :mod:`edge_explorer.plan.policy`) and quantizes without comparisons or casts.
* With ``input_pool`` k > 1 the six 0/1 channels are max-pooled k×k (zero-padded to a multiple of k) right after
  the encoding: a pooled cell is "free / occupied / non-flight somewhere in its block", so a single OCCUPIED or
  NON_FLIGHT cell stays visible (pooling the raw codes instead would let NON_FLIGHT hide OCCUPIED and UNKNOWN hide
  FREE). The environment, the daemon's observation and the exported graph's inputs stay 237×237; only the convs
  see a k× smaller map (~4× fewer conv MACs for k = 2: faster PPO on a CPU).
* The six channels go through three conv + ReLU layers (Nature-CNN-like kernels 8/4/3; strides 4/2/2 by default,
  so the flatten is 64·13·13 = 10 816 values instead of 43 264 with a last stride of 1), are flattened and
  concatenated with the one-hot ``last_action``.

The policy and value heads are separate ReLU MLPs (SB3 ``net_arch=dict(pi=…, vf=…)``) on the shared features;
``action_net`` maps the policy MLP's output to the six action logits.

Weights on disk: :func:`save_policy` writes the actor part (extractor, policy MLP, action layer) of an SB3
``ActorCriticPolicy`` to a safetensors file whose metadata holds the :class:`PolicyNetConfig`;
:func:`load_policy_module` rebuilds the deterministic actor from that file alone (no pickles) — what export
(ONNX/TFLite) and evaluation use.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from edge_explorer.errors import EdgeExplorerError
from edge_explorer.mapping.ego import NUM_ACTIONS, OBSERVATION_WINDOW_CELLS
from edge_explorer.world.grid import FREE, NON_FLIGHT, OCCUPIED

WEIGHTS_FORMAT = "edge-explorer/policy-actor"
CHANNELS_PER_LAYER = 3  # free, occupied, non-flight
INPUT_CHANNELS = 2 * CHANNELS_PER_LAYER  # high + thres
ACTOR_PREFIXES = ("features_extractor.", "policy_net.", "action_net.")


@dataclass(frozen=True)
class PolicyNetConfig:
    """Architecture of the policy network; stored in the weights file's metadata."""

    conv_channels: tuple[int, int, int] = (32, 64, 64)
    conv_kernels: tuple[int, int, int] = (8, 4, 3)
    conv_strides: tuple[int, int, int] = (4, 2, 2)
    pi_layers: tuple[int, ...] = (256,)
    vf_layers: tuple[int, ...] = (256,)
    window_cells: int = OBSERVATION_WINDOW_CELLS
    input_pool: int = 1  # k×k max-pool of the encoded channels before the convs (1: none)

    def __post_init__(self) -> None:
        for name in ("conv_channels", "conv_kernels", "conv_strides"):
            value = getattr(self, name)
            if len(value) != 3 or min(value) < 1:
                raise ValueError(f"{name} must be three positive integers, got {list(value)}")
        if min((*self.pi_layers, *self.vf_layers), default=1) < 1:
            raise ValueError("pi_layers and vf_layers must be positive widths")
        if self.window_cells < 1:
            raise ValueError(f"window_cells must be positive, got {self.window_cells}")
        if self.input_pool < 1:
            raise ValueError(f"input_pool must be a positive integer (1: no pooling), got {self.input_pool}")

    def to_dict(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> PolicyNetConfig:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown policy network key(s) {unknown}; allowed: {sorted(known)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})


def encode_codes(codes: torch.Tensor) -> torch.Tensor:
    """[B, H, W] float cell codes → [B, 3, H, W] 0/1 channels (free, occupied, non-flight); unknown is all zero.

    With integer codes x ∈ {−1, 0, 1, 2}: free = relu(x) − x (= relu(−x), written so the converter keeps it in
    int8: a negated input stays float in TFLite and falls off the Edge TPU), occupied = relu(x) − 2·relu(x − 1),
    non-flight = relu(x − 1). Only ReLUs and sums, so the exported graph stays quantization-friendly.
    """
    above_zero = torch.relu(codes)
    above_one = torch.relu(codes - 1.0)
    return torch.stack([above_zero - codes, above_zero - 2.0 * above_one, above_one], dim=1)


def encode_codes_by_comparison(*layers: torch.Tensor) -> torch.Tensor:
    """[B, H, W] integer code layers (int8 as the daemon holds them) → [B, 3·len(layers), H, W]: per layer the same
    channels as :func:`encode_codes`, by equality tests and one ``where``.

    The int8-input ONNX graph uses it: the export folds the quantization of the ``where`` into its two constants
    (:func:`edge_explorer.export.onnx_formats.fold_quantize_into_where`), so the first convolution reads the encoded
    channels as integers straight from the comparisons. Not for TFLite: EQUAL, SELECT and CAST do not run on the Edge
    TPU, so the TFLite graph keeps :func:`encode_codes`.
    """
    masks = torch.stack([codes == value for codes in layers for value in (FREE, OCCUPIED, NON_FLIGHT)], dim=1)
    return torch.where(masks, 1.0, 0.0)


class MapEncoder(nn.Module):
    """The two code layers → encoded channels → optional k×k max-pool → three conv + ReLU → flattened features."""

    def __init__(self, config: PolicyNetConfig) -> None:
        super().__init__()
        k = config.input_pool
        pad = -config.window_cells % k
        # no parameters either way: the state-dict keys (and weights files) of input_pool = 1 are unchanged
        self.pool: nn.Module = (
            nn.Sequential(nn.ZeroPad2d((0, pad, 0, pad)), nn.MaxPool2d(k)) if k > 1 else nn.Identity()
        )
        layers: list[nn.Module] = []
        in_channels = INPUT_CHANNELS
        for out_channels, kernel, stride in zip(
            config.conv_channels, config.conv_kernels, config.conv_strides, strict=True
        ):
            layers += [nn.Conv2d(in_channels, out_channels, kernel, stride), nn.ReLU()]
            in_channels = out_channels
        layers.append(nn.Flatten())
        self.cnn = nn.Sequential(*layers)
        with torch.no_grad():
            zeros = torch.zeros(1, config.window_cells, config.window_cells)
            self.out_dim = int(self.forward(zeros, zeros).shape[1])

    def forward(self, high: torch.Tensor, thres: torch.Tensor) -> torch.Tensor:
        return self.from_channels(torch.cat([encode_codes(high), encode_codes(thres)], dim=1))

    def from_channels(self, channels: torch.Tensor) -> torch.Tensor:
        """The encoded [B, 6, H, W] channels (high's three, then thres's) → flattened features."""
        return self.cnn(self.pool(channels))


class PolicyFeatures(BaseFeaturesExtractor):
    """SB3 features extractor: ``MapEncoder(high, thres)`` concatenated with the one-hot ``last_action``."""

    def __init__(self, observation_space: gym.spaces.Dict, net_config: dict[str, Any] | None = None) -> None:
        config = PolicyNetConfig.from_dict(net_config or {})
        expected = (config.window_cells, config.window_cells)
        for key in ("high", "thres"):
            if tuple(observation_space[key].shape) != expected:
                raise ValueError(f"observation {key!r} has shape {observation_space[key].shape}, expected {expected}")
        encoder = MapEncoder(config)
        super().__init__(observation_space, features_dim=encoder.out_dim + NUM_ACTIONS)
        self.encoder = encoder

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        return self.features(observations["high"], observations["thres"], observations["last_action"])

    def features(self, high: torch.Tensor, thres: torch.Tensor, last_action: torch.Tensor) -> torch.Tensor:
        return torch.cat([self.encoder(high.float(), thres.float()), last_action.float()], dim=1)


def sb3_policy_kwargs(config: PolicyNetConfig) -> dict[str, Any]:
    """``policy_kwargs`` for SB3 ``PPO("MultiInputPolicy", …)`` that build this network."""
    return {
        "features_extractor_class": PolicyFeatures,
        "features_extractor_kwargs": {"net_config": config.to_dict()},
        "net_arch": {"pi": list(config.pi_layers), "vf": list(config.vf_layers)},
        "activation_fn": nn.ReLU,
        "share_features_extractor": True,
        "normalize_images": False,
    }


def _mlp(in_dim: int, widths: tuple[int, ...]) -> nn.Sequential:
    """Linear + ReLU per width: the layout (and state-dict keys) of SB3's ``MlpExtractor.policy_net``."""
    layers: list[nn.Module] = []
    for width in widths:
        layers += [nn.Linear(in_dim, width), nn.ReLU()]
        in_dim = width
    return nn.Sequential(*layers)


class PolicyActor(nn.Module):
    """The deterministic actor: forward(high, thres, last_action) → [B, 6] action logits (argmax = action)."""

    def __init__(self, config: PolicyNetConfig) -> None:
        super().__init__()
        self.config = config
        size = config.window_cells
        space = gym.spaces.Dict(
            {
                "high": gym.spaces.Box(-1, 2, (size, size)),
                "thres": gym.spaces.Box(-1, 2, (size, size)),
                "last_action": gym.spaces.Box(0, 1, (NUM_ACTIONS,)),
            }
        )
        self.features_extractor = PolicyFeatures(space, config.to_dict())
        self.policy_net = _mlp(self.features_extractor.features_dim, config.pi_layers)
        last = config.pi_layers[-1] if config.pi_layers else self.features_extractor.features_dim
        self.action_net = nn.Linear(last, NUM_ACTIONS)

    def forward(self, high: torch.Tensor, thres: torch.Tensor, last_action: torch.Tensor) -> torch.Tensor:
        features = self.features_extractor.features(high, thres, last_action)
        return self.action_net(self.policy_net(features))

    def logits_from_channels(self, channels: torch.Tensor, last_action: torch.Tensor) -> torch.Tensor:
        """Logits from already encoded [B, 6, H, W] channels: the rest of :meth:`forward` after the encoding."""
        features = torch.cat([self.features_extractor.encoder.from_channels(channels), last_action.float()], dim=1)
        return self.action_net(self.policy_net(features))


def actor_state_dict(policy: nn.Module) -> dict[str, torch.Tensor]:
    """The actor's tensors of an SB3 ``ActorCriticPolicy`` built with :func:`sb3_policy_kwargs`, keyed as in
    :class:`PolicyActor` (``mlp_extractor.policy_net.*`` becomes ``policy_net.*``; the value head is left out)."""
    state = {}
    for key, value in policy.state_dict().items():
        name = key.removeprefix("mlp_extractor.")
        if name.startswith(ACTOR_PREFIXES) and not key.startswith(("pi_features_extractor.", "vf_features_extractor.")):
            state[name] = value.detach().cpu().contiguous()
    return state


def save_policy(
    policy: nn.Module, config: PolicyNetConfig, path: str | Path, metadata: dict[str, str] | None = None
) -> None:
    """Write the actor of ``policy`` (an SB3 ``ActorCriticPolicy`` or a :class:`PolicyActor`) to safetensors, the
    architecture in the metadata (``policy_net_config``) plus any extra string ``metadata``."""
    from safetensors.torch import save_file

    state = (
        {k: v.detach().cpu().contiguous() for k, v in policy.state_dict().items()}
        if isinstance(policy, PolicyActor)
        else actor_state_dict(policy)
    )
    meta = {"format": WEIGHTS_FORMAT, "policy_net_config": json.dumps(config.to_dict()), **(metadata or {})}
    save_file(state, str(path), metadata=meta)


def read_metadata(weights: str | Path) -> dict[str, str]:
    """The string metadata of a :func:`save_policy` file."""
    from safetensors import safe_open

    try:
        with safe_open(str(weights), framework="pt") as fh:
            return dict(fh.metadata() or {})
    except FileNotFoundError:
        raise EdgeExplorerError(f"{weights}: no such policy weights file; train or ship the policy first") from None


def load_policy_module(weights: Path) -> torch.nn.Module:
    """Rebuild the deterministic actor (:class:`PolicyActor`, eval mode, CPU) from a :func:`save_policy` file.

    ``forward(high, thres, last_action)``: float32 [B, 237, 237], [B, 237, 237], [B, 6] → [B, 6] logits.
    """
    from safetensors.torch import load_file

    metadata = read_metadata(weights)
    if metadata.get("format") != WEIGHTS_FORMAT or "policy_net_config" not in metadata:
        raise EdgeExplorerError(f"{weights}: not a policy weights file (no {WEIGHTS_FORMAT} metadata)")
    actor = PolicyActor(PolicyNetConfig.from_dict(json.loads(metadata["policy_net_config"])))
    try:
        actor.load_state_dict(load_file(str(weights), device="cpu"))
    except RuntimeError as exc:
        raise EdgeExplorerError(f"{weights}: weights do not match the architecture in its metadata: {exc}") from None
    return actor.eval()


class TorchPolicy:
    """The policy callable of the benchmark (:data:`edge_explorer.bench.explore.Policy`) on the torch actor:
    the simulator's observation dict → the argmax action, the deterministic choice the daemon makes too."""

    def __init__(self, actor: torch.nn.Module) -> None:
        self.actor = actor.eval()

    @classmethod
    def from_file(cls, weights: Path) -> TorchPolicy:
        return cls(load_policy_module(weights))

    @torch.no_grad()
    def __call__(self, observation: dict[str, np.ndarray]) -> int:
        inputs = (torch.as_tensor(observation[k], dtype=torch.float32)[None] for k in ("high", "thres", "last_action"))
        return int(self.actor(*inputs).argmax())
