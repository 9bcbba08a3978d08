"""The exploration benchmark (edge_explorer.bench.explore and `edge-explorer bench explore`)."""

import json

import numpy as np
import pytest

from edge_explorer.bench import explore
from edge_explorer.bench.summary import failures, markdown_failures
from edge_explorer.cli import main
from edge_explorer.errors import EdgeExplorerError
from edge_explorer.plan.frontier import NearestFrontier
from edge_explorer.plan.registry import PlannerEntry
from edge_explorer.sim import runs
from edge_explorer.world.plan import save_plan_json
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan
from tests.plan.test_policy import nearest_first_scores, write_policy_model


def occupied_predictor(window: np.ndarray) -> np.ndarray:
    """Test double of a map predictor: everything it is asked about is occupied."""
    return np.ones(window.shape, dtype=np.float32)


@pytest.fixture(scope="module")
def rooms():
    return rasterize(two_room_plan(), 0.05)


def test_runs_share_the_start_and_differ_by_noise(rooms):
    specs = explore.plan_specs([rooms], ["frontier", "fuel"], runs=3, seed=7)
    assert len(specs) == 6
    assert len({s.start_pose for s in specs}) == 1
    assert len({s.seed for s in specs}) == 3  # one noise seed per run, the same for every method
    assert explore.start_pose(rooms, 7) == specs[0].start_pose  # from the seed and the name only
    assert explore.start_pose(rooms, 8) != specs[0].start_pose
    with pytest.raises(EdgeExplorerError, match="--predictor"):
        explore.plan_specs([rooms], ["frontier+pred"], runs=1, seed=0)
    with pytest.raises(EdgeExplorerError, match="unknown method"):
        explore.parse_methods("frontier,nbv")


@pytest.mark.slow
def test_benchmark_runs_and_resumes(rooms, tmp_path, monkeypatch):
    config = explore.BenchConfig(max_steps=300)
    specs = explore.plan_specs(
        [rooms],
        ["frontier", "fuel+pred"],
        runs=2,
        seed=1,
        config=config,
        predictor="tests.bench.test_explore:occupied_predictor",
    )
    records = explore.run_benchmark([rooms], specs, workers=1, out_dir=tmp_path)
    assert len(list(tmp_path.glob("*.json"))) == 4
    for record in records:
        assert record["collisions"] == 0 and record["path_at_coverage_m"] is not None
        curves = record["curves"]
        assert len(curves["coverage"]) == len(curves["path_length_m"]) == record["steps"] + 1
    predicted = [r for r in records if r["spec"]["method"] == "fuel+pred"]
    for r in predicted:  # the predictor claims everything at once; correct coverage still needs the flight
        assert r["path_at_coverage_m"] == 0.0 and r["curves"]["correct_coverage"][0] < 0.9 and r["steps"] > 0

    def must_not_fly(*args, **kwargs):
        raise AssertionError("a recorded run was flown again")

    monkeypatch.setattr(explore, "run_episode", must_not_fly)
    assert explore.run_benchmark([rooms], specs, workers=1, out_dir=tmp_path) == json.loads(json.dumps(records))
    changed = explore.plan_specs([rooms], ["frontier"], runs=1, seed=2, config=config)
    with pytest.raises(AssertionError, match="flown again"):  # another seed: not the recorded run
        explore.run_benchmark([rooms], changed, workers=1, out_dir=tmp_path)


@pytest.mark.slow
def test_cli_writes_table_json_and_figure(tmp_path, capsys):
    plan = tmp_path / "rooms.json"
    save_plan_json(two_room_plan(), plan)
    out = tmp_path / "bench.json"
    argv = [
        "bench",
        "explore",
        "--plans",
        str(plan),
        "--methods",
        "frontier,fuel",
        "--runs",
        "2",
        "--workers",
        "2",
        "--max-steps",
        "300",
        "--json",
        str(out),
        "--plot",
        str(tmp_path / "fig.png"),
        "--markdown",
        str(tmp_path / "table.md"),
    ]
    assert main(argv) == 0
    report = json.loads(out.read_text())
    assert report["methods"] == ["frontier", "fuel"] and len(report["runs"]) == 4
    assert set(report["summary"]["plans"]["two-rooms"]) == {"frontier", "fuel"}
    assert set(report["curves"]["two-rooms"]["fuel"]) == {"path_m", "coverage", "correct_coverage"}
    assert (tmp_path / "fig.png").read_bytes()[:4] == b"\x89PNG"
    metrics = ["path_at_coverage_m", "path_at_correct_90_m", "path_at_correct_coverage_m"]
    assert [(p["metric"], p["a"], p["b"]) for p in report["paired"]] == [(m, "frontier", "fuel") for m in metrics]
    out = capsys.readouterr().out
    assert "| two-rooms | fuel |" in out and "| fuel − frontier |" in out


def test_cli_errors_are_one_line(tmp_path, capsys):
    assert main(["bench", "explore", "--methods", "frontier+pred", "--plans", "A"]) == 2
    assert "--predictor" in capsys.readouterr().err
    assert main(["bench", "explore", "--methods", "fuel+pred", "--predictor", "no.such.module:f"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot load" in err


def test_predictor_loads_from_a_model_folder_weights_or_a_callable(tmp_path):
    from tests.predict.test_predictor import WINDOW, expected_probability, write_predictor_model

    window = np.zeros((WINDOW, WINDOW), dtype=np.int8)
    window[3, 4] = 1
    from_folder = explore.load_predictor(str(write_predictor_model(tmp_path / "predictor").parent))
    np.testing.assert_allclose(from_folder(window), expected_probability(window), atol=1e-6)
    assert explore.load_predictor("tests.bench.test_explore:occupied_predictor") is occupied_predictor

    torch = pytest.importorskip("torch")
    from edge_explorer.learn.unet import UNet, UNetConfig, save_unet

    torch.manual_seed(0)
    unet = UNet(UNetConfig(channels=(2, 4), head_channels=2)).eval()
    save_unet(unet, tmp_path / "tiny.safetensors")
    from_weights = explore.load_predictor(str(tmp_path / "tiny.safetensors"))
    probs = from_weights(np.zeros((8, 8), dtype=np.int8))
    assert probs.shape == (8, 8) and ((probs >= 0) & (probs <= 1)).all()
    with pytest.raises(EdgeExplorerError, match="no such file"):
        explore.load_predictor(str(tmp_path / "missing.safetensors"))
    with pytest.raises(EdgeExplorerError, match="model folder"):
        explore.load_predictor("not-a-reference")


def test_drl_methods_fly_a_goal_policy_through_the_planner_loop(rooms, tmp_path):
    with pytest.raises(EdgeExplorerError, match="--policy"):
        explore.plan_specs([rooms], ["drl"], runs=1, seed=0)
    spec = explore.plan_specs([rooms], ["drl"], runs=1, seed=0, policy="p")[0]
    seen = []

    def nearest_goal_first(observation):
        seen.append({k: v.shape for k, v in observation.items()})
        return nearest_first_scores()

    record = explore.run_episode(rooms, spec, policy=nearest_goal_first)
    assert record["ending"] == "goal" and record["collisions"] == 0  # its goals are flown along observed free space
    assert seen and seen[0] == {"high": (237, 237), "thres": (237, 237), "last_action": (6,)}
    assert len(seen) < record["steps"] / 3  # one decision per goal, not per step
    exported = explore.load_policy(str(write_policy_model(tmp_path / "policy").parent))  # the daemon's runtime
    assert explore.run_episode(rooms, spec, policy=exported)["curves"] == record["curves"]
    with pytest.raises(EdgeExplorerError, match="--policy"):
        explore.load_policy("not-a-model")


def test_runs_threshold_with_the_predictor_s_calibrated_thresholds(rooms, tmp_path, monkeypatch):
    from edge_explorer.mapping.ego import PREDICTOR_WINDOW_CELLS
    from edge_explorer.predict.thresholding import ThresholdConfig
    from tests.predict.test_predictor import add_thresholds, write_predictor_model

    card = write_predictor_model(tmp_path / "predictor", window=PREDICTOR_WINDOW_CELLS)
    add_thresholds(card, {"t_f_max": 0.1, "t_o": 0.9})
    used = []

    class RecordingEnv(runs.ExplorationEnv):
        def __init__(self, rasters, config, **kwargs):
            used.append(config.thresholds)
            super().__init__(rasters, config, **kwargs)

    config = explore.BenchConfig(max_steps=2)
    spec = explore.plan_specs([rooms], ["frontier+pred"], runs=1, seed=0, config=config, predictor=str(card))[0]
    monkeypatch.setattr(runs, "ExplorationEnv", RecordingEnv)
    explore.run_episode(rooms, spec, explore.load_predictor(str(card.parent)))
    explore.run_episode(rooms, spec, occupied_predictor)  # a predictor without a card: the defaults
    assert used == [ThresholdConfig(t_f_max=0.1, t_o=0.9), ThresholdConfig()]


class _GivesUp(NearestFrontier):
    """A planner that finds nothing to explore from the first step."""

    def __init__(self, config, table, policy=None):
        super().__init__(config, table)

    def act(self, maps, pose, previous_action, fused_low=None):
        return None


def test_a_short_run_says_why(rooms, monkeypatch):
    pose = explore.start_pose(rooms, 0)
    capped = explore.RunSpec("frontier", rooms.name, 0, 1, pose, 0.95, 5, None)
    record = explore.run_episode(rooms, capped)
    why = record["why"]
    assert record["ending"] == "step_cap" and why["reason"] == "step_limit"
    assert why["text"].startswith("step limit 5 reached") and why["unexplored_m2"] > 2.0
    assert 0 < why["unexplored_reachable_m2"] < why["unexplored_m2"]

    monkeypatch.setitem(explore.PLANNERS, "frontier", PlannerEntry("gives up", False, _GivesUp))
    record = explore.run_episode(rooms, explore.RunSpec("frontier", rooms.name, 0, 1, pose, 0.95, 50, None))
    assert record["ending"] == "explored" and record["why"]["reason"] == "planner_stall"
    page = markdown_failures(failures([record]))
    assert f"frontier on {rooms.name} run 0: planner stall" in page
    assert markdown_failures([]) == ""
