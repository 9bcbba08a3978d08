"""The learned planner's worth-a-look gain counting a partly predicted corridor as unknown (issue #21, session 35).

The shipped rule (``goal_policy.worth_a_look``) counts the cells a view from a goal shows that are UNKNOWN in the
fused map. A corridor the prediction has begun to fill then shows few such cells, though its frontier is still a
target (``predictive.open_unknown``, the expert's ``open_prediction``): on building D the policy left such a corridor
next to it for a goal 16 m away and came back for it (runs 0 and 6, +20 m each; ``explain_decision.py``). Here the
gain counts ``open_unknown`` cells instead: fused UNKNOWN plus the predicted-free cells connected to them. Flies
``expert_sweep.py``'s val runs with that patch::

    python docs/policy/session35/open_gain_sweep.py --name s35_open_drl40 --first 40 --count 96 \
        --planner drl --policy models/policy/policy.safetensors --workers 2
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

from edge_explorer.plan import goal_policy
from edge_explorer.plan.predictive import open_unknown
from edge_explorer.world.grid import OCCUPIED

_shipped_init = goal_policy._Gains.__init__


def _open_init(self, view, decision, fused_low, config):  # noqa: ANN001 - _Gains.__init__'s signature
    _shipped_init(self, view, decision, fused_low, config)
    self.unknown = open_unknown(view.maps.low, fused_low)
    self.blocking = fused_low == OCCUPIED


def patch() -> None:
    """Make every ``_Gains`` (the worth-a-look measure) count open-unknown cells."""
    goal_policy._Gains.__init__ = _open_init


if __name__ == "__main__":
    patch()
    sys.argv[0] = str(Path(__file__).parents[1] / "expert_sweep.py")
    runpy.run_path(sys.argv[0], run_name="__main__")
