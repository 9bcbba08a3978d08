"""A flight that ends short says why (issue #18): the run summary's ``why`` and the picture's unexplored cells."""

from types import SimpleNamespace

import numpy as np

from edge_explorer.mapping.observed import ObservedMaps
from edge_explorer.runtime.daemon.report import CoverageTruth, DecisionView
from edge_explorer.runtime.flight_summary import draw_run, explain_ending
from edge_explorer.world.catalog import plan_to_raster
from edge_explorer.world.grid import FREE, LOW_RES_M, UNKNOWN
from tests.conftest import two_room_plan


def _daemon(raster, known_left_room: bool):
    maps = ObservedMaps.empty(raster.grid, LOW_RES_M)
    low = np.full(maps.low.shape, UNKNOWN, dtype=maps.low.dtype)
    if known_left_room:
        low[:, : low.shape[1] // 2] = FREE
    view = DecisionView(maps.high, maps.high_grid, low, maps.low_grid, None)
    config = SimpleNamespace(coverage_goal=0.95)
    return SimpleNamespace(truth=CoverageTruth(raster), view=view, config=config)


def test_a_planner_stall_reports_the_unknown_area_and_how_much_is_reachable():
    raster = plan_to_raster(two_room_plan())
    daemon = _daemon(raster, known_left_room=True)
    report = SimpleNamespace(coverage=0.5, ending="explored")
    why = explain_ending(report, daemon)
    assert why["reason"] == "planner_stall" and "planner stall" in why["text"]
    n_m_m2 = daemon.truth.interior.sum() * LOW_RES_M**2
    assert 0.3 * n_m_m2 < why["unexplored_m2"] < 0.7 * n_m_m2  # the right room
    assert 0 < why["unexplored_reachable_m2"] < why["unexplored_m2"]  # walls and the band along them: seen, not flown


def test_a_time_limit_and_the_goal_are_named():
    raster = plan_to_raster(two_room_plan())
    daemon = _daemon(raster, known_left_room=False)
    why = explain_ending(SimpleNamespace(coverage=0.1, ending="time limit"), daemon)
    assert why["reason"] == "time limit" and why["text"].startswith("time limit at 10.0%")
    assert explain_ending(SimpleNamespace(coverage=0.96, ending="coverage goal"), daemon)["reason"] == "goal"
    assert explain_ending(SimpleNamespace(coverage=None, ending="time limit"), daemon) is None  # no plan to measure


def test_the_picture_marks_the_unexplored_cells(tmp_path):
    raster = plan_to_raster(two_room_plan())
    daemon = _daemon(raster, known_left_room=True)
    why = explain_ending(SimpleNamespace(coverage=0.5, ending="explored"), daemon)
    summary = {
        "path_xy_m": [(1.0, 1.0), (1.5, 1.2)],
        "plan": raster.name,
        "planner": "frontier",
        "ending": "explored",
        "coverage": 0.5,
        "correct_coverage": 0.5,
        "path_length_m": 0.6,
        "collisions": 0,
        "why": why,
    }
    unexplored = daemon.truth.unexplored(daemon.view.low, daemon.view.low_grid)[0]
    panels = [("observed", daemon.view.low, daemon.view.low_grid)]
    plan = (raster.occupied, raster.interior, raster.grid)
    draw_run(tmp_path / "a.png", summary, panels, plan, None, (unexplored, daemon.truth.grid))
    draw_run(tmp_path / "b.png", summary, panels, plan, None, None)
    import matplotlib.image as mpimg

    a, b = mpimg.imread(tmp_path / "a.png"), mpimg.imread(tmp_path / "b.png")
    orange = (a[..., 0] > 0.9) & (a[..., 1] > 0.45) & (a[..., 1] < 0.75) & (a[..., 2] < 0.35)
    orange_b = (b[..., 0] > 0.9) & (b[..., 1] > 0.45) & (b[..., 1] < 0.75) & (b[..., 2] < 0.35)
    assert orange.sum() > 1000 and orange_b.sum() < orange.sum() / 10


def test_without_a_plan_the_map_stop_is_named_with_the_areas():
    daemon = SimpleNamespace(truth=None, view=None, config=SimpleNamespace(coverage_goal=0.95, stop_threshold_m2=4.0))
    parts = {"unknown_reachable_m2": 1.2, "expected_wrong_m2": 0.8, "predicted_m2": 9.0}
    report = SimpleNamespace(
        coverage=None, ending="map says verified", unverified_m2=2.0, verified_m2=150.0, unverified=parts
    )
    why = explain_ending(report, daemon)
    assert why["reason"] == "map_verified" and why["verified_m2"] == 150.0 and why["expected_wrong_m2"] == 0.8
    assert why["text"] == "map says verified: 2.0 m² unverified (below 4 m²), 150.0 m² verified"
    report.ending = "time limit"
    assert explain_ending(report, daemon) is None
