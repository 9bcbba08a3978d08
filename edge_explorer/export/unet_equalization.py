"""Rewrites of the map predictor's U-Net before int8 quantization: the same function, better int8.

Two rewrites, both per-channel rescalings of ReLU tensors: cross-layer equalization (:func:`equalize_unet`) and the
alignment of unobserved areas' interior values to the int8 grid (:func:`align_unknown_to_grid`, which made the
2026-11-26 H100 weights pass the export's gate: 82.7 % → 99.3 % cell agreement). The export tries combinations of
both and keeps the one with the least fake-quantized error on the calibration feeds (:func:`choose_equalization`).

Equalization:

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


class _Topology:
    """The fused U-Net's ReLU blocks by name, their convolutions, who reads each block's output and which block's
    output is concatenated with it: ``a_k`` / ``b_k`` the two convolutions of encoder level ``k``, ``u_k`` the
    decoder block that outputs level ``k``'s width, ``h`` the head's 3×3 block; ``order`` is topological."""

    def __init__(self, net: UNet) -> None:
        self.net = net
        levels = len(net.down)
        self.blocks: dict[str, nn.Module] = {}
        for k, level in enumerate(net.down):
            self.blocks[f"a{k}"], self.blocks[f"b{k}"] = level[0], level[1]
        for j, block in enumerate(net.up):
            self.blocks[f"u{levels - 2 - j}"] = block
        self.blocks["h"] = net.head[0]
        encoder = [f"{part}{k}" for k in range(levels) for part in "ab"]
        self.order = [*encoder, *(f"u{k}" for k in reversed(range(levels - 1))), "h"]
        self.convs = {name: _conv(block) for name, block in self.blocks.items()}
        # consumers of each tensor: (convolution, first input channel); partner: the tensor concatenated with it
        self.consumers: dict[str, list[tuple[nn.Conv2d, int]]] = {name: [] for name in self.blocks}
        self.partners: dict[str, str | None] = {name: None for name in self.blocks}
        for k in range(levels):
            self.consumers[f"a{k}"].append((self.convs[f"b{k}"], 0))
            if k + 1 < levels:
                self.consumers[f"b{k}"].append((self.convs[f"a{k + 1}"], 0))
        for k in range(levels - 1):  # decoder block u_k reads cat(upsample(deeper), b_k)
            deeper = f"b{levels - 1}" if k == levels - 2 else f"u{k + 1}"
            self.consumers[deeper].append((self.convs[f"u{k}"], 0))
            self.consumers[f"b{k}"].append((self.convs[f"u{k}"], net.config.channels[k + 1]))
            self.partners[deeper], self.partners[f"b{k}"] = f"b{k}", deeper
        self.consumers["u0"].append((self.convs["h"], 0))  # the head reads cat(upsample(u_0), input map): unscaled
        self.consumers["h"].append((net.head[1], 0))

    @torch.no_grad()
    def outputs(self, net_input: torch.Tensor) -> dict[str, torch.Tensor]:
        """Every ReLU block's output for ``net_input``."""
        outs: dict[str, torch.Tensor] = {}
        hooks = [b.register_forward_hook(lambda _m, _i, o, n=n: outs.__setitem__(n, o)) for n, b in self.blocks.items()]
        try:
            self.net(net_input)
        finally:
            for hook in hooks:
                hook.remove()
        return outs

    def channel_maxima(self, feeds: Sequence[np.ndarray]) -> dict[str, torch.Tensor]:
        """Each ReLU tensor's per-channel maximum over ``feeds``."""
        maxima: dict[str, torch.Tensor] = {}
        for feed in feeds:
            x = torch.from_numpy(np.asarray(feed, np.float32))
            for name, out in self.outputs(x if x.ndim == 4 else x[None]).items():
                r = out.amax(dim=(0, 2, 3))
                maxima[name] = torch.maximum(maxima[name], r) if name in maxima else r
        return maxima

    def top(self, name: str, maxima: dict[str, torch.Tensor]) -> torch.Tensor:
        """The maximum that sets tensor ``name``'s int8 scale: its own, or over a skip concatenation's two parts
        (one int8 scale for the concatenated tensor in TFLite); ``u0`` shares the head concat's with the 0/1 map."""
        top = maxima[name].max()
        if self.partners[name] is not None:
            top = torch.maximum(top, maxima[self.partners[name]].max())
        return torch.maximum(top, torch.tensor(1.0)) if name == "u0" else top

    @torch.no_grad()
    def rescale(self, name: str, scale: torch.Tensor) -> None:
        """Multiply tensor ``name``'s channels by ``scale`` (> 0) and divide its consumers' inputs back."""
        self.convs[name].weight.mul_(scale[:, None, None, None])
        self.convs[name].bias.mul_(scale)
        for conv, start in self.consumers[name]:
            conv.weight[:, start : start + len(scale)] /= scale[None, :, None, None]


@torch.no_grad()
def equalize_unet(net: UNet, feeds: Sequence[np.ndarray], strength: float = 1.0, cap: float = 16.0) -> UNet:
    """A copy of the fused ``net`` with every ReLU tensor's channels rescaled towards its int8 range (see the module
    docstring); ``feeds`` are encoded windows (N, 2, H, W) or (2, H, W) as the calibration reads them."""
    if not 0.0 < strength <= 1.0 or cap < 1.0:
        raise ValueError(f"need 0 < strength <= 1 and cap >= 1, got strength={strength}, cap={cap}")
    net = copy.deepcopy(net).eval()
    topology = _Topology(net)
    maxima = topology.channel_maxima(feeds)
    for name, r in maxima.items():
        top = topology.top(name, maxima)
        s = torch.where(r > 0, (top / r.clamp_min(1e-12)) ** strength, torch.ones_like(r)).clamp(max=cap)
        topology.rescale(name, s)
    return net


@torch.no_grad()
def align_unknown_to_grid(net: UNet, feeds: Sequence[np.ndarray], int8_upstream: bool = False) -> UNet:
    """A copy of the fused ``net`` whose ReLU tensors hold the value they take deep inside an unobserved region
    exactly on their int8 grid — the same function, channels rescaled as in :func:`equalize_unet`.

    Why: an unobserved cell is encoded as all-zero input, so far from the observed area every ReLU tensor is one
    constant per channel. Per-tensor int8 rounding moves that constant by the same fraction of a step over thousands
    of cells: not noise but a bias, which the decoder turns into P(occupied) shifts of tenths over whole unknown
    areas (the 2026-11-26 H100 trainings; docs/predictor/at_scale.md). Channel ``c`` with interior value ``v_c`` is
    scaled by ``n·step / v_c`` with ``n = round(v_c / step)`` (at least 1), ``step = top / 255`` the tensor's int8
    step over ``feeds`` (asymmetric int8 of a ReLU tensor: 0 and every multiple of ``step`` are exact), never past
    the tensor's top; the channel that sets the top keeps it. Tensors go in topological order and each interior value
    is computed with the weights rounded per output channel to int8, as the export will round them — and with
    ``int8_upstream`` every tensor upstream rounded to its grid too, as the int8 network computes it (a channel left
    off its grid, e.g. the one that sets the top, moves the next tensor's interior; session 16's H100 weights need
    this, the shipped session-13 weights align better without it: the export tries both).
    """
    net = copy.deepcopy(net).eval()
    topology = _Topology(net)
    maxima = topology.channel_maxima(feeds)
    shape = np.shape(feeds[0])[-3:]
    steps = {name: float(topology.top(name, maxima)) / 255.0 for name in topology.order}  # no rescale moves a top
    for k, name in enumerate(topology.order):
        r, top, step = maxima[name], topology.top(name, maxima), steps[name]
        upstream = {done: steps[done] for done in topology.order[:k]} if int8_upstream else {}
        interior = _int8_outputs(net, upstream, torch.zeros(1, *shape))[name][0]
        value = interior[:, interior.shape[-2] // 2, interior.shape[-1] // 2]
        n = torch.round(value / step).clamp_min(1.0)
        n = torch.where(r * n * step / value.clamp_min(1e-12) > top, torch.floor(value / step), n)
        keep = (value <= 0) | (n < 1) | (r >= top)  # nothing to align, or it would leave the range or move the top
        scale = torch.where(keep, torch.ones_like(value), n * step / value.clamp_min(1e-12))
        topology.rescale(name, scale)
        maxima[name] = r * scale
    return net


def _int8_outputs(net: UNet, steps: dict[str, float], net_input: torch.Tensor) -> dict[str, torch.Tensor]:
    """Every ReLU block's output with the weights rounded as the export rounds them and the blocks named in
    ``steps`` rounded to their int8 grid (0..255 steps): what the int8 network computes upstream of the others."""
    topology = _Topology(_rounded_weights(net))

    def rounded(step: float):  # noqa: ANN202 - a forward hook
        return lambda _m, _i, o: torch.clamp(torch.round(o / step), 0, 255) * step

    hooks = [topology.blocks[name].register_forward_hook(rounded(step)) for name, step in steps.items()]
    try:
        return topology.outputs(net_input)
    finally:
        for hook in hooks:
            hook.remove()


def _rounded_weights(net: nn.Module) -> nn.Module:
    """A copy with every convolution's weights rounded to int8 per output channel (symmetric), as the export does."""
    net = copy.deepcopy(net)
    for module in net.modules():
        if isinstance(module, nn.Conv2d):
            step = module.weight.abs().amax(dim=(1, 2, 3), keepdim=True).clamp_min(1e-12) / 127.0
            module.weight.data = torch.round(module.weight.data / step) * step
    return net


def _batch(feeds: Sequence[np.ndarray]) -> torch.Tensor:
    return torch.cat([torch.from_numpy(np.asarray(f, np.float32)).reshape(-1, *np.shape(f)[-3:]) for f in feeds])


@torch.no_grad()
def fake_quant_error(net: UNet, feeds: Sequence[np.ndarray]) -> float:
    """Mean |ΔP(occupied)| over the feeds' unobserved cells when the weights are rounded to int8 per output channel
    and every ReLU tensor to 256 levels over its range on the same feeds (per-tensor int8 activations): the part of
    the int8 error that the rewrites of this module change."""
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

    quantized_net = _rounded_weights(net)
    quantized_relus = [m for m in quantized_net.modules() if isinstance(m, nn.ReLU)]
    for k, m in enumerate(quantized_relus):
        m.register_forward_hook(rounded(k))
    quantized = quantized_net(x)
    unobserved = (x.sum(dim=1, keepdim=True) == 0).expand_as(reference)
    return float((quantized - reference).abs()[unobserved].mean())


# How a candidate's unobserved interiors are aligned (:func:`align_unknown_to_grid`): not at all, with the weights
# rounded, or with the weights and the upstream tensors rounded.
ALIGNMENTS = ("", "grid", "int8 grid")


def candidate_label(strength: float, alignment: str) -> str:
    """How :func:`choose_equalization` names a candidate in its errors and in the export's metadata."""
    return f"strength {strength:g}" + (f" + {alignment}" if alignment else "")


def choose_equalization(
    net: UNet,
    feeds: Sequence[np.ndarray],
    strengths: Sequence[float] = CANDIDATE_STRENGTHS,
    alignments: Sequence[str] = ALIGNMENTS,
) -> tuple[UNet, str, dict[str, float]]:
    """(network, label, {label: fake_quant_error}) for the candidate with the least error on ``feeds`` —
    calibration observations only, never the gates' held-back ones. A candidate is an equalization strength
    (0: ``net`` itself), optionally followed by :func:`align_unknown_to_grid` in one of :data:`ALIGNMENTS`; labels
    by :func:`candidate_label`."""
    errors, nets = {}, {}
    for strength in strengths:
        equalized = net if strength == 0 else equalize_unet(net, feeds, strength)
        for alignment in alignments:
            label = candidate_label(strength, alignment)
            if alignment not in ALIGNMENTS:
                raise ValueError(f"alignment {alignment!r} is not one of {ALIGNMENTS}")
            if alignment:
                nets[label] = align_unknown_to_grid(equalized, feeds, int8_upstream=alignment == "int8 grid")
            else:
                nets[label] = equalized
            errors[label] = fake_quant_error(nets[label], feeds)
    best = min(errors, key=errors.__getitem__)
    return nets[best], best, errors
