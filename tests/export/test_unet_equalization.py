"""export.unet_equalization: the equalized U-Net computes the same function with its channels spread over each
tensor's int8 range, and the export picks the strength with the least fake-quantization error."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from edge_explorer.export.unet_equalization import choose_equalization, equalize_unet, fake_quant_error
from edge_explorer.learn.unet import UNet, UNetConfig


def _fused_unet_with_uneven_channels() -> UNet:
    torch.manual_seed(0)
    model = UNet(UNetConfig(channels=(4, 8, 8), head_channels=4, batchnorm=False)).eval()
    with torch.no_grad():  # one stem channel 20x larger than the others: a per-tensor int8 scale starves the rest
        model.down[0][0][0].weight[0].mul_(20.0)
        model.down[0][0][0].bias[0].mul_(20.0)
        model.down[0][1][0].weight[:, 0].div_(20.0)
    return model


def _feeds(count: int = 6) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    return [(rng.random((1, 2, 32, 32)) > 0.6).astype(np.float32) for _ in range(count)]


def _stem_channel_maxima(model: UNet, feeds: list[np.ndarray]) -> torch.Tensor:
    x = torch.from_numpy(np.concatenate(feeds))
    with torch.no_grad():
        return model.down[0][0](x).amax(dim=(0, 2, 3))


def test_equalization_keeps_the_function_and_evens_the_channels():
    model, feeds = _fused_unet_with_uneven_channels(), _feeds()
    equalized = equalize_unet(model, feeds, strength=1.0)
    x = torch.from_numpy(np.concatenate(feeds))
    with torch.no_grad():
        assert torch.allclose(equalized(x), model(x), atol=1e-5)
    before, after = _stem_channel_maxima(model, feeds), _stem_channel_maxima(equalized, feeds)
    assert float(before.min() / before.max()) < 0.2 < float(after.min() / after.max())
    assert fake_quant_error(equalized, feeds) < fake_quant_error(model, feeds)


def test_the_choice_is_the_strength_with_the_least_error_and_zero_is_the_network_itself():
    model, feeds = _fused_unet_with_uneven_channels(), _feeds()
    chosen, strength, errors = choose_equalization(model, feeds, strengths=(0.0, 1.0))
    assert set(errors) == {0.0, 1.0} and errors[strength] == min(errors.values())
    assert errors[0.0] == pytest.approx(fake_quant_error(model, feeds))
    only_plain, plain_strength, _ = choose_equalization(model, feeds, strengths=(0.0,))
    assert only_plain is model and plain_strength == 0.0


def test_a_unet_with_batchnorm_is_refused():
    with pytest.raises(ValueError, match="fused"):
        equalize_unet(UNet(UNetConfig(channels=(4, 8), head_channels=4)), _feeds(1))
