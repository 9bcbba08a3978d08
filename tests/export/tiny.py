"""Tiny deterministic networks with the predictor's and the policy's export contracts (a few kB of weights).

``make_fixtures`` regenerates the committed ``data/`` files (needs ``make convert-env``)::

    python -m tests.export.tiny
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from edge_explorer.learn.policy_net import encode_codes
from edge_explorer.learn.unet import UNet, UNetConfig, load_unet, save_unet
from edge_explorer.mapping.ego import NUM_ACTIONS

DATA = Path(__file__).parent / "data"
TINY_UNET = DATA / "tiny_unet.safetensors"
TINY_TFLITE = DATA / "tiny_predictor_int8.tflite"


def tiny_unet(windows: torch.Tensor, seed: int = 0) -> UNet:
    """A two-level U-Net (1.8 k parameters), random but *confident*: its last layer is rescaled so that on
    ``windows`` (encoded inputs) the logits have median 0 and standard deviation 6. Probabilities then span both
    thresholds and depend on the whole network, like the real predictor's (a plain random net answers about the same
    value everywhere, which thresholding turns into UNKNOWN: nothing for the gates to compare)."""
    torch.manual_seed(seed)
    model = UNet(UNetConfig(channels=(4, 8), head_channels=4, batchnorm=False)).eval()
    with torch.no_grad():
        logits = model.logits(windows)
        scale = 6.0 / logits.std()
        model.head[1].weight.mul_(scale)
        model.head[1].bias.mul_(scale).sub_(torch.median(logits) * scale)
    return model


class TinyPolicy(nn.Module):
    """The interface of :class:`edge_explorer.learn.policy_net.PolicyActor` (``forward`` on float codes,
    ``logits_from_channels`` on the encoded channels) with a few kB of weights; the last action dominates the logits
    so that the argmax is well defined under quantization noise."""

    def __init__(self, seed: int = 0) -> None:
        super().__init__()
        torch.manual_seed(seed)
        self.conv = nn.Conv2d(6, 4, kernel_size=8, stride=8)
        self.maps = nn.Linear(4 * 29 * 29, NUM_ACTIONS)
        self.last = nn.Linear(NUM_ACTIONS, NUM_ACTIONS)
        with torch.no_grad():
            self.maps.weight.mul_(0.1)
            self.last.weight.copy_(4.0 * torch.roll(torch.eye(NUM_ACTIONS), 1, dims=0))

    def forward(self, high: torch.Tensor, thres: torch.Tensor, last_action: torch.Tensor) -> torch.Tensor:
        return self.logits_from_channels(torch.cat([encode_codes(high), encode_codes(thres)], dim=1), last_action)

    def logits_from_channels(self, channels: torch.Tensor, last_action: torch.Tensor) -> torch.Tensor:
        x = torch.relu(self.conv(channels))
        return self.maps(torch.flatten(x, 1)) + self.last(last_action)


def make_fixtures() -> None:
    """Write ``tiny_unet.safetensors`` and its onnx2tf int8 conversion ``tiny_predictor_int8.tflite``."""
    import tempfile

    from edge_explorer.export.calibration import predictor_observations
    from edge_explorer.export.networks import predictor_network
    from edge_explorer.export.onnx_formats import export_fp32
    from edge_explorer.export.recipe import CalibrationConfig
    from edge_explorer.export.tflite import convert, finalize_tflite

    DATA.mkdir(exist_ok=True)
    obs = predictor_observations(CalibrationConfig(plans=2, held_back_plans=1, per_plan=4), "map")
    windows = torch.from_numpy(np.concatenate([f["map"] for f in obs.calibration]))
    save_unet(tiny_unet(windows), TINY_UNET)
    network = predictor_network(load_unet(TINY_UNET), TINY_UNET)
    with tempfile.TemporaryDirectory() as tmp:
        onnx_path = Path(tmp) / "tiny.onnx"
        export_fp32(network, onnx_path)
        convert(onnx_path, TINY_TFLITE, obs.calibration, True, Path(tmp) / "work")
    finalize_tflite(TINY_TFLITE, list(network.inputs), network.outputs, network.metadata)


if __name__ == "__main__":
    make_fixtures()
