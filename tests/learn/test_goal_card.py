"""The goal policy's card: the flight-ready verdict and the evaluation that must have flown these very weights."""

from __future__ import annotations

import json

import pytest
import torch

from edge_explorer.errors import EdgeExplorerError
from edge_explorer.learn.goal_card import count_macs, flight_ready, ship_goal_policy
from edge_explorer.learn.goal_net import GoalNet, GoalNetConfig, save_goal_net

TINY = GoalNetConfig(encoder=(4, 4, 4, 4), decoder=(4, 4))


def summary(success_rate: float, collisions: int) -> dict:
    return {"frontier+pred": {"success_rate": 1.0, "collisions": 0, "runs": 40},
            "drl+pred": {"success_rate": success_rate, "collisions": collisions, "runs": 40}}  # fmt: skip


def test_flight_ready_needs_98_percent_success_and_no_collision():
    assert flight_ready(summary(1.0, 0))["ready"]
    assert flight_ready(summary(0.98, 0))["ready"]
    assert not flight_ready(summary(0.975, 0))["ready"]
    verdict = flight_ready(summary(1.0, 1))
    assert not verdict["ready"] and "1 collisions (needs 0)" in verdict["why"]
    assert not flight_ready(None)["ready"] and not flight_ready({"frontier": summary(1, 0)["frontier+pred"]})["ready"]


def test_an_evaluation_of_other_weights_is_refused(tmp_path):
    torch.manual_seed(0)
    save_goal_net(GoalNet(TINY), tmp_path / "a.safetensors")
    save_goal_net(GoalNet(TINY), tmp_path / "b.safetensors")  # other random weights
    report = {"command": "c", "plans": "A", "methods": ["drl+pred"], "runs_per_plan": 1, "seed": 0, "paired": [],
              "config": {"policy": str(tmp_path / "b.safetensors")}, "summary": {"all": summary(1.0, 0)}}  # fmt: skip
    (tmp_path / "bench.json").write_text(json.dumps(report))
    with pytest.raises(EdgeExplorerError, match="did not fly these weights"):
        ship_goal_policy(tmp_path / "a.safetensors", [], tmp_path / "out", tmp_path / "bench.json", "c")
    card = ship_goal_policy(tmp_path / "b.safetensors", [], tmp_path / "out", tmp_path / "bench.json", "c")
    assert card["flight_ready"]["ready"] and (tmp_path / "out" / "policy.safetensors").is_file()
    assert card["evaluation_buildings"]["summary_all"]["drl+pred"]["runs"] == 40


def test_macs_count_the_convolutions():
    assert count_macs(GoalNet(TINY)) < count_macs(GoalNet()) and 50e6 < count_macs(GoalNet()) < 200e6
