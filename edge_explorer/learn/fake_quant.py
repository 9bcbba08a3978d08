"""Quantization-aware training for the map predictor: every ReLU tensor rounded to int8's 256 levels in the forward
pass, the gradient passed straight through (the straight-through estimator).

Why: post-training int8 (``edge-explorer export``) keeps one scale per activation tensor. Some trainings of the same
U-Net learn to read differences in the stem's activations smaller than one int8 step, and their int8 export then
moves P(occupied) of unobserved cells by tenths (the 2026-11-26 lease's runs failed the export's 99 % cell-agreement
gate at 65–83 %; docs/predictor/at_scale.md). Fine-tuning with the rounding in the loop teaches the network not to
depend on what int8 cannot represent.

The range of each tensor is the batch's own maximum (ReLU outputs start at 0), so the rounding has no state: a
resumed run rounds exactly as the uninterrupted one, and the checkpoint format is unchanged. The export's
calibration takes the maximum over its observations, of the same order as a training batch's.
"""

from __future__ import annotations

import torch
from torch import nn

INT8_LEVELS = 255  # steps between 0 and the tensor's maximum (an asymmetric int8 range over [0, max])


def fake_quantize(x: torch.Tensor) -> torch.Tensor:
    """``x`` (≥ 0) rounded to ``INT8_LEVELS`` steps of its own maximum in the forward pass; identity gradient."""
    step = x.detach().amax().clamp_min(1e-8) / INT8_LEVELS
    return x + (torch.round(x.detach() / step) * step - x.detach())


def attach_fake_quant(model: nn.Module) -> list[torch.utils.hooks.RemovableHandle]:
    """Round every ReLU output of ``model`` (training and evaluation alike) until the returned handles are removed."""
    return [m.register_forward_hook(lambda _m, _i, out: fake_quantize(out)) for m in model.modules()
            if isinstance(m, nn.ReLU)]  # fmt: skip
