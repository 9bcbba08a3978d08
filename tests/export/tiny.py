"""A tiny deterministic network with the predictor's export contract (a few kB of weights).

``make_fixtures`` regenerates the committed ``data/`` files (needs ``make convert-env``)::

    python -m tests.export.tiny
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from edge_explorer.learn.unet import UNet, UNetConfig, load_unet, save_unet

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
