"""The daemon thresholds with the shipped predictor's calibrated thresholds (edge_explorer.runtime.flight)."""

from __future__ import annotations

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
