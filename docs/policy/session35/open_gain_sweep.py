"""The learned planner's worth-a-look gain counting a partly predicted corridor as unknown (issue #21, session 35;
measured, not adopted).

The shipped rule (``goal_policy.worth_a_look``) counts the cells a view from a goal shows that are UNKNOWN in the
fused map. A corridor the prediction has begun to fill then shows few such cells, though its frontier is still a
target (``predictive.open_unknown``, the expert's ``open_prediction``): on building D the policy left such a corridor
next to it for a goal 16 m away and came back for it (runs 0 and 6, +20 m each; ``explain_decision.py``). Here the
gain also counts the predicted-free cells ``open_unknown`` joins to the fused unknown, those within
``--open-gain-m`` of it (default: all). With ``--expert`` the predictive expert's cluster gain counts them too.
Flies ``expert_sweep.py``'s val runs with that patch (other arguments are ``expert_sweep.py``'s)::

    python docs/policy/session35/open_gain_sweep.py --name s35_open_drl40 --first 40 --count 96 \
        --planner drl --policy models/policy/policy.safetensors --workers 2
    python docs/policy/session35/open_gain_sweep.py --open-gain-m 1.0 --name s35_og1_drl40 --first 40 --count 96 \
        --planner drl --policy models/policy/policy.safetensors --workers 2
    python docs/policy/session35/open_gain_sweep.py --expert --name s35_opengain_40 --first 40 --count 96 --workers 2
"""

from __future__ import annotations

import math
import runpy
import sys
from pathlib import Path

import cv2
import numpy as np

from edge_explorer.plan import goal_policy, predictive
from edge_explorer.plan.predictive import open_unknown
from edge_explorer.world.grid import UNKNOWN

_shipped_init = goal_policy._Gains.__init__


def gain_unknown(
    observed_low: np.ndarray, fused_low: np.ndarray, open_gain_m: float, resolution_m: float
) -> np.ndarray:
    """bool: fused UNKNOWN plus the predicted-free cells of ``open_unknown`` within ``open_gain_m`` of it."""
    unknown = fused_low == UNKNOWN
    if not unknown.any():
        return unknown
    distance_m = cv2.distanceTransform((~unknown).astype(np.uint8), cv2.DIST_L2, 5) * resolution_m
    return unknown | (open_unknown(observed_low, fused_low) & (distance_m <= open_gain_m))


def patch(open_gain_m: float = math.inf) -> None:
    """Make every ``_Gains`` (the worth-a-look measure) count open-unknown cells within ``open_gain_m``."""

    def _open_init(self, view, decision, fused_low, config):  # noqa: ANN001 - _Gains.__init__'s signature
        _shipped_init(self, view, decision, fused_low, config)
        self.unknown = gain_unknown(view.maps.low, fused_low, open_gain_m, view.maps.low_grid.resolution_m)

    goal_policy._Gains.__init__ = _open_init


def patch_expert(open_gain_m: float = math.inf) -> None:
    """Make the expert's cluster gain (``PredictiveFrontier.cluster_options``) count the same cells: its fused map
    is seen through a copy whose open-unknown cells read UNKNOWN while the gain is measured."""
    shipped = predictive.PredictiveFrontier.cluster_options

    def cluster_options(self, view, cost_m):  # noqa: ANN001, ANN202 - cluster_options' signature
        fused = self._fused if self._fused is not None else view.maps.low
        counted = fused.copy()
        counted[gain_unknown(view.maps.low, fused, open_gain_m, view.maps.low_grid.resolution_m)] = UNKNOWN
        self._fused = counted
        try:
            return shipped(self, view, cost_m)
        finally:
            self._fused = fused

    predictive.PredictiveFrontier.cluster_options = cluster_options


if __name__ == "__main__":
    limit = math.inf
    if "--open-gain-m" in sys.argv:
        at = sys.argv.index("--open-gain-m")
        limit = float(sys.argv[at + 1])
        del sys.argv[at : at + 2]
    patch(limit)
    if "--expert" in sys.argv:
        sys.argv.remove("--expert")
        patch_expert(limit)
    sys.argv[0] = str(Path(__file__).parents[1] / "expert_sweep.py")
    runpy.run_path(sys.argv[0], run_name="__main__")
