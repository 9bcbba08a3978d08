"""Cross-layer equalization of the map predictor's U-Net before int8 quantization (the same function, better int8).

int8 activations have one scale per tensor. In a trained U-Net some channels of a ReLU tensor span a tenth of the
tensor's range and get a tenth of its 256 levels; the stem's channels carry fine "how far from the observed area"
cues in small values, and losing them moves P(occupied) of unobserved cells by tenths (measured on the 2026-11-26
lease's runs: `docs/predictor/at_scale.md`). Since ``relu(s·x) = s·relu(x)`` for ``s > 0`` and nearest upsampling
and concatenation act per channel, scaling a ReLU block's output channel ``c`` by ``s_c`` (its convolution's weights
and bias) and dividing every consumer's input weights for that channel by ``s_c`` leaves the network's function
unchanged (up to float rounding) while spreading each tensor's channels over its int8 range.

``s_c = min(cap, (top / r_c) ** strength)`` with ``r_c`` the channel's maximum over the calibration feeds and
``top`` the tensor's maximum — or, for the two parts of a skip concatenation (one int8 scale for the concatenated
tensor in TFLite), the maximum over both parts. The goal policy's own equalization is
:func:`edge_explorer.export.networks.equalize_goal_net`; this is the same idea on the U-Net's topology.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from edge_explorer.learn.unet import UNet

# Strengths the export tries (0 = the network as trained); the one whose fake-quantized activations move the
# calibration feeds' probabilities least is exported. Which is best differs between trainings of the same U-Net
# (docs/predictor/at_scale.md, 2026-11-26), hence a choice on the calibration feeds rather than one constant.
CANDIDATE_STRENGTHS = (0.0, 0.5, 1.0)


def _conv(block: nn.Module) -> nn.Conv2d:
    """The convolution of a fused :class:`~edge_explorer.learn.unet.ConvBlock` (conv with bias → ReLU)."""
    conv = block[0]
    if not isinstance(conv, nn.Conv2d) or conv.bias is None or isinstance(block[1], nn.BatchNorm2d):
        raise ValueError("equalize_unet needs a fused U-Net (UNet.fused(): BatchNorm folded into conv biases)")
    return conv


@torch.no_grad()
def equalize_unet(net: UNet, feeds: Sequence[np.ndarray], strength: float = 1.0, cap: float = 16.0) -> UNet:
    """A copy of the fused ``net`` with every ReLU tensor's channels rescaled towards its int8 range (see the module
    docstring); ``feeds`` are encoded windows (N, 2, H, W) or (2, H, W) as the calibration reads them."""
    if not 0.0 < strength <= 1.0 or cap < 1.0:
        raise ValueError(f"need 0 < strength <= 1 and cap >= 1, got strength={strength}, cap={cap}")
    net = copy.deepcopy(net).eval()
    levels = len(net.down)
    # the ReLU blocks, named: a_k / b_k the two convolutions of encoder level k, u_k the decoder block that
    # outputs level k's width, h the head's 3x3 block
    blocks: dict[str, nn.Module] = {}
    for k, level in enumerate(net.down):
        blocks[f"a{k}"], blocks[f"b{k}"] = level[0], level[1]
    for j, block in enumerate(net.up):
        blocks[f"u{levels - 2 - j}"] = block
    blocks["h"] = net.head[0]
    convs = {name: _conv(block) for name, block in blocks.items()}

    ranges: dict[str, torch.Tensor] = {}

    def keep_max(name: str):
        def hook(_module, _inputs, out):
            r = out.amax(dim=(0, 2, 3))
            ranges[name] = torch.maximum(ranges[name], r) if name in ranges else r

        return hook

    hooks = [block.register_forward_hook(keep_max(name)) for name, block in blocks.items()]
    for feed in feeds:
        x = torch.from_numpy(np.asarray(feed, np.float32))
        net(x if x.ndim == 4 else x[None])
    for hook in hooks:
        hook.remove()

    # consumers of each tensor: (convolution, first input channel); partners: the tensor concatenated with it
    consumers: dict[str, list[tuple[nn.Conv2d, int]]] = {name: [] for name in blocks}
    partners: dict[str, str | None] = {name: None for name in blocks}
    for k in range(levels):
        consumers[f"a{k}"].append((convs[f"b{k}"], 0))
        if k + 1 < levels:
            consumers[f"b{k}"].append((convs[f"a{k + 1}"], 0))
    for k in range(levels - 1):  # decoder block u_k reads cat(upsample(deeper), b_k)
        deeper = f"b{levels - 1}" if k == levels - 2 else f"u{k + 1}"
        width = net.config.channels[k + 1]
        consumers[deeper].append((convs[f"u{k}"], 0))
        consumers[f"b{k}"].append((convs[f"u{k}"], width))
        partners[deeper], partners[f"b{k}"] = f"b{k}", deeper
    consumers["u0"].append((convs["h"], 0))  # the head reads cat(upsample(u_0), input map): the map is not scaled
    consumers["h"].append((net.head[1], 0))

    for name, r in ranges.items():
        top = r.max() if partners[name] is None else torch.maximum(r.max(), ranges[partners[name]].max())
        if name == "u0":
            top = torch.maximum(top, torch.tensor(1.0))  # shares the head concat's scale with the 0/1 map
        s = torch.where(r > 0, (top / r.clamp_min(1e-12)) ** strength, torch.ones_like(r)).clamp(max=cap)
        convs[name].weight.mul_(s[:, None, None, None])
        convs[name].bias.mul_(s)
        for conv, start in consumers[name]:
            conv.weight[:, start : start + len(s)] /= s[None, :, None, None]
    return net


def _batch(feeds: Sequence[np.ndarray]) -> torch.Tensor:
    return torch.cat([torch.from_numpy(np.asarray(f, np.float32)).reshape(-1, *np.shape(f)[-3:]) for f in feeds])


@torch.no_grad()
def fake_quant_error(net: UNet, feeds: Sequence[np.ndarray]) -> float:
    """Mean |ΔP(occupied)| over the feeds' unobserved cells when every ReLU tensor is rounded to 256 levels over
    its range on the same feeds (per-tensor int8 activations, weights left in float): the part of the int8 error
    that equalization changes."""
    x = _batch(feeds)
    relus = [m for m in net.modules() if isinstance(m, nn.ReLU)]
    tops: dict[int, float] = {}
    hooks = [m.register_forward_hook(lambda _m, _i, o, k=k: tops.__setitem__(k, float(o.amax())))
             for k, m in enumerate(relus)]  # fmt: skip
    reference = net(x)
    for hook in hooks:
        hook.remove()

    def rounded(k: int):
        step = max(tops[k], 1e-12) / 255.0
        return lambda _m, _i, o: torch.clamp(torch.round(o / step), 0, 255) * step

    hooks = [m.register_forward_hook(rounded(k)) for k, m in enumerate(relus)]
    try:
        quantized = net(x)
    finally:
        for hook in hooks:
            hook.remove()
    unobserved = (x.sum(dim=1, keepdim=True) == 0).expand_as(reference)
    return float((quantized - reference).abs()[unobserved].mean())


def choose_equalization(
    net: UNet, feeds: Sequence[np.ndarray], strengths: Sequence[float] = CANDIDATE_STRENGTHS
) -> tuple[UNet, float, dict[float, float]]:
    """(network, strength, {strength: fake_quant_error}) for the strength with the least error on ``feeds`` —
    calibration observations only, never the gates' held-back ones. Strength 0 is ``net`` itself."""
    errors, nets = {}, {}
    for strength in strengths:
        nets[strength] = net if strength == 0 else equalize_unet(net, feeds, strength)
        errors[strength] = fake_quant_error(nets[strength], feeds)
    best = min(errors, key=errors.__getitem__)
    return nets[best], best, errors
