"""The oracle (edge_explorer.bench.oracle, `edge-explorer bench oracle`): a perfect-knowledge explorer's path."""

import json

import numpy as np
import pytest

from edge_explorer.bench import explore
from edge_explorer.bench.oracle import oracle_path, visible_cells
from edge_explorer.bench.summary import markdown_oracle, oracle_ratios
from edge_explorer.cli import main
from edge_explorer.world.catalog import load_building, plan_to_raster
from edge_explorer.world.grid import LOW_RES_M
from edge_explorer.world.plan import FloorPlan, Rect, save_plan_json
from tests.conftest import two_room_plan


def box_plan(width_m: float, height_m: float, name: str) -> FloorPlan:
    """One empty room of ``width_m`` × ``height_m`` with 0.1 m walls."""
    w, h = width_m, height_m
    walls = (Rect(0.0, 0.0, w, 0.1), Rect(0.0, h - 0.1, w, h), Rect(0.0, 0.0, 0.1, h), Rect(w - 0.1, 0.0, w, h))
    return FloorPlan(name, ((0.0, 0.0), (w, 0.0), (w, h), (0.0, h)), walls)


@pytest.fixture(scope="module")
def rooms():
    return plan_to_raster(two_room_plan())


def test_one_view_covers_an_empty_room():
    raster = plan_to_raster(box_plan(5.0, 5.0, "box"))
    result = oracle_path(raster, (2.5, 2.5, 0.0))
    assert result.path_m == pytest.approx(0.0, abs=0.2)
    assert len(result.tour) == 0 and result.coverage >= 0.95


def test_path_grows_with_a_corridor():
    paths = []
    for length in (10.0, 20.0):
        raster = plan_to_raster(box_plan(length, 1.6, f"corridor-{length:.0f}"))
        result = oracle_path(raster, (0.8, 0.8, 0.0))
        assert result.coverage >= 0.95
        paths.append(result.path_m)
    # from one end the sensor sees 4.5 m ahead: about length − 2 · 4.5 m (the last 5 % may be skipped)
    assert 0 < paths[0] < paths[1]
    assert paths[1] - paths[0] == pytest.approx(10.0, abs=1.5)


def test_viewpoints_cover_the_goal_and_the_tour_is_deterministic(rooms):
    pose = explore.start_pose(rooms, 0)
    result = oracle_path(rooms, pose, goal=0.95)
    n_m = rooms.coarsened(LOW_RES_M).interior
    seen = visible_cells(rooms, np.vstack([result.start_xy_m, result.viewpoints_xy_m]), n_m)
    covered = np.unique(np.concatenate(seen))
    assert len(covered) / n_m.sum() == pytest.approx(result.coverage) and result.coverage >= 0.95
    assert sorted(result.tour) == list(range(len(result.viewpoints_xy_m)))
    assert result.path_m == pytest.approx(sum(result.leg_m)) and len(result.leg_m) == len(result.tour)
    assert result.path_at_goal_m is not None and result.path_at_goal_m <= result.path_m + 1e-9
    again = oracle_path(rooms, pose, goal=0.95)
    assert again.tour == result.tour and again.path_m == result.path_m
    assert np.array_equal(again.viewpoints_xy_m, result.viewpoints_xy_m)
    assert oracle_path(rooms, pose, goal=0.5).path_m <= result.path_m


def test_shorter_than_nearest_frontier():
    # on building A (not the two rooms: there the start sees nearly everything, and the greedy cover's
    # distance-blind choice of its one viewpoint loses to a frontier flight of 1.5 m)
    plan = load_building("A")
    pose = explore.start_pose(plan, 0)
    spec = explore.RunSpec("frontier", plan.name, 0, explore.run_seed(0, plan.name, 0), pose, 0.95, 1500, None)
    flown = explore.run_episode(plan, spec)["path_at_coverage_m"]
    assert flown is not None and oracle_path(plan, pose).path_at_goal_m < flown


def test_ratios_pair_by_building():
    def stats(avg):
        return {"path_at_coverage_m": {"avg": avg}}

    summary = {"plans": {"A": {"f": stats(20.0), "d": stats(10.0)}, "B": {"f": stats(30.0), "d": stats(None)}}}
    ratios = oracle_ratios(summary, ["f", "d"], {"A": 10.0, "B": 10.0})
    assert ratios["f"]["mean"] == pytest.approx(2.5) and ratios["f"]["buildings"] == 2
    assert ratios["d"]["plans"] == {"A": 1.0}
    table = markdown_oracle(summary, ["f", "d"], {"A": 10.0, "B": 10.0})
    assert "×2.50" in table and "| B | 10.0 | 30.0 (×3.00) | – |" in table


def test_mean_row_counts_the_buildings_shown():
    """Oracle paths of more buildings than the bench flew: the mean row names the buildings it averages."""
    summary = {"plans": {"A": {"f": {"path_at_coverage_m": {"avg": 20.0}}}}}
    table = markdown_oracle(summary, ["f"], {"A": 10.0, "B": 10.0, "C": 5.0})
    assert "| mean ratio (1 plans) | 1 | ×2.00 |" in table


def test_cli_writes_the_oracle_and_the_ratios(tmp_path, capsys):
    plan = tmp_path / "rooms.json"
    save_plan_json(two_room_plan(), plan)
    bench = tmp_path / "bench.json"
    stats = {"path_at_coverage_m": {"avg": 12.0}}
    bench.write_text(
        json.dumps({"seed": 0, "methods": ["frontier"], "summary": {"plans": {"two-rooms": {"frontier": stats}}}})
    )
    out = tmp_path / "oracle.json"
    assert main(["bench", "oracle", "--plans", str(plan), "--compare", str(bench), "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    path = report["oracle"][0]["path_at_goal_m"]
    assert report["ratios"]["frontier"]["plans"]["two-rooms"] == pytest.approx(12.0 / path, rel=1e-3)
    assert "| two-rooms |" in capsys.readouterr().out
