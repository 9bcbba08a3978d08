"""Predictor evaluation: scoring with the thresholded prediction against the true coverage, summary, CLI."""

import json

import numpy as np
import pytest

from edge_explorer.cli import main
from edge_explorer.learn.eval_predictor import REPORT_LEVELS, evaluate_plan, summarize
from edge_explorer.learn.predictor_flights import FlightLimits, RandomGoalWalk
from edge_explorer.learn.unet import UNet, UNetConfig, save_unet
from edge_explorer.mapping.ego import pad_shift
from edge_explorer.world.grid import FREE
from edge_explorer.world.plan import save_plan_json
from tests.conftest import two_room_plan

LIMITS = FlightLimits(max_steps=300)


def test_no_prediction_scores_like_the_observed_map(scene):
    def unsure(window):
        return np.full(window.shape, 0.5, dtype=np.float32)  # between the thresholds: predicts nothing

    curve = evaluate_plan(scene, unsure, RandomGoalWalk(), np.random.default_rng(0), limits=LIMITS)
    np.testing.assert_allclose(curve.series["f1"], curve.series["f1_observed"])
    np.testing.assert_allclose(curve.series["coverage"], curve.true_coverage)
    assert np.all(np.diff(curve.true_coverage) >= 0.005 - 1e-9)  # one scored scan per 0.5 % bin


def test_a_perfect_prediction_scores_higher_early(scene, monkeypatch):
    from edge_explorer.learn import eval_predictor

    cells = []  # the predictor only sees the window: learn the robot's cell from the evaluation's ego shift

    def spy(codes, cell, size):
        cells.append(cell)
        return pad_shift(codes, cell, size)

    def perfect(window):
        truth = pad_shift(scene.truth_low, cells[-1], window.shape[0])
        return np.where(truth == FREE, 0.0, 1.0).astype(np.float32)

    monkeypatch.setattr(eval_predictor, "pad_shift", spy)
    curve = evaluate_plan(scene, perfect, RandomGoalWalk(), np.random.default_rng(0), limits=LIMITS)
    assert np.all(curve.series["f1"] >= curve.series["f1_observed"] - 1e-12)
    assert curve.series["f1"][0] > curve.series["f1_observed"][0] + 0.2
    assert np.all(curve.series["correct_coverage"] <= curve.series["coverage"] + 1e-12)
    assert np.all(curve.series["f1"] <= curve.series["f1_ceiling"] + 1e-12)
    summary = summarize([curve])
    assert summary["levels"]["0.50"]["n"] == 1 and summary["levels"]["0.50"]["f1"] > 0.9
    assert len(summary["curve"]["f1"]) == 100


def test_cli_writes_json_and_plot(tmp_path, capsys):
    plan = tmp_path / "rooms.json"
    save_plan_json(two_room_plan(), plan)
    model = tmp_path / "tiny.safetensors"
    save_unet(UNet(UNetConfig(channels=(4, 8, 8, 8, 8), head_channels=2)).eval().fused(), model)
    out, png = tmp_path / "eval.json", tmp_path / "eval.png"
    assert (
        main(["eval", "predictor", "--model", str(model), "--plans", str(plan), "--json", str(out), "--plot", str(png)])
        == 0
    )
    report = json.loads(out.read_text())
    assert report["n_plans"] == 1 and set(report["levels"]) == {f"{x:.2f}" for x in REPORT_LEVELS}
    assert len(report["model_sha256"]) == 64 and png.read_bytes()[:4] == b"\x89PNG"
    assert "F1" in capsys.readouterr().out


def test_cli_scores_with_the_thresholds_it_is_given(tmp_path, capsys):
    plan = tmp_path / "rooms.json"
    save_plan_json(two_room_plan(), plan)
    model = tmp_path / "tiny.safetensors"
    save_unet(UNet(UNetConfig(channels=(4, 8, 8, 8, 8), head_channels=2)).eval().fused(), model)
    out = tmp_path / "eval.json"
    args = ["eval", "predictor", "--model", str(model), "--plans", str(plan), "--json", str(out)]
    assert main([*args, "--thresholds", "0.1,0.8"]) == 0
    assert json.loads(out.read_text())["thresholds"] == {"t_f_max": 0.1, "t_o": 0.8}
    with pytest.raises(SystemExit) as exit_info:
        main([*args, "--thresholds", "0.9,0.8"])
    assert exit_info.value.code == 2 and "t_f_max ≤ t_o" in capsys.readouterr().err


def test_cli_rejects_a_missing_model(tmp_path, capsys):
    assert (
        main(
            [
                "eval",
                "predictor",
                "--model",
                str(tmp_path / "none.safetensors"),
                "--plans",
                "A",
                "--json",
                str(tmp_path / "x.json"),
            ]
        )
        == 2
    )
    assert "no such file" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["nope"])
def test_unknown_explorer(name):
    from edge_explorer.errors import EdgeExplorerError
    from edge_explorer.learn.eval_predictor import make_explorer

    with pytest.raises(EdgeExplorerError):
        make_explorer(name)
