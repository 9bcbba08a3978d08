"""`edge-explorer train calibrate-probabilities` and the reliability figures of `eval predictor`
(learn.calibrate_probabilities, learn.eval_predictor)."""

import json

import numpy as np

from edge_explorer.backends.card import load_card, verify_sha256
from edge_explorer.cli import main
from edge_explorer.learn.calibrate_probabilities import order_safe, reachable_thresholds
from edge_explorer.learn.eval_predictor import evaluate_plan
from edge_explorer.learn.predictor_flights import FlightLimits, RandomGoalWalk
from edge_explorer.learn.reliability import GRID_STEPS
from edge_explorer.mapping.ego import PREDICTOR_WINDOW_CELLS
from edge_explorer.predict.predictor import card_calibration
from edge_explorer.predict.probability_calibration import ProbabilityCalibration
from edge_explorer.predict.thresholding import ThresholdConfig
from edge_explorer.world.plan import save_plan_json
from tests.conftest import two_room_plan
from tests.predict.test_predictor import write_predictor_model


def test_the_reachable_thresholds_are_every_dynamic_free_threshold_then_t_o():
    thresholds = reachable_thresholds(ThresholdConfig(t_f_max=0.35, t_o=0.96))
    assert thresholds[0] == 0.0 and thresholds[-2:] == [0.35, 0.96]
    assert np.all(np.diff(thresholds[:-1]) > 0) and 3000 < len(thresholds) < 3500  # the factor saturates at 130 m²


def test_a_map_that_changes_no_comparison_is_kept_as_fitted():
    fitted = ProbabilityCalibration("beta", a=0.6, b=-1.2, c=0.87)
    levels = np.arange(257) / 256
    assert order_safe(fitted, levels, reachable_thresholds(ThresholdConfig(t_f_max=0.35, t_o=0.96))) == (fitted, 0)


def test_the_evaluation_counts_the_unobserved_interior_cells_of_every_scored_scan(scene):
    half = ProbabilityCalibration("platt", a=1.0, b=0.0, c=1.0)

    def unsure(window):
        return np.full(window.shape, 0.5, dtype=np.float32)

    curve = evaluate_plan(scene, unsure, RandomGoalWalk(), np.random.default_rng(0), limits=FlightLimits(300))
    assert curve.counts.total > 0
    k = GRID_STEPS // 2  # every cell was given 0.5
    assert curve.counts.free.sum() == curve.counts.free[k] and curve.counts.occupied.sum() == curve.counts.occupied[k]
    rel = curve.counts.reliability(10, half)
    occupied = curve.counts.occupied[k] / curve.counts.total
    assert rel.ece == rel.mce == abs(occupied - 0.5)


def test_the_command_writes_the_map_into_the_card_and_eval_reports_before_and_after(tmp_path, capsys):
    card = write_predictor_model(tmp_path / "predictor", window=PREDICTOR_WINDOW_CELLS)
    artifacts_before = json.loads(card.read_text())["artifacts"]
    docs = tmp_path / "docs"
    arguments = ["train", "calibrate-probabilities", "--model", str(card.parent), "--plans", "1", "--docs", str(docs)]
    assert main(arguments) == 0
    doc = json.loads(card.read_text())
    assert doc["artifacts"] == artifacts_before  # only the calibration key was added
    calibration = card_calibration(card)
    assert calibration is not None and calibration.method == "beta"
    entry = doc["calibration"]
    assert entry["order_check"]["violations"] == 0 and entry["provenance"]["plans"] == "val-00000"
    assert entry["val"]["ece_calibrated"] <= entry["val"]["ece_raw"]
    loaded = load_card(card)
    for artifact in loaded.artifacts.values():
        verify_sha256(loaded, artifact)
    report = json.loads((docs / "probability_calibration_val.json").read_text())
    assert report["raw"]["ece"] == entry["val"]["ece_raw"]
    assert (docs / "reliability_val.png").read_bytes()[:4] == b"\x89PNG"
    assert "ECE" in capsys.readouterr().out
    # eval predictor measures the raw and the calibrated probabilities
    plan = tmp_path / "rooms.json"
    save_plan_json(two_room_plan(), plan)
    out, png = tmp_path / "eval.json", tmp_path / "rel.png"
    evaluate = ["eval", "predictor", "--model", str(card.parent), "--plans", str(plan), "--json", str(out)]
    assert main([*evaluate, "--reliability-plot", str(png)]) == 0
    rel = json.loads(out.read_text())["reliability"]
    assert rel["raw"]["cells"] == rel["calibrated"]["cells"] > 0
    assert rel["calibration"] == calibration.to_json() and png.read_bytes()[:4] == b"\x89PNG"
    assert "reliability, calibrated probabilities" in capsys.readouterr().out
