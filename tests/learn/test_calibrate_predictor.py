"""Threshold calibration on val flights and `edge-explorer train calibrate-predictor` (learn.calibrate_predictor)."""

import json

import numpy as np

from edge_explorer.backends.card import load_card, verify_sha256
from edge_explorer.cli import main
from edge_explorer.learn.calibrate_predictor import plan_samples
from edge_explorer.learn.predictor_flights import RandomGoalWalk
from edge_explorer.mapping.ego import PREDICTOR_WINDOW_CELLS
from edge_explorer.predict.predictor import card_thresholds
from edge_explorer.predict.thresholding import ThresholdConfig
from edge_explorer.world.grid import UNKNOWN
from edge_explorer.world.plan import save_plan_json
from tests.conftest import two_room_plan
from tests.predict.test_predictor import write_predictor_model


def unsure(window):
    return np.full(window.shape, 0.5, dtype=np.float32)


def test_a_flight_gives_one_sample_per_level_reached(scene):
    samples = plan_samples(scene, unsure, RandomGoalWalk(), np.random.default_rng(0), levels=(0.5, 0.1, 2.0))
    assert [s.level for s in samples] == [0.1, 0.5]  # 200 % is never reached; sorted by level
    for s in samples:
        coverage = np.count_nonzero(scene.interior_low & (s.observed != UNKNOWN)) / np.count_nonzero(scene.interior_low)
        assert s.level <= coverage < s.level + 0.05
        assert s.probabilities.shape == s.observed.shape == scene.truth_low.shape
    assert np.count_nonzero(samples[0].observed != UNKNOWN) < np.count_nonzero(samples[1].observed != UNKNOWN)


def test_the_command_writes_the_thresholds_into_the_card_and_the_figures_and_eval_reads_them(tmp_path, capsys):
    card = write_predictor_model(tmp_path / "predictor", window=PREDICTOR_WINDOW_CELLS)
    artifacts_before = json.loads(card.read_text())["artifacts"]
    docs = tmp_path / "docs"
    arguments = ["train", "calibrate-predictor", "--model", str(card.parent), "--plans", "1", "--docs", str(docs)]
    assert main([*arguments, "--levels", "0.1", "0.2", "--target", "0.5"]) == 0
    report = json.loads((docs / "calibration_val.json").read_text())
    assert report["card_written"] and report["levels"] == ["0.10", "0.20"]
    assert report["provenance"]["plans"] == "val-00000"
    assert (docs / "calibration_val.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    doc = json.loads(card.read_text())
    assert doc["artifacts"] == artifacts_before  # only the thresholds key was added
    chosen = ThresholdConfig(t_f_max=doc["thresholds"]["t_f_max"], t_o=doc["thresholds"]["t_o"])
    assert card_thresholds(card) == chosen and doc["thresholds"]["precision_target"] == 0.5
    loaded = load_card(card)
    for artifact in loaded.artifacts.values():
        verify_sha256(loaded, artifact)
    assert "card: thresholds written" in capsys.readouterr().out
    # eval predictor reads them too
    plan = tmp_path / "rooms.json"
    save_plan_json(two_room_plan(), plan)
    evaluation = tmp_path / "eval.json"
    evaluate = ["eval", "predictor", "--model", str(card.parent), "--plans", str(plan), "--json", str(evaluation)]
    assert main(evaluate) == 0
    assert json.loads(evaluation.read_text())["thresholds"] == {"t_f_max": chosen.t_f_max, "t_o": chosen.t_o}
