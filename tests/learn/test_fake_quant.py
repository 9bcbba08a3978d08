"""learn.fake_quant: int8 rounding of ReLU tensors in the forward pass, straight-through gradient."""

from __future__ import annotations

import torch

from edge_explorer.learn.fake_quant import INT8_LEVELS, attach_fake_quant, fake_quantize
from edge_explorer.learn.unet import UNet, UNetConfig


def test_values_land_on_256_levels_of_the_tensor_maximum_within_half_a_step():
    x = torch.rand(2, 3, 8, 8) * 7.0
    q = fake_quantize(x)
    step = float(x.max()) / INT8_LEVELS
    assert len(torch.unique(q)) <= INT8_LEVELS + 1
    assert float((q - x).abs().max()) <= step / 2 + 1e-6
    assert torch.allclose(q / step, torch.round(q / step), atol=1e-4)


def test_the_gradient_passes_straight_through():
    x = (torch.rand(4, 4) * 3.0).requires_grad_()
    (fake_quantize(x) * torch.arange(16.0).reshape(4, 4)).sum().backward()
    assert torch.equal(x.grad, torch.arange(16.0).reshape(4, 4))


@torch.no_grad()
def test_attached_rounding_changes_a_unet_until_removed():
    torch.manual_seed(0)
    model = UNet(UNetConfig(channels=(4, 8), head_channels=4)).eval()
    x = (torch.rand(2, 2, 32, 32) > 0.7).float()
    plain = model.logits(x)
    handles = attach_fake_quant(model)
    rounded = model.logits(x)
    assert len(handles) == sum(isinstance(m, torch.nn.ReLU) for m in model.modules())
    assert not torch.allclose(plain, rounded) and float((plain - rounded).abs().max()) < 1.0
    for handle in handles:
        handle.remove()
    assert torch.equal(model.logits(x), plain)
