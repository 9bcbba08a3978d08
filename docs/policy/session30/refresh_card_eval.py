"""Refresh the shipped policy card's building evaluation (and so its flight-ready verdict) after a change to the
shared planner loop re-flew the benchmark with the same weights (session 30: the follower's unseen clearance). The
weights, their training record and the export's artifacts stay as they are; ``train ship-policy --eval`` would
rebuild the whole card from the training runs' folders, which live on the machine that trained them.

    python docs/policy/session30/refresh_card_eval.py runs/s30/bench/bundled.json
"""

import json
import sys
from pathlib import Path

from edge_explorer.learn.goal_card import building_evaluation, flight_ready


def main(report: str, card_path: str = "models/policy/card.json") -> None:
    path = Path(card_path)
    card = json.loads(path.read_text())
    buildings = building_evaluation(Path(report), card["sha256"])  # refuses a report that flew other weights
    card["evaluation_buildings"] = buildings
    card["flight_ready"] = flight_ready(buildings["summary_all"])
    path.write_text(json.dumps(card, indent=1) + "\n")
    print(f"{path}: {card['flight_ready']['why']} → flight ready {card['flight_ready']['ready']}")


if __name__ == "__main__":
    main(*sys.argv[1:])
