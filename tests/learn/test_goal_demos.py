"""Expert demonstrations for the goal policy flown inside the planning hierarchy, on plans and on whole floors
(edge_explorer.learn.goal_demos)."""

import math

import numpy as np
import pytest

from edge_explorer.learn.goal_demos import DemoConfig, LabellingPlanner, fly_demo
from edge_explorer.mapping.ego import OBSERVATION_WINDOW_CELLS
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.sim.episode import Episode
from edge_explorer.world.plan import FloorPlan, Rect
from edge_explorer.world.raster import rasterize
from tests.conftest import two_room_plan


def offices_along_a_corridor(length_m: float) -> FloorPlan:
    """A 2.4 m corridor along x with a row of 4 m offices on one side, each with a 1 m door: longer than the
    planning window and than the 23 × 13 m envelope, so the planner takes its whole-floor settings."""
    depth_m, corridor_m, wall_m = 5.0, 2.4, 0.1
    height_m = corridor_m + depth_m
    walls = [
        Rect(0.0, 0.0, length_m, wall_m),
        Rect(0.0, height_m - wall_m, length_m, height_m),
        Rect(0.0, 0.0, wall_m, height_m),
        Rect(length_m - wall_m, 0.0, length_m, height_m),
    ]
    x = 4.0
    while x < length_m - 1.0:  # the offices' dividing walls, and their front wall with a door each
        walls.append(Rect(x, corridor_m, x + wall_m, height_m))
        walls.append(Rect(x - 4.0, corridor_m, x - 2.5, corridor_m + wall_m))
        walls.append(Rect(x - 1.5, corridor_m, x, corridor_m + wall_m))
        x += 4.0
    walls.append(Rect(x - 4.0, corridor_m, length_m, corridor_m + wall_m))
    outline = ((0.0, 0.0), (length_m, 0.0), (length_m, height_m), (0.0, height_m))
    return FloorPlan(f"offices-{length_m:.0f}m", outline, tuple(walls), (), ())


def labelled_records_check(records) -> None:
    for high, thres, last_action, mask, label in records:
        assert high.shape == thres.shape == (OBSERVATION_WINDOW_CELLS, OBSERVATION_WINDOW_CELLS)
        assert mask.shape == (GOAL_GRID_CELLS * GOAL_GRID_CELLS,) and mask[label]
        assert 0 <= last_action < 6


def test_on_a_plan_that_fits_the_window_the_demonstrations_are_the_bare_experts():
    raster = rasterize(two_room_plan(), 0.05)
    config = DemoConfig(max_steps=300)
    env = ExplorationEnv([raster], EnvConfig(coverage_goal=1.0, max_steps=config.max_steps))
    bare = LabellingPlanner(None, env.table)
    bare.reset()
    _, info = env.reset(seed=3)
    Episode(env, bare, info, coverage_goal=config.coverage_goal, max_steps=config.max_steps).run()

    windowed = fly_demo(raster, None, 3, config)

    assert len(windowed) == len(bare.records) >= 3
    for a, b in zip(windowed, bare.records, strict=True):
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) and np.array_equal(a[3], b[3])
        assert a[2] == b[2] and a[4] == b[4]


def test_on_a_floor_longer_than_the_window_the_expert_labels_the_windows_decisions():
    raster = rasterize(offices_along_a_corridor(40.0), 0.05)
    assert max(raster.grid.size_xy_m) > 24.0 + 1.0  # the hierarchy's window does not hold it

    records = fly_demo(raster, None, 5, DemoConfig(max_steps=900))

    assert len(records) >= 5
    labelled_records_check(records)


def test_on_a_whole_floor_the_labelling_planner_takes_the_learned_planners_targets():
    planner = LabellingPlanner()
    planner.reset()
    assert not planner.observed_targets  # in the window: the fused frontier, as the learned planner there
    planner.on_whole_floor()
    assert planner.observed_targets and math.isfinite(planner.settings.policy_max_extra_m)
    planner.reset()
    assert not planner.observed_targets


@pytest.mark.parametrize("floors, expected_steps, per_shard", [(False, 1500, 10), (True, 40_000, 1)])
def test_goal_demos_command_flies_floors_one_per_shard_to_the_benchs_step_cap(
    floors, expected_steps, per_shard, monkeypatch, tmp_path
):
    from edge_explorer import cli
    from edge_explorer.learn import goal_demos

    seen = {}

    def fake_generate(plans, out, split, plan_range, predictor, policy, **kw):
        seen.update(split=split, plan_range=plan_range, **kw)
        return 0

    monkeypatch.setattr(goal_demos, "generate_demos", fake_generate)
    argv = ["train", "goal-demos", "--out", str(tmp_path), "--split", "val", "--count", "2", "--predictor", ""]
    assert cli.main(argv + (["--floors"] if floors else [])) == 0
    assert seen["floors"] is floors and seen["plans_per_shard"] == per_shard
    assert seen["config"].max_steps == expected_steps and seen["plan_range"] == (0, 2) and seen["split"] == "val"
