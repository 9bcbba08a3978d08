"""The map predictor network: a small U-Net built only from ops that quantize to int8 and map to the Edge TPU.

Layout (default :class:`UNetConfig`, input 2×256×256, see :mod:`edge_explorer.predict.encoding`)::

    stem     conv3×3 stride 2 → 128²×12, conv3×3            encoder level 0
    down k   conv3×3 stride 2, conv3×3  → 64²×24, 32²×48, 16²×96, 8²×128
    up k     nearest ×2, concat skip, conv3×3               back to 128²×12
    head     nearest ×2 to 256², concat the input, conv3×3 → 8, conv1×1 → 1, sigmoid

Every conv is followed by BatchNorm (training only) and ReLU. :meth:`UNet.fused` folds each BatchNorm into its
convolution for export, leaving Conv2d (with bias), ReLU, nearest upsampling, concat and sigmoid — no transposed
convolution (a known Edge TPU failure), no normalization at inference. The strided stem keeps the work at full
256² resolution to the one cheap head conv: the model costs 0.44 GMAC and 0.70 M parameters per prediction.

:class:`TorchPredictor` wraps a model as the ``Callable[[int8 window], probabilities]`` that the simulator, the
benchmark and the evaluation take (the ONNX/TFLite backends provide the same callable).
"""

from __future__ import annotations

import copy
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from edge_explorer.mapping.ego import PREDICTOR_WINDOW_CELLS
from edge_explorer.predict.encoding import INPUT_CHANNELS, OUTPUT_CHANNELS, decode_probabilities, encode_windows


@dataclass(frozen=True)
class UNetConfig:
    """Architecture of :class:`UNet`; stored beside every checkpoint and in the model card."""

    in_channels: int = INPUT_CHANNELS
    channels: tuple[int, ...] = (12, 24, 48, 96, 128)  # encoder levels at 1/2, 1/4, … of the input resolution
    head_channels: int = 8
    batchnorm: bool = True  # False: convolutions carry biases instead (a fused, export-ready model)

    def __post_init__(self) -> None:
        if len(self.channels) < 2 or min(self.channels) < 1 or self.head_channels < 1 or self.in_channels < 1:
            raise ValueError(f"UNetConfig needs ≥ 2 levels of positive channels, got {self}")

    @property
    def stride(self) -> int:
        """The input side must be a multiple of this (the deepest level's downsampling)."""
        return 2 ** len(self.channels)

    def to_dict(self) -> dict:
        return {**asdict(self), "channels": list(self.channels)}

    @classmethod
    def from_dict(cls, data: dict) -> UNetConfig:
        return cls(**{**data, "channels": tuple(data["channels"])})


class ConvBlock(nn.Sequential):
    """conv3×3 (optionally strided) → BatchNorm → ReLU, or conv with bias → ReLU when ``batchnorm`` is off."""

    def __init__(self, in_channels: int, out_channels: int, stride: int = 1, batchnorm: bool = True) -> None:
        conv = nn.Conv2d(in_channels, out_channels, 3, stride=stride, padding=1, bias=not batchnorm)
        layers: list[nn.Module] = [conv, nn.BatchNorm2d(out_channels)] if batchnorm else [conv]
        super().__init__(*layers, nn.ReLU(inplace=True))


class UNet(nn.Module):
    """Encoder–decoder with skip connections; ``forward`` gives probabilities, ``logits`` the pre-sigmoid values."""

    def __init__(self, config: UNetConfig = UNetConfig()) -> None:
        super().__init__()
        self.config = config
        c, bn = config.channels, config.batchnorm
        self.down = nn.ModuleList()
        previous = config.in_channels
        for width in c:
            self.down.append(nn.Sequential(ConvBlock(previous, width, 2, bn), ConvBlock(width, width, 1, bn)))
            previous = width
        self.up = nn.ModuleList(ConvBlock(c[k + 1] + c[k], c[k], 1, bn) for k in reversed(range(len(c) - 1)))
        self.head = nn.Sequential(
            ConvBlock(c[0] + config.in_channels, config.head_channels, 1, bn),
            nn.Conv2d(config.head_channels, OUTPUT_CHANNELS, 1),
        )
        self.upsample = nn.Upsample(scale_factor=2, mode="nearest")

    def logits(self, x: torch.Tensor) -> torch.Tensor:
        """(N, in_channels, H, W) encoded windows → (N, 1, H, W) occupancy logits; H, W multiples of ``stride``."""
        skips = []
        h = x
        for level in self.down:
            h = level(h)
            skips.append(h)
        h = skips.pop()
        for block in self.up:
            h = block(torch.cat([self.upsample(h), skips.pop()], dim=1))
        return self.head(torch.cat([self.upsample(h), x], dim=1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.logits(x))

    def fused(self) -> UNet:
        """A copy with every BatchNorm folded into its convolution (eval statistics): the export/shipping form."""
        if not self.config.batchnorm:
            return self
        out = UNet(UNetConfig(**{**asdict(self.config), "batchnorm": False}))
        trained = copy.deepcopy(self).eval()  # folding needs eval mode; leave this model's mode alone
        source = [m for m in trained.modules() if isinstance(m, ConvBlock)]
        target = [m for m in out.modules() if isinstance(m, ConvBlock)]
        for src, dst in zip(source, target, strict=True):
            fused = torch.nn.utils.fuse_conv_bn_eval(src[0], src[1])
            dst[0].load_state_dict(fused.state_dict())
        out.head[1].load_state_dict(self.head[1].state_dict())
        return out.eval()


def count_macs_params(model: nn.Module, size_cells: int = PREDICTOR_WINDOW_CELLS) -> tuple[int, int]:
    """(multiply–accumulates of one prediction, trainable parameters), counted by torch's FlopCounterMode."""
    from torch.utils.flop_counter import FlopCounterMode

    in_channels = model.config.in_channels if isinstance(model, UNet) else INPUT_CHANNELS
    was_training = model.training
    model.eval()
    with torch.no_grad(), FlopCounterMode(display=False) as counter:
        model(torch.zeros(1, in_channels, size_cells, size_cells))
    model.train(was_training)
    return counter.get_total_flops() // 2, sum(p.numel() for p in model.parameters())


# ---- weights on disk: safetensors + a JSON config, never pickles ------------------------------------------------
def save_unet(model: UNet, weights_path: str | Path) -> None:
    """Write ``weights_path`` (safetensors) with the architecture in its metadata."""
    from safetensors.torch import save_file

    state = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    save_file(state, str(weights_path), metadata={"unet_config": json.dumps(model.config.to_dict())})


def load_unet(weights_path: str | Path, device: str = "cpu") -> UNet:
    """Rebuild a :class:`UNet` from a file written by :func:`save_unet`, in eval mode."""
    from safetensors import safe_open
    from safetensors.torch import load_file

    with safe_open(str(weights_path), framework="pt") as fh:
        metadata = fh.metadata() or {}
    if "unet_config" not in metadata:
        raise ValueError(f"{weights_path}: no unet_config in the safetensors metadata; not a save_unet file")
    model = UNet(UNetConfig.from_dict(json.loads(metadata["unet_config"])))
    model.load_state_dict(load_file(str(weights_path), device=device))
    return model.to(device).eval()


class TorchPredictor:
    """The predictor callable: int8 256×256 ego window → float32 occupancy probabilities of the same shape."""

    def __init__(self, model: UNet, device: str = "cpu") -> None:
        self.model = model.to(device).eval()
        self.device = device

    @classmethod
    def from_file(cls, weights_path: str | Path, device: str = "cpu") -> TorchPredictor:
        return cls(load_unet(weights_path, device), device)

    @torch.no_grad()
    def __call__(self, window: np.ndarray) -> np.ndarray:
        x = torch.from_numpy(encode_windows(window)[None]).to(self.device)
        return decode_probabilities(self.model(x).cpu().numpy())
