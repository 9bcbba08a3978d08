"""How much int8 rounding of the ReLU activations alone moves a predictor's output (torch fake quantization).

    python docs/predictor/gpu_h100/activation_rounding.py WEIGHTS.safetensors [...]

For each folded predictor: mean |ΔP(occupied)| over unobserved cells of the export's calibration observations
(quantize/predictor.toml: 16 val plans x 8) when (a) the weights are rounded per channel, (b) every ReLU tensor is
rounded to 256 levels of its maximum, (c) both; then (b) one layer at a time. Session 13 used it to find that the
H100 runs' int8 failures come from the stem's activations, not from the weights (docs/predictor/at_scale.md).
"""

import copy
import sys

import numpy as np
import torch
from torch import nn

from edge_explorer.export.calibration import predictor_observations
from edge_explorer.export.recipe import CalibrationConfig
from edge_explorer.learn.unet import load_unet


def rounded_weights(model: nn.Module) -> nn.Module:
    model = copy.deepcopy(model)
    for module in model.modules():
        if isinstance(module, nn.Conv2d):
            w = module.weight.data
            step = w.abs().amax(dim=(1, 2, 3), keepdim=True) / 127
            module.weight.data = torch.round(w / step) * step
    return model


def rounded_activations(model: nn.Module, tops: list[float | None]) -> nn.Module:
    model = copy.deepcopy(model)
    relus = [m for m in model.modules() if isinstance(m, nn.ReLU)]
    for module, top in zip(relus, tops, strict=True):
        if top is not None:
            step = top / 255
            module.register_forward_hook(lambda _m, _i, o, s=step: torch.clamp(torch.round(o / s), 0, 255) * s)
    return model


@torch.no_grad()
def main(paths: list[str]) -> None:
    obs = predictor_observations(CalibrationConfig(plans=16, held_back_plans=1, per_plan=8), "x")
    x = torch.from_numpy(np.concatenate([f["x"] for f in obs.calibration]))
    unobserved = x.sum(1) == 0
    for path in paths:
        model = load_unet(path).eval()
        relus = [m for m in model.modules() if isinstance(m, nn.ReLU)]
        tops: list[float] = [0.0] * len(relus)
        hooks = [m.register_forward_hook(lambda _m, _i, o, k=k, t=tops: t.__setitem__(k, float(o.amax())))
                 for k, m in enumerate(relus)]  # fmt: skip
        p = model(x)
        for hook in hooks:
            hook.remove()

        def error(q: nn.Module, reference: torch.Tensor = p) -> float:
            return float((q(x) - reference)[:, 0][unobserved].abs().mean())

        both = rounded_activations(rounded_weights(model), tops)
        print(f"{path}: weights {error(rounded_weights(model)):.4f}  activations "
              f"{error(rounded_activations(model, tops)):.4f}  both {error(both):.4f}")  # fmt: skip
        for k in range(len(tops)):
            alone = [None] * len(tops)
            alone[k] = tops[k]
            print(f"   ReLU {k:2d} alone (range {tops[k]:5.1f}): {error(rounded_activations(model, alone)):.4f}")


if __name__ == "__main__":
    main(sys.argv[1:])
