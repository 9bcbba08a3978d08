"""Where a predictor's int8 error comes from (issue #17, session 16): after the export's weights-only grid alignment
('strength 0 + grid'), round the weights to int8 and the ReLU tensors 0..k to their int8 grid (prefix), and all
tensors but k; print the mean |ΔP(occupied)| over the unobserved cells of the export's calibration feeds.

    python docs/predictor/session16/int8_rounding_prefix.py WEIGHTS.safetensors [...]

Session 16's H100 weights: the stem's two tensors rounded together give 0.025 while each alone gives 0.002: rounding
the first moves the second's unobserved interior off the grid it was aligned to (computed with the first in float),
which is what the export's 'int8 grid' alignment fixes (output: int8_rounding_prefix.txt).
"""

import sys

import torch
from torch import nn

from edge_explorer.export import unet_equalization as ue
from edge_explorer.export.calibration import predictor_observations
from edge_explorer.export.recipe import CalibrationConfig
from edge_explorer.learn.unet import load_unet


def error(net: nn.Module, feeds: torch.Tensor, rounded: list[int]) -> float:
    relus = [m for m in net.modules() if isinstance(m, nn.ReLU)]
    tops: dict[int, float] = {}
    hooks = [m.register_forward_hook(lambda _m, _i, o, k=k: tops.__setitem__(k, float(o.amax())))
             for k, m in enumerate(relus)]  # fmt: skip
    with torch.no_grad():
        reference = net(feeds)
    for hook in hooks:
        hook.remove()
    quantized = ue._rounded_weights(net)
    for k, m in enumerate(m for m in quantized.modules() if isinstance(m, nn.ReLU)):
        if k in rounded:
            step = tops[k] / 255
            m.register_forward_hook(lambda _m, _i, o, s=step: torch.clamp(torch.round(o / s), 0, 255) * s)
    with torch.no_grad():
        out = quantized(feeds)
    unobserved = (feeds.sum(dim=1, keepdim=True) == 0).expand_as(reference)
    return float((out - reference).abs()[unobserved].mean())


if __name__ == "__main__":
    calibration = predictor_observations(CalibrationConfig(plans=16, held_back_plans=12, per_plan=8), "map")
    cal = [f["map"] for f in calibration.calibration]
    x = ue._batch(cal)
    for path in sys.argv[1:]:
        net = ue.align_unknown_to_grid(load_unet(path).eval(), cal)
        n = sum(isinstance(m, nn.ReLU) for m in net.modules())
        print(path)
        print(" prefix 0..k:", " ".join(f"{error(net, x, list(range(k + 1))):.4f}" for k in range(n)))
        print(" all but k:  ", " ".join(f"{error(net, x, [j for j in range(n) if j != k]):.4f}" for k in range(n)))
