"""The predictor U-Net: shapes, Edge-TPU-friendly ops, BatchNorm folding, safetensors round trip, MACs."""

import numpy as np
import pytest
import torch
from torch import nn

from edge_explorer.learn.unet import TorchPredictor, UNet, UNetConfig, count_macs_params, load_unet, save_unet
from edge_explorer.world.grid import CELL_DTYPE, FREE, OCCUPIED

TINY = UNetConfig(channels=(4, 8, 8), head_channels=2)


def _trained_a_little(config: UNetConfig) -> UNet:
    torch.manual_seed(0)
    model = UNet(config)
    optimizer = torch.optim.SGD(model.parameters(), lr=0.1)
    for _ in range(2):  # BatchNorm running statistics move away from their initial values
        loss = model.logits(torch.rand(2, 2, 32, 32)).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    return model.eval()


def test_output_is_one_probability_channel_of_the_input_size():
    model = UNet(TINY).eval()
    with torch.no_grad():
        y = model(torch.rand(3, 2, 32, 32))
    assert y.shape == (3, 1, 32, 32) and float(y.min()) >= 0 and float(y.max()) <= 1


def test_fused_model_has_only_deployable_ops_and_the_same_output():
    model = _trained_a_little(TINY)
    fused = model.fused()
    kinds = {type(m) for m in fused.modules()}
    assert not kinds & {nn.BatchNorm2d, nn.ConvTranspose2d}
    assert kinds <= {UNet, nn.ModuleList, nn.Sequential, nn.Conv2d, nn.ReLU, nn.Upsample} | {
        type(m) for m in fused.modules() if type(m).__name__ == "ConvBlock"
    }
    x = torch.rand(2, 2, 32, 32)
    with torch.no_grad():
        torch.testing.assert_close(fused(x), model(x), atol=1e-5, rtol=1e-4)
    assert model.config.batchnorm and not fused.config.batchnorm


def test_fusing_leaves_a_training_model_in_training_mode():
    model = UNet(TINY).train()
    model.fused()
    assert all(m.training for m in model.modules())


def test_safetensors_round_trip_and_predictor_callable(tmp_path):
    model = _trained_a_little(TINY).fused()
    path = tmp_path / "unet.safetensors"
    save_unet(model, path)
    loaded = load_unet(path)
    assert loaded.config == model.config
    window = np.zeros((32, 32), dtype=CELL_DTYPE)
    window[10:20, 10] = OCCUPIED
    window[12:18, 12:18] = FREE
    p = TorchPredictor(loaded)(window)
    assert p.shape == (32, 32) and p.dtype == np.float32
    with torch.no_grad():
        expected = model(torch.from_numpy(np.stack([window == FREE, window == OCCUPIED]).astype(np.float32))[None])
    np.testing.assert_allclose(p, expected[0, 0].numpy(), atol=1e-6)


def test_default_model_fits_the_budget():
    macs, params = count_macs_params(UNet())
    assert 0.3e9 < macs < 0.5e9  # DESIGN budget: ≤ 0.5 GMAC per 256×256 prediction
    assert params < 1_000_000


def test_config_validation():
    with pytest.raises(ValueError):
        UNetConfig(channels=(8,))
    assert UNetConfig.from_dict(TINY.to_dict()) == TINY
