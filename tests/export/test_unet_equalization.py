"""export.unet_equalization: the equalized and the grid-aligned U-Nets compute the same function, the first with its
channels spread over each tensor's int8 range, the second with an unobserved area's interior values exactly on the
int8 grid (with "int8 grid": as the int8 network computes them, upstream tensors rounded); the export picks the
candidate with the least fake-quantization error."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from edge_explorer.export.unet_equalization import (
    ALIGNMENTS,
    align_unknown_to_grid,
    candidate_label,
    choose_equalization,
    equalize_unet,
    fake_quant_error,
)
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


def test_the_choice_is_the_candidate_with_the_least_error_and_plain_is_the_network_itself():
    model, feeds = _fused_unet_with_uneven_channels(), _feeds()
    chosen, label, errors = choose_equalization(model, feeds, strengths=(0.0, 1.0))
    assert set(errors) == {candidate_label(s, a) for s in (0.0, 1.0) for a in ALIGNMENTS}
    assert errors[label] == min(errors.values())
    assert errors[candidate_label(0.0, "")] == pytest.approx(fake_quant_error(model, feeds))
    only_plain, plain_label, _ = choose_equalization(model, feeds, strengths=(0.0,), alignments=("",))
    assert only_plain is model and plain_label == "strength 0"
    with pytest.raises(ValueError, match="alignment"):
        choose_equalization(model, feeds, strengths=(0.0,), alignments=("grid please",))


def _interior_values(model: UNet, size: int = 32) -> list[torch.Tensor]:
    """Each ReLU tensor's value at the centre of an all-unobserved (all-zero) window."""
    values: list[torch.Tensor] = []
    relus = [m for m in model.modules() if isinstance(m, torch.nn.ReLU)]
    hooks = [m.register_forward_hook(lambda _m, _i, o: values.append(o[0, :, o.shape[2] // 2, o.shape[3] // 2]))
             for m in relus]  # fmt: skip
    with torch.no_grad():
        model(torch.zeros(1, 2, size, size))
    for hook in hooks:
        hook.remove()
    return values


def _positive_bias_unet() -> UNet:
    torch.manual_seed(1)
    model = UNet(UNetConfig(channels=(4, 8, 8), head_channels=4, batchnorm=False)).eval()
    with torch.no_grad():  # positive biases: every channel has something to align inside an unobserved area
        for module in model.modules():
            if isinstance(module, torch.nn.Conv2d):
                module.bias.abs_().add_(0.05)
    return model


def test_grid_alignment_keeps_the_function_and_puts_unobserved_interiors_on_the_int8_grid():
    model, feeds = _positive_bias_unet(), _feeds()
    aligned = align_unknown_to_grid(model, feeds)
    x = torch.from_numpy(np.concatenate(feeds))
    with torch.no_grad():
        assert torch.allclose(aligned(x), model(x), atol=1e-5)
        relus = [m for m in aligned.modules() if isinstance(m, torch.nn.ReLU)]
        tops = [0.0] * len(relus)
        hooks = [m.register_forward_hook(lambda _m, _i, o, k=k: tops.__setitem__(k, float(o.amax())))
                 for k, m in enumerate(relus)]  # fmt: skip
        aligned(x)
        for hook in hooks:
            hook.remove()
    before = _interior_values(model)
    after = _interior_values(aligned)
    # the stem reads zeros inside an unobserved area: its value is the bias, exact in float, so exactly on the grid
    steps = after[0] / (tops[0] / 255.0)
    sets_the_top = _stem_channel_maxima(aligned, feeds) >= tops[0]  # that channel keeps its scale, and the top
    assert int(sets_the_top.sum()) == 1
    assert torch.allclose(steps[~sets_the_top], torch.round(steps[~sets_the_top]), atol=1e-3)
    steps_before = before[0] / (tops[0] / 255.0)  # the top is kept: the channel that sets it is not rescaled
    assert float((steps_before - torch.round(steps_before)).abs().mean()) > 0.05  # it was off the grid before
    assert fake_quant_error(aligned, feeds) < fake_quant_error(model, feeds)


def _int8_interiors(model: UNet, feeds: list[np.ndarray], size: int = 32) -> tuple[list[torch.Tensor], list[float]]:
    """As the int8 network computes an all-unobserved window: weights rounded per output channel, every ReLU tensor
    rounded to 256 levels of its maximum over ``feeds``; returns each tensor's centre value *before* its own
    rounding (in steps of its grid) and its maximum."""
    model = copy.deepcopy(model)
    relus = [m for m in model.modules() if isinstance(m, torch.nn.ReLU)]
    tops = [0.0] * len(relus)
    hooks = [m.register_forward_hook(lambda _m, _i, o, k=k: tops.__setitem__(k, max(tops[k], float(o.amax()))))
             for k, m in enumerate(relus)]  # fmt: skip
    with torch.no_grad():
        model(torch.from_numpy(np.concatenate(feeds)))
        for hook in hooks:
            hook.remove()
        for module in model.modules():
            if isinstance(module, torch.nn.Conv2d):
                step = module.weight.abs().amax(dim=(1, 2, 3), keepdim=True) / 127.0
                module.weight.copy_(torch.round(module.weight / step) * step)
        in_steps: list[torch.Tensor] = []

        def rounding(k: int):  # noqa: ANN202 - a forward hook
            def hook(_m, _i, o):  # noqa: ANN001, ANN202
                step = tops[k] / 255.0
                in_steps.append(o[0, :, o.shape[2] // 2, o.shape[3] // 2] / step)
                return torch.clamp(torch.round(o / step), 0, 255) * step

            return hook

        for k, m in enumerate(relus[:2]):  # the stem's two tensors: the second reads the first, rounded
            m.register_forward_hook(rounding(k))
        model(torch.zeros(1, 2, size, size))
    return in_steps, tops


def test_int8_grid_alignment_puts_interiors_on_the_grid_as_the_int8_network_computes_them():
    model, feeds = _positive_bias_unet(), _feeds()
    aligned = align_unknown_to_grid(model, feeds, int8_upstream=True)
    x = torch.from_numpy(np.concatenate(feeds))
    with torch.no_grad():
        assert torch.allclose(aligned(x), model(x), atol=1e-5)
    in_steps, tops = _int8_interiors(aligned, feeds)
    second = in_steps[1]  # the stem's second tensor, from the first one rounded to int8
    sets_the_top = second >= second.max() - 1e-6
    off_grid = (second - torch.round(second)).abs()[~sets_the_top]
    assert float(off_grid.max()) < 1e-2
    before, _ = _int8_interiors(model, feeds)
    assert float((before[1] - torch.round(before[1])).abs().mean()) > 0.05  # it was off the grid before


def test_a_unet_with_batchnorm_is_refused():
    with pytest.raises(ValueError, match="fused"):
        equalize_unet(UNet(UNetConfig(channels=(4, 8), head_channels=4)), _feeds(1))
