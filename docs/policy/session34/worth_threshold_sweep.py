"""How many unknown cells make a goal worth a look? (issue #21, session 34)

Since session 33 the learned planner takes the policy's best valid goal whose view shows at least the expert's
``min_gain_cells`` (30) cells unknown in the fused map (``plan/goal_policy.py``, ``_Gains.worth_a_look``). This
sweep flies ``expert_sweep.py``'s val runs with the product code and another threshold for the policy's rule only
(the expert's own fallbacks keep 30)::

    python docs/policy/session34/worth_threshold_sweep.py 15 --name s34_worth15_drl40 --first 40 --count 96 \\
        --planner drl --policy models/policy/policy.safetensors --workers 2
    python docs/policy/expert_sweep.py --compare s34_worth15_drl40 s33_worth_drl40
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

from edge_explorer.plan import goal_policy
from edge_explorer.plan.predictive import visible_unknown

MIN_GAIN = int(sys.argv.pop(1))


def worth_a_look(self, cell: int) -> bool:  # noqa: ANN001 - _Gains.worth_a_look with MIN_GAIN for the threshold
    node = int(self.decision.options.node.flat[cell])
    if node not in self.cells:
        xy = self.view.graph.node_xy_m([node])[0]
        seen = visible_unknown(xy, self.unknown, self.blocking, self.view.maps.low_grid, self.config.sensor.range_m)
        self.cells[node] = len(seen)
    return self.cells[node] >= MIN_GAIN


goal_policy._Gains.worth_a_look = worth_a_look
sys.argv[0] = str(Path(__file__).parents[1] / "expert_sweep.py")
runpy.run_path(sys.argv[0], run_name="__main__")
