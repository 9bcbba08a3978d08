"""The policy card's flight-readiness rule (edge_explorer.learn.policy_card.flight_ready)."""

from edge_explorer.learn.policy_card import flight_ready


def _buildings(success_rate: float, collisions: int) -> dict:
    drl = {"runs": 40, "success_rate": success_rate, "collisions": collisions}
    return {"summary_all": {"drl": drl, "frontier": {"runs": 40, "success_rate": 1.0, "collisions": 0}}}


def test_only_an_evaluated_collision_free_policy_is_flight_ready():
    assert flight_ready(_buildings(0.975, 0))["ready"]
    assert not flight_ready(_buildings(0.975, 1))["ready"]
    low = flight_ready(_buildings(0.9, 0))
    assert not low["ready"] and "90%" in low["why"]
    assert not flight_ready(None)["ready"]
    assert "no drl" in flight_ready({"summary_all": {"frontier": {}}})["why"]
