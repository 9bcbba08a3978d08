"""The daemon thresholds with the shipped predictor's calibrated thresholds (edge_explorer.runtime.flight)."""

from __future__ import annotations

import json

import pytest

from edge_explorer.predict.thresholding import ThresholdConfig
from edge_explorer.runtime import daemon as daemon_module
from edge_explorer.runtime.daemon import choose_models
from edge_explorer.runtime.flight import fly
from edge_explorer.runtime.options import RunOptions
from edge_explorer.sim.flight import SimulatedFlight
from edge_explorer.world.plan import save_plan_json
from tests.conftest import two_room_plan
from tests.predict.test_predictor import add_thresholds, write_predictor_model

ORDER = ("onnxruntime-cpu",)
CALIBRATED = ThresholdConfig(t_f_max=0.1, t_o=0.9)


class _Built(Exception):
    """Raised by the stand-in daemon once the flight has built its configuration."""


def test_the_loaded_predictor_carries_its_card_s_thresholds(tmp_path):
    card = write_predictor_model(tmp_path / "models" / "predictor")
    assert choose_models(tmp_path / "models", "frontier", ORDER).predictor.thresholds == ThresholdConfig()
    add_thresholds(card, {"t_f_max": 0.1, "t_o": 0.9})
    assert choose_models(tmp_path / "models", "frontier", ORDER).predictor.thresholds == CALIBRATED


def test_the_daemon_loads_the_whole_floor_model_the_predictor_s_card_names_and_flies_on_without_a_bad_one(tmp_path):
    card = write_predictor_model(tmp_path / "models" / "predictor")
    floors = write_predictor_model(tmp_path / "models" / "predictor_floors", gain=20.0)
    add_thresholds(floors, {"t_f_max": 0.2, "t_o": 0.8})
    choice = choose_models(tmp_path / "models", "frontier", ORDER)
    assert choice.predictor.beyond is None and "whole-floor predictor: none" in choice.notes[-1]
    doc = json.loads(card.read_text())
    doc["beyond_envelope"] = "predictor_floors"
    card.write_text(json.dumps(doc))
    choice = choose_models(tmp_path / "models", "frontier", ORDER)
    assert choice.predictor.thresholds == ThresholdConfig(beyond=ThresholdConfig(t_f_max=0.2, t_o=0.8))
    assert choice.predictor.beyond is not None
    assert choice.notes[-1].startswith("whole-floor predictor: predictor: onnxruntime-cpu")
    (floors.parent / "predictor_fp32.onnx").write_bytes(b"corrupt")  # the run goes on with the predictor alone
    choice = choose_models(tmp_path / "models", "frontier", ORDER)
    assert choice.predictor is not None and choice.predictor.beyond is None
    assert choice.predictor.thresholds == ThresholdConfig() and "sha256" in choice.notes[-1]


@pytest.mark.parametrize("calibrated", [True, False])
def test_a_flight_s_daemon_config_takes_the_predictor_s_thresholds(tmp_path, monkeypatch, calibrated):
    card = write_predictor_model(tmp_path / "models" / "predictor")
    if calibrated:
        add_thresholds(card, {"t_f_max": 0.1, "t_o": 0.9})
    seen = []

    def daemon(config, *args, **kwargs):
        seen.append(config.thresholds)
        raise _Built

    monkeypatch.setattr(daemon_module, "Daemon", daemon)
    plan = tmp_path / "rooms.json"
    save_plan_json(two_room_plan(), plan)
    options = RunOptions(tmp_path / "out", "frontier", plan=str(plan), models_dir=tmp_path / "models", progress=False)
    with pytest.raises(_Built):
        fly(options, SimulatedFlight())
    assert seen == [CALIBRATED if calibrated else ThresholdConfig()]
