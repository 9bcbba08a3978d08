"""Replay one `bench explore` run from its stored spec and print every collision with its context (session 30).

For each collision: the distance from the pose before the step to the nearest observed OCCUPIED and UNKNOWN cell,
and the eight steps before it as (step, pose, previous action, action, the action the follower would take there
without the unseen-cell clearance, unseen clearance of the pose). Plans are resolved like `bench explore --plans`.

    python docs/policy/session30/collide_replay.py runs/s30/bench/real.json frontier kth_50037764_PLAN1_0 1 \
        --plans ../shared/data/realplans
"""

import argparse
import dataclasses
import json

import numpy as np

from edge_explorer.bench import explore as bench
from edge_explorer.plan.baselines import PLANNERS
from edge_explorer.plan.follow import FreeSpace, choose_action
from edge_explorer.predict.predictor import thresholds_of
from edge_explorer.sim.env import EnvConfig, ExplorationEnv
from edge_explorer.world.catalog import load_buildings
from edge_explorer.world.grid import OCCUPIED, UNKNOWN


def nearest_m(codes: np.ndarray, grid, pose, code: int, cells: int = 20) -> float:
    """Distance (m) from ``pose`` to the nearest cell of ``code`` within ``cells`` cells (inf if none)."""
    r, c = (int(v) for v in grid.cell_of(pose[0], pose[1]))
    window = codes[max(r - cells, 0) : r + cells + 1, max(c - cells, 0) : c + cells + 1]
    rows, cols = np.nonzero(window == code)
    if not len(rows):
        return float("inf")
    return float(np.hypot(rows + max(r - cells, 0) - r, cols + max(c - cells, 0) - c).min() * grid.resolution_m)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("report")
    parser.add_argument("method")
    parser.add_argument("plan")
    parser.add_argument("run", type=int)
    parser.add_argument("--plans", default="test", help="the bench's --plans reference holding the plan")
    args = parser.parse_args()
    records = json.load(open(args.report))["runs"]
    spec = next(
        r["spec"]
        for r in records
        if (r["spec"]["method"], r["spec"]["plan"], r["spec"]["run"]) == (args.method, args.plan, args.run)
    )
    raster = next(r for r in load_buildings(args.plans) if r.name == args.plan)
    predictor = bench.load_predictor(spec["predictor"]) if args.method.endswith("+pred") else None
    config = EnvConfig(coverage_goal=1.0, max_steps=spec["max_steps"], thresholds=thresholds_of(predictor))
    env = ExplorationEnv([raster], config, predictor=predictor)
    planner = PLANNERS[args.method.removesuffix("+pred")](env.table)
    without = dataclasses.replace(planner.config.follow, unseen_clearance_m=0.0)
    planner.reset()
    _, info = env.reset(seed=spec["seed"], options={"start_pose": tuple(spec["start_pose"])})
    previous, recent = 0, []
    for step in range(spec["max_steps"]):
        if info["coverage"] >= spec["coverage_goal"] and info["correct_coverage"] >= spec["coverage_goal"]:
            break
        pose, high = env.pose, env.maps.high.copy()
        free = FreeSpace.from_codes(high, env.maps.high_grid)
        action = planner.act(env.maps, pose, previous, env.thresholded_low)
        if action is None:
            break
        goal = planner._goal
        alternative = (
            None
            if goal is None
            else choose_action(env.table, pose, previous, goal.path_xy_m, free, without, goal.yaw_rad)
        )
        unseen = round(float(free.unseen_clearance_m[env.maps.high_grid.cell_of(*pose[:2])]), 2)
        recent = [*recent, (step, tuple(round(float(v), 3) for v in pose), previous, action, alternative, unseen)][-8:]
        _, _, _, _, info = env.step(action)
        if info["collided"]:
            grid = env.maps.high_grid
            print(
                f"collision at step {step}: observed wall {nearest_m(high, grid, pose, OCCUPIED):.2f} m, "
                f"unseen cell {nearest_m(high, grid, pose, UNKNOWN):.2f} m"
            )
            for row in recent:
                print("   ", row)
        previous = 0 if info["collided"] else action
    print(f"{args.plan} {args.method} run {args.run}: path {info['path_length_m']:.2f} m")


if __name__ == "__main__":
    main()
