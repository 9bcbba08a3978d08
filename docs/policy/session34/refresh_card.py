"""Refresh the shipped policy card after a change to how the planner ranks the policy's goals (session 34: the path-
cost weight): the building evaluation and flight-ready verdict from a re-flown benchmark (as
``session30/refresh_card_eval.py``) and the card's ``decision`` from today's ``PredictiveConfig``. The weights, their
training record and the export's artifacts stay as they are.

    python docs/policy/session34/refresh_card.py runs/s34/bench/bundled.json
"""

import json
import sys
from pathlib import Path

from edge_explorer.learn.goal_card import building_evaluation, flight_ready
from edge_explorer.plan.predictive import PredictiveConfig


def main(report: str, card_path: str = "models/policy/card.json") -> None:
    path = Path(card_path)
    card = json.loads(path.read_text())
    buildings = building_evaluation(Path(report), card["sha256"])  # refuses a report that flew other weights
    card["evaluation_buildings"] = buildings
    card["flight_ready"] = flight_ready(buildings["summary_all"])
    card["decision"] = {"policy_cost_weight_per_m": PredictiveConfig().policy_cost_weight_per_m}
    path.write_text(json.dumps(card, indent=1) + "\n")
    print(f"{path}: {card['flight_ready']['why']} → flight ready {card['flight_ready']['ready']}; {card['decision']}")


if __name__ == "__main__":
    main(*sys.argv[1:])
