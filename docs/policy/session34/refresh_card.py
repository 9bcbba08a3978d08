"""Refresh the shipped policy card after a change to how the planner ranks the policy's goals (session 34: the path-
cost weight): the building evaluation and flight-ready verdict from a re-flown benchmark
(session 30's ``refresh_card_eval.py``, run first) and the card's ``decision`` from today's ``PredictiveConfig``
(``goal_card.decision_settings``). The weights, their training record and the export's artifacts stay as they are.

    python docs/policy/session34/refresh_card.py runs/s34/bench/bundled.json
"""

import json
import sys
from pathlib import Path

from edge_explorer.learn.goal_card import decision_settings

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "session30"))
import refresh_card_eval  # noqa: E402


def main(report: str, card_path: str = "models/policy/card.json") -> None:
    refresh_card_eval.main(report, card_path)
    path = Path(card_path)
    card = json.loads(path.read_text())
    card["decision"] = decision_settings()
    path.write_text(json.dumps(card, indent=1) + "\n")
    print(f"{path}: decision {card['decision']}")


if __name__ == "__main__":
    main(*sys.argv[1:])
