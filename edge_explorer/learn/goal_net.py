"""The goal policy network: a fully convolutional spatial action map over the 59 × 59 goal cells, and a value head.

Input: the paper's observation (docs/design.md §5) — the heading-up 237 × 237 windows ``high`` (0.05 m, 11.85 m
across) and ``thres`` (0.20 m, 47.4 m) as int8 cell codes, and the one-hot ``last_action``.

* ``high`` is max-pooled 4 × 4 to 0.20 m *as codes* (the pooled cell takes the highest code: NON_FLIGHT over
  OCCUPIED over UNKNOWN over FREE — a conservative coarse map) and zero-padded into the ``thres`` frame, where it
  covers the central 11.85 m (the two windows share their centre cell), so both layers line up cell for cell.
* Each code layer is encoded as three 0/1 channels (free, occupied, non-flight; unknown is all zero) with ReLUs only
  (:func:`encode_codes`), which quantizes to full-integer int8.
* Encoder: a 4 × 4 stride-4 convolution straight to the goal-cell resolution (240 → 60, 0.8 m), then 3 × 3
  convolutions at 60, 30 and 15 cells; the last motion enters as a per-channel bias at 15 × 15. Decoder: nearest
  ×2 upsampling with skip concatenation back to 60 × 60, a 1 × 1 convolution to one score per goal cell, cropped to
  59 × 59 (goal cell (i, j) covers observation cells [4i, 4i + 4) — :mod:`edge_explorer.plan.goal_grid`).
  Pooling the codes before encoding and the stride-4 first layer keep the full-resolution work small: in the first
  design (pooled channels, stride-2 convolutions at 120 and 60) the input stage took 1.9 of 2.7 ms of the int8
  TFLite graph on one host thread.
* Value head: global average of the 15 × 15 features → one number (PPO's critic).

Only Conv2d, ReLU, MaxPool, zero padding, nearest Upsample, concat, add, mean and slicing: ops that quantize to
full-integer int8 and run on the Edge TPU. About 0.1 GMAC.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from edge_explorer.mapping.ego import NUM_ACTIONS, OBSERVATION_WINDOW_CELLS
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS, GOAL_POOL

_PADDED = 240  # the 237-cell window padded to a multiple of 16
GOAL_NET_FORMAT = "edge-explorer/goal-policy"


@dataclass(frozen=True)
class GoalNetConfig:
    """Widths of :class:`GoalNet` (encoder at 60, 60, 30, 15 cells; decoder at 30 and 60)."""

    encoder: tuple[int, int, int, int] = (16, 24, 40, 64)
    decoder: tuple[int, int] = (40, 24)

    def __post_init__(self) -> None:
        if len(self.encoder) != 4 or len(self.decoder) != 2 or min(*self.encoder, *self.decoder) < 1:
            raise ValueError("encoder needs 4 and decoder 2 positive widths")


def encode_codes(codes: torch.Tensor) -> torch.Tensor:
    """[B, H, W] float cell codes → [B, 3, H, W] 0/1 channels (free, occupied, non-flight); unknown is all zero.

    With codes x ∈ {−1, 0, 1, 2}: free = relu(x) − x, occupied = relu(x) − 2·relu(x − 1), non-flight = relu(x − 1):
    ReLUs and sums only, so the exported graph stays in int8.
    """
    above_zero = torch.relu(codes)
    above_one = torch.relu(codes - 1.0)
    return torch.stack([above_zero - codes, above_zero - 2.0 * above_one, above_one], dim=1)


def _conv(in_channels: int, out_channels: int, stride: int = 1, kernel: int = 3) -> nn.Sequential:
    padding = kernel // 2 if kernel % 2 else 0  # odd kernels keep the size (stride 1); even ones tile it
    return nn.Sequential(nn.Conv2d(in_channels, out_channels, kernel, stride, padding=padding), nn.ReLU())


class GoalNet(nn.Module):
    """Observation → (goal-cell logits [B, 59, 59], value [B]); see the module docstring."""

    def __init__(self, config: GoalNetConfig = GoalNetConfig()) -> None:
        super().__init__()
        self.config = config
        e1, e2, e3, e4 = config.encoder
        d1, d2 = config.decoder
        window = OBSERVATION_WINDOW_CELLS
        pooled = -(-window // GOAL_POOL)  # 60 cells of 0.20 m
        before = window // 2 - (window // 2) // GOAL_POOL  # the pooled high window's centre on the thres centre
        # The codes are pooled shifted by +1 (so ≥ 0): the zero padding then stands for FREE and never wins the
        # max-pool over a real cell, with no non-zero constant pad (PADV2 is no Edge TPU op).
        self.pad_high = nn.ZeroPad2d((0, pooled * GOAL_POOL - window, 0, pooled * GOAL_POOL - window))
        self.pool_high = nn.MaxPool2d(GOAL_POOL)
        self.place_high = nn.ZeroPad2d((before, _PADDED - pooled - before, before, _PADDED - pooled - before))
        self.pad_thres = nn.ZeroPad2d((0, _PADDED - window, 0, _PADDED - window))
        self.down1 = _conv(6, e1, stride=GOAL_POOL, kernel=GOAL_POOL)  # 60: goal cells
        self.down2 = _conv(e1, e2)  # 60
        self.down3 = _conv(e2, e3, stride=2)  # 30
        self.down4 = _conv(e3, e4, stride=2)  # 15
        self.motion = nn.Linear(NUM_ACTIONS, e4)
        self.mix = _conv(e4, e4)
        self.up = nn.Upsample(scale_factor=2, mode="nearest")
        self.up1 = _conv(e4 + e3, d1)  # 30
        self.up2 = _conv(d1 + e2, d2)  # 60
        self.score = nn.Conv2d(d2, 1, 1)
        self.value = nn.Linear(e4, 1)

    def forward(
        self, high: torch.Tensor, thres: torch.Tensor, last_action: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        pooled_codes = self.pool_high(self.pad_high(high.unsqueeze(1) + 1.0)).squeeze(1) - 1.0
        high_ch = self.place_high(encode_codes(pooled_codes))
        x = torch.cat([self.pad_thres(encode_codes(thres)), high_ch], dim=1)
        s1 = self.down1(x)
        s2 = self.down2(s1)
        s3 = self.down3(s2)
        s4 = self.down4(s3) + self.motion(last_action)[:, :, None, None]
        s4 = self.mix(s4)
        u1 = self.up1(torch.cat([self.up(s4), s3], dim=1))
        u2 = self.up2(torch.cat([self.up(u1), s2], dim=1))
        logits = self.score(u2)[:, 0, :GOAL_GRID_CELLS, :GOAL_GRID_CELLS]
        value = self.value(s4.mean(dim=(2, 3)))[:, 0]
        return logits, value


def observation_tensors(observations: list[dict[str, np.ndarray]], device: str = "cpu") -> tuple[torch.Tensor, ...]:
    """Batch the numpy observations as the network's float inputs (high, thres, last_action)."""
    high = torch.from_numpy(np.stack([o["high"] for o in observations]).astype(np.float32))
    thres = torch.from_numpy(np.stack([o["thres"] for o in observations]).astype(np.float32))
    last = torch.from_numpy(np.stack([o["last_action"] for o in observations]).astype(np.float32))
    return high.to(device), thres.to(device), last.to(device)


def save_goal_net(model: GoalNet, path: str | Path) -> None:
    """safetensors weights with the architecture in the metadata (no pickles)."""
    from safetensors.torch import save_file

    state = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    metadata = {"format": GOAL_NET_FORMAT, "config": json.dumps(asdict(model.config))}
    save_file(state, str(path), metadata=metadata)


def load_goal_net(path: str | Path) -> GoalNet:
    """A :class:`GoalNet` from :func:`save_goal_net`'s file, in eval mode."""
    from safetensors import safe_open
    from safetensors.torch import load_file

    with safe_open(str(path), framework="pt") as f:
        metadata = f.metadata() or {}
    if metadata.get("format") != GOAL_NET_FORMAT:
        raise ValueError(f"{path}: not a goal policy (format {metadata.get('format')!r})")
    config = {k: tuple(v) for k, v in json.loads(metadata["config"]).items()}
    model = GoalNet(GoalNetConfig(**config))
    model.load_state_dict(load_file(str(path)))
    return model.eval()


class TorchGoalPolicy:
    """The torch network as a :data:`~edge_explorer.plan.goal_policy.GoalPolicy` (benchmarks of unexported
    weights; the daemon runs the exported ONNX/TFLite graph instead)."""

    def __init__(self, model: GoalNet) -> None:
        self.model = model.eval()

    @classmethod
    def from_file(cls, path: str | Path) -> TorchGoalPolicy:
        return cls(load_goal_net(path))

    @torch.no_grad()
    def __call__(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        logits, _ = self.model(*observation_tensors([observation]))
        return logits[0].numpy()
