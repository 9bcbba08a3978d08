"""The map stop rule in the benchmark (issue #56 item 3): ``bench explore --stop map``, its records and summary, and
a flight whose predictor is wrong in a known region that keeps exploring until it has seen it."""

import json
import math

import numpy as np
import pytest

from edge_explorer.bench import explore
from edge_explorer.bench.stops import markdown_stops, stop_summary
from edge_explorer.cli import main
from edge_explorer.mapping import ego
from edge_explorer.plan.registry import build_planner
from edge_explorer.predict.thresholding import ThresholdConfig
from edge_explorer.predict.verification import unverified_area_m2
from edge_explorer.sim import runs
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.sim.episode import Episode
from edge_explorer.world.grid import FREE, LOW_RES_M, OCCUPIED, UNKNOWN
from edge_explorer.world.plan import save_plan_json
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan

WEST_ROOM_FACING_WEST = (1.0, 1.5, math.pi)  # the east room (x > 2 m) is out of sight at the start


@pytest.fixture(scope="module")
def rooms():
    return rasterize(two_room_plan(), 0.05)


def _spec(method: str = "frontier", stop: str = "map", threshold: float | None = 2.0) -> runs.RunSpec:
    return runs.RunSpec(method, "two-rooms", 0, 3, WEST_ROOM_FACING_WEST, 0.95, 300, None, None, stop, threshold)


def test_a_map_stop_run_ends_by_the_rule_and_says_how_right_the_map_was(rooms):
    record = runs.run_episode(rooms, _spec())
    assert record["ending"] == "map_stop" and record["why"]["reason"] == "map_stop"
    assert record["unverified"]["total_m2"] < 2.0
    assert len(record["curves"]["unverified_m2"]) == record["steps"] + 1
    assert record["curves"]["unverified_m2"][-1] < 2.0 <= min(record["curves"]["unverified_m2"][:-1])
    assert record["correct_coverage_at_stop"] == record["final_correct_coverage"]
    assert record["path_at_stop_m"] == record["path_length_m"] > 0
    assert record["false_stop"] == (record["final_correct_coverage"] < 0.9)
    truth = runs.run_episode(rooms, _spec(stop="truth", threshold=None))
    assert "unverified" not in truth and "unverified_m2" not in truth["curves"]  # truth runs: records as before


def test_stop_settings_are_part_of_the_spec_and_old_records_stay_readable(rooms, tmp_path):
    with pytest.raises(ValueError, match="stop"):
        _spec(stop="map", threshold=None)
    with pytest.raises(ValueError, match="stop"):
        _spec(stop="oracle")
    truth, mapped = (
        explore.plan_specs([rooms], ["frontier"], 1, 0, explore.BenchConfig(stop=s, stop_threshold_m2=3.0))[0]
        for s in ("truth", "map")
    )
    assert (truth.stop, truth.stop_threshold_m2, mapped.stop, mapped.stop_threshold_m2) == ("truth", None, "map", 3.0)
    spec = {k: v for k, v in runs.asdict(truth).items() if k not in ("stop", "stop_threshold_m2", "policy")}
    old = tmp_path / "old.json"
    old.write_text(json.dumps({"format": runs.RECORD_FORMAT, "spec": spec, "ending": "goal"}))
    assert explore._read_record(old, truth) is not None  # a record from before the stop rule: a truth run
    assert explore._read_record(old, mapped) is None  # never reused for a map-stop run


def _record(method: str, plan: str, correct: float, path: float, ending: str = "map_stop") -> dict:
    spec = {"method": method, "plan": plan, "run": 0}
    return {"spec": spec, "ending": ending, "correct_coverage_at_stop": correct, "path_at_stop_m": path}


def test_the_summary_counts_false_stops_and_pairs_the_path_with_frontiers_end():
    records = [
        _record("frontier", "a", 0.95, 50.0, "explored"),
        _record("frontier", "b", 0.96, 80.0),
        _record("frontier+pred", "a", 0.85, 30.0),  # a false stop
        _record("frontier+pred", "b", 0.93, 60.0),
    ]
    stops = stop_summary(records, ["frontier", "frontier+pred"])
    pred = stops["frontier+pred"]
    assert (pred["false_stops"], pred["false_stop_rate"], pred["false_stop_runs"]) == (1, 0.5, ["a run 0"])
    assert pred["endings"] == {"map_stop": 2, "explored": 0, "step_cap": 0}
    vs = pred["vs_reference"]
    assert (vs["mean_m"], vs["median_m"], vs["shorter"], vs["buildings"]) == (-20.0, -20.0, 2, 2)
    assert vs["mean_ratio"] == pytest.approx((0.6 + 0.75) / 2)
    assert stops["frontier"]["false_stops"] == 0 and stops["frontier"]["endings"]["explored"] == 1
    table = markdown_stops(stops, 4.0)
    assert "| frontier+pred | 2 | 2 / 0 / 0 | 1 (50.0 %) |" in table and "-20.0 ± 0.0" in table
    assert stop_summary(records, ["frontier+pred"])["frontier+pred"]["vs_reference"] is None


@pytest.mark.slow
def test_cli_stop_map_reports_the_rule(tmp_path, capsys):
    plan = tmp_path / "rooms.json"
    save_plan_json(two_room_plan(), plan)
    out = tmp_path / "bench.json"
    argv = ["bench", "explore", "--plans", str(plan), "--methods", "frontier", "--runs", "1", "--workers", "1"]
    assert main([*argv, "--max-steps", "200", "--stop", "map", "--stop-threshold-m2", "2", "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["config"]["stop"] == "map" and report["config"]["stop_threshold_m2"] == 2.0
    assert report["runs"][0]["ending"] in ("map_stop", "explored") and "frontier" in report["stops"]
    assert "Map stop rule (unverified area < 2 m²)" in capsys.readouterr().out
    assert main([*argv, "--stop-threshold-m2", "2"]) == 2  # a threshold goes with --stop map
    assert "--stop map" in capsys.readouterr().err


class RoomPredictor:
    """Test double of a map predictor that knows the plan: right (p = 0 / 1) everywhere but in the east room, where
    it says FREE with probability ``p_east`` of being occupied — wrong where the truth has the room's walls."""

    def __init__(self, env: ExplorationEnv, p_east: float) -> None:
        self.env = env
        self.p_east = p_east

    def __call__(self, window: np.ndarray) -> np.ndarray:
        truth = self.env._truth
        assert truth is not None
        probs = np.where(truth.truth_low == FREE, 0.0, 1.0).astype(np.float32)
        probs[east_room(self.env)] = self.p_east
        x, y, _ = self.env.pose
        row, col = (int(v) for v in self.env.maps.low_grid.cell_of(x, y))
        return ego.pad_shift(probs, (row, col), window.shape[0], fill=1.0)


def east_room(env: ExplorationEnv) -> np.ndarray:
    """N_M cells east of the dividing wall (its door included): the region the double gets wrong."""
    grid, truth = env.maps.low_grid, env._truth
    assert truth is not None
    x = grid.origin_xy[0] + (np.arange(grid.shape[1]) + 0.5) * grid.resolution_m
    return truth.interior_low & (x >= 1.9)[np.newaxis, :] & (truth.truth_low != UNKNOWN)


def fly_until_map_stop(rooms, p_east: float, threshold_m2: float) -> tuple[ExplorationEnv, str]:
    """Fly frontier+pred from the west room with the double, until the map stop rule (or the planner's end).
    Thresholds that let a p = 0.5 cell be predicted FREE, and open at once (a tiny plan)."""
    thresholds = ThresholdConfig(t_f_max=0.6, t_o=0.9, max_plan_area_m2=1.0)
    env = ExplorationEnv([rooms], EnvConfig(coverage_goal=1.0, max_steps=300, thresholds=thresholds))
    env.predictor = RoomPredictor(env, p_east)
    planner = build_planner("frontier", env.table, None)
    planner.reset()
    _, info = env.reset(seed=5, options={"start_pose": WEST_ROOM_FACING_WEST})

    def map_stop() -> bool:
        maps = env.maps
        area = unverified_area_m2(maps.low, env.thresholded_low, env.probabilities_low, LOW_RES_M)
        return area.total_m2 < threshold_m2

    episode = Episode(env, planner, info, coverage_goal=0.95, max_steps=300, map_stop=map_stop)
    return env, episode.run()


def test_a_predictor_wrong_in_a_known_region_keeps_the_flight_going_until_it_has_seen_it(rooms):
    env, ending = fly_until_map_stop(rooms, p_east=0.5, threshold_m2=0.5)
    east = east_room(env)
    assert ending == "map_stop"
    predicted_east = east & (env.thresholded_low == FREE)
    assert predicted_east.any() or (env.maps.low[east] != UNKNOWN).all()
    seen = float((env.maps.low[east] != UNKNOWN).mean())
    assert seen >= 0.85  # it flew over and looked: at most 0.5 m² / (0.5 × 0.04 m²) = 25 cells left unseen
    assert (env.thresholded_low[east & (env.maps.low == UNKNOWN)] != OCCUPIED).all()
    # the same flight with a confident (p = 0) prediction of the east room trusts it and stops before seeing it
    confident_env, confident_ending = fly_until_map_stop(rooms, p_east=0.0, threshold_m2=0.5)
    assert confident_ending == "map_stop"
    assert float((confident_env.maps.low[east_room(confident_env)] != UNKNOWN).mean()) < 0.5 * seen
